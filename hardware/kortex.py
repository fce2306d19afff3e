"""The Kortex backend: a Kinova Gen3-family arm over the vendor's ``kortex_api``.

``kortex_api`` is not on PyPI; it is an optional extra. Install Kinova's wheel from the Kortex
GitHub releases (https://github.com/Kinovarobotics/kortex/releases)::

    pip install kortex_api-<version>-py3-none-any.whl

Kortex drives the Gen3 family (Gen3, Gen3 lite), not the JACO Gen2 the default task models: the
arm model the policy was trained on must match the arm deployed (joint count, limits, kinematics);
:meth:`KortexArm.connect` refuses an arm whose actuator count differs from the description.

Everything that can be done without the vendor library is a pure function here and is tested
without it: degree/radian conversion (Kortex speaks degrees; this protocol radians), unwrapping of
continuous joints, the joint-speed message as plain values, the arm-state and fault mapping, and
the credentials (from environment variables or a file outside the repository, never logged, never
in an error message: :func:`scrub`).

The robot address is always explicit: there is no default address, and nothing is contacted before
:meth:`KortexArm.connect`.
"""

from __future__ import annotations

import dataclasses
import functools
import html
import importlib
import json
import logging
import os
import re
import urllib.parse
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ahrm_stack.robot import RobotDescription
from hardware.protocol import (ArmAdapter, ArmFaultError, ArmState, CommandRefusedError,
                               ConnectionLostError, Fault, Feedback, FeedbackTimeoutError,
                               HardwareError, NotConnectedError, ServoingMode, WallClock,
                               check_joint_speeds)

log = logging.getLogger(__name__)

REPOSITORY_ROOT = Path(__file__).resolve().parent.parent
USERNAME_ENV = "KORTEX_USERNAME"
PASSWORD_ENV = "KORTEX_PASSWORD"
CREDENTIALS_FILE_ENV = "KORTEX_CREDENTIALS_FILE"
INSTALL_HINT = ("kortex_api is not installed. It is not on PyPI: download Kinova's wheel from the "
                "Kortex GitHub releases (https://github.com/Kinovarobotics/kortex/releases) and run "
                "`pip install kortex_api-<version>-py3-none-any.whl`.")


class KortexNotInstalledError(HardwareError):
    """The vendor library ``kortex_api`` is missing; the message says how to install it."""


class CredentialsError(HardwareError):
    """Credentials are missing or stored somewhere they must not be; never contains a secret."""


# ---------------------------------------------------------------------------------------------
# Pure functions (tested without kortex_api)
# ---------------------------------------------------------------------------------------------


def radians_to_degrees(values) -> np.ndarray:
    """rad (or rad/s) -> deg (or deg/s)."""
    return np.degrees(np.asarray(values, dtype=float))


def degrees_to_radians(values) -> np.ndarray:
    """deg (or deg/s) -> rad (or rad/s)."""
    return np.radians(np.asarray(values, dtype=float))


def unwrap_positions(measured: np.ndarray, reference: np.ndarray | None,
                     continuous: np.ndarray, range_centre: np.ndarray | None = None) -> np.ndarray:
    """Joint positions (rad) with each continuous joint moved by whole turns to lie within π of
    ``reference`` (the previous reading, rad), and each limited joint moved by whole turns to lie
    within π of the centre of its range (``range_centre``, rad; without it, in (-π, π]).

    Kortex reports continuous joints in [0°, 360°) and limited ones in (-180°, 180°]; the model's
    continuous joints are unbounded (e.g. the JACO home posture is 275° = 4.80 rad), so a reading
    near 0° right after 359° must become 2π + small, not 0. A limited joint's range may lie past
    180° (JACO's joint 2 spans 47°–313°), so -150° read there is 210°, the angle inside the range.
    """
    measured = np.asarray(measured, dtype=float)
    continuous = np.asarray(continuous, dtype=bool)
    if range_centre is None:
        limited = np.angle(np.exp(1j * measured))  # (-π, π]
        limited = np.where(limited == -np.pi, np.pi, limited)
    else:
        centre = np.asarray(range_centre, dtype=float)
        limited = measured + 2 * np.pi * np.round((centre - measured) / (2 * np.pi))
    if reference is None:
        return np.where(continuous, measured, limited)
    reference = np.asarray(reference, dtype=float)
    turns = np.round((reference - measured) / (2 * np.pi))
    return np.where(continuous, measured + 2 * np.pi * turns, limited)


def joint_speeds_message(speeds_rad_s: Sequence[float]) -> list[dict]:
    """The ``Base_pb2.JointSpeeds`` content, as plain values: one entry per joint with
    ``joint_identifier`` (0-based), ``value`` (deg/s) and ``duration`` 0 (hold until the next)."""
    degrees = radians_to_degrees(speeds_rad_s)
    return [{"joint_identifier": i, "value": float(v), "duration": 0} for i, v in enumerate(degrees)]


_ARM_STATES = {
    "ARMSTATE_BASE_INITIALIZATION": ArmState.BASE_INITIALIZATION,
    "ARMSTATE_IDLE": ArmState.IDLE,
    "ARMSTATE_INITIALIZATION": ArmState.INITIALIZATION,
    "ARMSTATE_IN_FAULT": ArmState.IN_FAULT,
    "ARMSTATE_MAINTENANCE": ArmState.MAINTENANCE,
    "ARMSTATE_SERVOING_LOW_LEVEL": ArmState.SERVOING_LOW_LEVEL,
    "ARMSTATE_SERVOING_READY": ArmState.SERVOING_READY,
    "ARMSTATE_SERVOING_PLAYING_SEQUENCE": ArmState.SERVOING_PLAYING_SEQUENCE,
    "ARMSTATE_SERVOING_MANUALLY_CONTROLLED": ArmState.SERVOING_MANUALLY_CONTROLLED,
}

_SERVOING_MODES = {
    ServoingMode.SINGLE_LEVEL_SERVOING: "SINGLE_LEVEL_SERVOING",
    ServoingMode.LOW_LEVEL_SERVOING: "LOW_LEVEL_SERVOING",
}


def arm_state_from_kortex(name: str) -> ArmState:
    """A Kortex ``ArmState`` enum name (``Common_pb2.ArmState.Name(value)``) -> :class:`ArmState`.
    Unknown names (e.g. ``ARMSTATE_RESERVED``) read as in fault: never as ready."""
    return _ARM_STATES.get(name, ArmState.IN_FAULT)


def servoing_mode_name(mode: ServoingMode) -> str:
    """:class:`ServoingMode` -> the Kortex ``Base_pb2.ServoingMode`` enum name."""
    return _SERVOING_MODES[ServoingMode(mode)]


def faults_from_banks(base_bank_a: int, base_bank_b: int, actuator_banks: Sequence[int],
                      arm_state: ArmState) -> Fault:
    """Summarise Kortex fault banks: any non-zero bank is a hardware fault; in fault with empty
    banks (as after ApplyEmergencyStop) is an emergency stop."""
    faults = Fault.NONE
    if base_bank_a or base_bank_b or any(actuator_banks):
        faults |= Fault.HARDWARE
    if arm_state == ArmState.IN_FAULT and faults == Fault.NONE:
        faults |= Fault.EMERGENCY_STOP
    return faults


def feedback_from_values(*, timestamp: float, frame_id: int, positions_deg, velocities_deg_s,
                         torques_nm, arm_state_name: str, base_bank_a: int = 0,
                         base_bank_b: int = 0, actuator_banks: Sequence[int] = (),
                         reference: np.ndarray | None = None,
                         continuous: np.ndarray | None = None,
                         range_centre: np.ndarray | None = None) -> Feedback:
    """A :class:`Feedback` (SI, radians) from the plain values of a BaseCyclic feedback frame;
    ``continuous`` and ``range_centre`` as in :func:`unwrap_positions`."""
    positions = degrees_to_radians(positions_deg)
    if continuous is None:
        continuous = np.zeros(positions.size, dtype=bool)
    state = arm_state_from_kortex(arm_state_name)
    return Feedback(timestamp=float(timestamp), frame_id=int(frame_id),
                    position=unwrap_positions(positions, reference, continuous, range_centre),
                    velocity=degrees_to_radians(velocities_deg_s),
                    torque=np.asarray(torques_nm, dtype=float),
                    arm_state=state,
                    faults=faults_from_banks(base_bank_a, base_bank_b, actuator_banks, state))


# ---------------------------------------------------------------------------------------------
# Credentials
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Credentials:
    """A Kortex login. ``repr`` and ``str`` never show the password."""

    username: str
    password: str = dataclasses.field(repr=False)

    def __repr__(self) -> str:
        return f"Credentials(username={self.username!r}, password='***')"

    __str__ = __repr__


def _c_escape(text: str, *, octal_utf8: bool) -> str:
    """C-style escaping as protobuf's text format writes a string (``CEscape``): ``\\n \\r \\t``,
    backslash-escaped quotes and backslash, other control bytes in octal; non-ASCII kept as is, or
    (``octal_utf8``) each UTF-8 byte as a 3-digit octal escape (``é`` -> ``\\303\\251``)."""
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t", '"': '\\"', "'": "\\'",
             "\\": "\\\\"}
    out = []
    for char in text:
        if char in named:
            out.append(named[char])
        elif ord(char) < 0x20 or ord(char) == 0x7F or (octal_utf8 and ord(char) > 0x7F):
            out.extend(f"\\{byte:03o}" for byte in char.encode("utf-8", "surrogatepass"))
        else:
            out.append(char)
    return "".join(out)


def _inner(quoted: str) -> str:
    """A quoted literal without its quotes (and a ``b`` prefix): ``'a\\'b'`` -> ``a\\'b``."""
    return quoted[2:-1] if quoted[:1] == "b" else quoted[1:-1]


#: The ways a library may echo a string into an exception or a log line, each as text -> text.
#: :func:`secret_variants` composes them twice (an escaped echo inside an escaped echo, e.g. the
#: repr of an exception whose message holds a repr).
_ENCODINGS = (
    lambda s: _inner(repr(s)),  # Python repr: \\ \' \n, non-printable as \x.. \u....
    lambda s: _inner(ascii(s)),  # repr with non-ASCII escaped
    lambda s: s.encode("unicode_escape").decode("ascii"),  # like ascii(), quotes unescaped
    lambda s: _inner(repr(s.encode("utf-8", "surrogatepass"))),  # bytes repr: \xc3\xa9
    lambda s: _inner(json.dumps(s)),  # JSON, \u00e9 and surrogate pairs
    lambda s: _inner(json.dumps(s, ensure_ascii=False)),  # JSON, non-ASCII kept
    lambda s: urllib.parse.quote(s, safe=""),  # URL encoding (userinfo, form values)
    lambda s: urllib.parse.quote(s),  # ... with '/' kept (quote's default)
    lambda s: urllib.parse.quote_plus(s),  # form encoding: ' ' -> '+'
    lambda s: urllib.parse.quote_plus(s, safe="/"),
    lambda s: _c_escape(s, octal_utf8=False),  # protobuf text format (as_utf8=True)
    lambda s: _c_escape(s, octal_utf8=True),  # protobuf text format, UTF-8 bytes in octal
    lambda s: html.escape(s),  # XML / HTML bodies
    lambda s: s.encode("utf-8", "surrogatepass").decode("latin-1"),  # UTF-8 read as Latin-1
)

_HEX_ESCAPE = re.compile(r"(%|\\x)([0-9a-fA-F]{2})|(\\u)([0-9a-fA-F]{4})|(\\U)([0-9a-fA-F]{8})")


def _hex_case(text: str, case) -> str:
    """``text`` with the digits of its hex escapes (``%2f``, ``\\xc3``, ``\\u00e9``) in ``case``."""
    def repl(match: re.Match) -> str:
        prefix, digits = next((match.group(i), match.group(i + 1)) for i in (1, 3, 5)
                              if match.group(i) is not None)
        return prefix + case(digits)
    return _HEX_ESCAPE.sub(repl, text)


def _encodings(text: str) -> set[str]:
    """``text`` under each of :data:`_ENCODINGS` (an encoding that cannot take it is skipped,
    e.g. URL encoding of a lone surrogate)."""
    out = set()
    for encode in _ENCODINGS:
        try:
            out.add(encode(text))
        except (UnicodeError, ValueError):
            pass
    return out


def secret_variants(secret: str) -> frozenset[str]:
    """``secret`` as every encoding of :data:`_ENCODINGS` may echo it: the literal, each encoding,
    each encoding of an encoding, and each with its hex escapes in upper and lower case."""
    variants = {secret}
    for _ in range(2):
        variants |= set().union(*(_encodings(v) for v in variants))
    variants |= {_hex_case(v, case) for v in variants for case in (str.upper, str.lower)}
    return frozenset(v for v in variants if v)


@functools.lru_cache(maxsize=8)
def _scrubber(secrets: tuple[str, ...]) -> re.Pattern | None:
    variants = set().union(*(secret_variants(s) for s in secrets if s))
    if not variants:
        return None
    # Longest first: at each position the longest echo wins, so no tail of one is left behind.
    return re.compile("|".join(re.escape(v) for v in sorted(variants, key=lambda v: (-len(v), v))))


def scrub(text: str, secrets: Sequence[str]) -> str:
    """``text`` with every echo of every non-empty secret replaced by ``***``: the literal and its
    escaped forms (repr, bytes repr, JSON, URL/form encoding, protobuf text format escapes in
    octal, HTML; see :func:`secret_variants`)."""
    pattern = _scrubber(tuple(secrets))
    if pattern is None:
        return text
    for _ in range(3):  # an echo may surface only once a longer overlapping one is gone
        scrubbed = pattern.sub("***", text)
        if scrubbed == text:
            break
        text = scrubbed
    return text


def load_credentials(file: str | Path | None = None, env: Mapping[str, str] | None = None,
                     repository_root: Path = REPOSITORY_ROOT) -> Credentials:
    """Credentials from ``file`` (or ``$KORTEX_CREDENTIALS_FILE``), else from
    ``$KORTEX_USERNAME`` / ``$KORTEX_PASSWORD``.

    The file holds two lines, ``username`` then ``password``, and must lie outside the repository
    (so it can never be committed). Errors name the file or variable, never a secret.
    """
    env = os.environ if env is None else env
    file = file if file is not None else env.get(CREDENTIALS_FILE_ENV)
    if file:
        path = Path(file).expanduser().resolve()
        root = Path(repository_root).resolve()
        if path == root or root in path.parents:
            raise CredentialsError(f"credentials file {path} is inside the repository ({root}); "
                                   "keep it outside so it is never committed")
        try:
            lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        except OSError as error:
            raise CredentialsError(f"cannot read credentials file {path}: {error.strerror}") from None
        if len(lines) != 2:
            raise CredentialsError(f"credentials file {path} must hold 2 non-empty lines "
                                   f"(username, password), found {len(lines)}")
        return Credentials(lines[0], lines[1])
    username, password = env.get(USERNAME_ENV), env.get(PASSWORD_ENV)
    if not username or not password:
        missing = USERNAME_ENV if not username else PASSWORD_ENV
        raise CredentialsError(f"no Kortex credentials: set {USERNAME_ENV} and {PASSWORD_ENV}, or "
                               f"{CREDENTIALS_FILE_ENV} / kortex.credentials_file to a file outside "
                               f"the repository ({missing} is missing)")
    return Credentials(username, password)


def import_kortex_api() -> dict:
    """The vendor modules the backend uses, or :class:`KortexNotInstalledError`."""
    names = {
        "TCPTransport": "kortex_api.TCPTransport",
        "RouterClient": "kortex_api.RouterClient",
        "SessionManager": "kortex_api.SessionManager",
        "BaseClientRpc": "kortex_api.autogen.client_stubs.BaseClientRpc",
        "BaseCyclicClientRpc": "kortex_api.autogen.client_stubs.BaseCyclicClientRpc",
        "Base_pb2": "kortex_api.autogen.messages.Base_pb2",
        "Common_pb2": "kortex_api.autogen.messages.Common_pb2",
        "Session_pb2": "kortex_api.autogen.messages.Session_pb2",
    }
    try:
        return {key: importlib.import_module(module) for key, module in names.items()}
    except ImportError:
        raise KortexNotInstalledError(INSTALL_HINT) from None


# ---------------------------------------------------------------------------------------------
# The adapter
# ---------------------------------------------------------------------------------------------


class KortexArm(ArmAdapter):
    """A Gen3-family arm over ``kortex_api`` (TCP transport, router, session, BaseClient,
    BaseCyclicClient).

    Args:
        robot: the arm model the controller was trained on; its joint count must match the arm.
        address: the arm's IP address, required (no default is ever contacted).
        credentials: the login (:func:`load_credentials`).
        port: Kortex TCP port (10000).
        session_inactivity_timeout_ms, connection_inactivity_timeout_ms: the arm closes the
            session / stops itself when the link is silent this long.
        api: the vendor modules (default :func:`import_kortex_api`; tests pass fakes).
    """

    def __init__(self, robot: RobotDescription, address: str, credentials: Credentials, *,
                 port: int = 10000, session_inactivity_timeout_ms: int = 60000,
                 connection_inactivity_timeout_ms: int = 2000, api: dict | None = None) -> None:
        if not isinstance(address, str) or not address.strip():
            raise HardwareError("the Kortex backend needs the arm's address explicitly "
                                f"(got {address!r}); there is no default")
        self._robot = robot
        self._address, self._port = address.strip(), int(port)
        self._credentials = credentials
        self._session_timeout = int(session_inactivity_timeout_ms)
        self._connection_timeout = int(connection_inactivity_timeout_ms)
        self._api = api
        self._clock = WallClock()
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._previous: np.ndarray | None = None
        self._frame = 0
        limited = robot.limited
        self._range_centre = np.where(
            limited, 0.5 * (np.where(limited, robot.position_lower, 0.0)
                            + np.where(limited, robot.position_upper, 0.0)), 0.0)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._robot.joint_names

    @property
    def velocity_limit(self) -> np.ndarray:
        return self._robot.velocity_limit.copy()

    @property
    def is_connected(self) -> bool:
        return self._connected

    def _secret_free(self, error: BaseException) -> str:
        return scrub(f"{type(error).__name__}: {error}", [self._credentials.password])

    def _require(self) -> None:
        if not self._connected:
            raise NotConnectedError(f"KortexArm({self._address}) is not connected; call connect()")

    def connect(self) -> None:
        if self._connected:
            raise HardwareError(f"KortexArm({self._address}) is already connected")
        api = self._api if self._api is not None else import_kortex_api()
        self._api = api
        try:
            self._transport = api["TCPTransport"].TCPTransport()
            self._router = api["RouterClient"].RouterClient(self._transport, lambda e: None)
            self._transport.connect(self._address, self._port)
            info = api["Session_pb2"].CreateSessionInfo()
            info.username = self._credentials.username
            info.password = self._credentials.password
            info.session_inactivity_timeout = self._session_timeout
            info.connection_inactivity_timeout = self._connection_timeout
            self._session = api["SessionManager"].SessionManager(self._router)
            self._session.CreateSession(info)
            self._base = api["BaseClientRpc"].BaseClient(self._router)
            self._cyclic = api["BaseCyclicClientRpc"].BaseCyclicClient(self._router)
        except Exception as error:  # the vendor's errors may echo the request: scrub them
            failure = self._secret_free(error)
        else:
            failure = None
        if failure is not None:  # raised outside the handler: no chained vendor exception
            log.error("kortex: connecting to %s:%d failed: %s", self._address, self._port, failure)
            raise HardwareError(f"connecting to the arm at {self._address}:{self._port} failed: "
                                f"{failure}")
        self._connected = True
        try:  # a failure from here on closes the session it opened (scrubbed, like every call)
            actuators = len(self._call("RefreshFeedback", self._cyclic.RefreshFeedback).actuators)
            if actuators != self._robot.num_joints:
                raise HardwareError(f"the arm at {self._address} has {actuators} actuators; the "
                                    f"deployed model {self._robot.name!r} has "
                                    f"{self._robot.num_joints} joints: the trained arm model must "
                                    "match the arm")
            self.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
            self.stop()
        except HardwareError:
            self.disconnect()
            raise
        log.info("kortex: connected to %s:%d as %s", self._address, self._port,
                 self._credentials.username)

    def disconnect(self) -> None:
        if not self._connected:
            return
        try:
            self._base.Stop()
        except Exception as error:
            log.error("kortex: stop on disconnect failed: %s", self._secret_free(error))
        try:
            self._session.CloseSession()
            self._transport.disconnect()
        except Exception as error:
            log.error("kortex: closing the session failed: %s", self._secret_free(error))
        self._connected = False

    def _call(self, what: str, fn, *args):
        """``fn(*args)``; a vendor exception becomes a scrubbed :class:`HardwareError`, raised
        outside the handler so the original (which may echo a secret) is not chained."""
        try:
            return fn(*args)
        except Exception as error:
            message = self._secret_free(error)
        lowered = message.lower()
        if "timeout" in lowered:
            raise FeedbackTimeoutError(f"{what}: {message}")
        if "connection" in lowered or "transport" in lowered:
            self._connected = False
            raise ConnectionLostError(f"{what}: {message}")
        raise HardwareError(f"{what}: {message}")

    def refresh_feedback(self) -> Feedback:
        self._require()
        raw = self._call("RefreshFeedback", self._cyclic.RefreshFeedback)
        names = self._api["Common_pb2"].ArmState.Name
        actuators = raw.actuators
        self._frame = max(self._frame + 1, int(getattr(raw, "frame_id", 0)))
        frame = feedback_from_values(
            timestamp=self._clock.now(), frame_id=self._frame,
            positions_deg=[a.position for a in actuators],
            velocities_deg_s=[a.velocity for a in actuators],
            torques_nm=[a.torque for a in actuators],
            arm_state_name=names(raw.base.active_state),
            base_bank_a=raw.base.fault_bank_a, base_bank_b=raw.base.fault_bank_b,
            actuator_banks=[a.fault_bank_a for a in actuators],
            reference=self._previous, continuous=~self._robot.limited,
            range_centre=self._range_centre)
        self._previous = frame.position
        return frame

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        self._require()
        try:
            command = check_joint_speeds(speeds, self._robot.velocity_limit)
        except CommandRefusedError:
            self.apply_emergency_stop()
            raise
        if self._mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise ArmFaultError("joint speed commands need single-level servoing")
        message = self._api["Base_pb2"].JointSpeeds()
        for entry in joint_speeds_message(command):
            item = message.joint_speeds.add()
            item.joint_identifier = entry["joint_identifier"]
            item.value = entry["value"]
            item.duration = entry["duration"]
        self._call("SendJointSpeedsCommand", self._base.SendJointSpeedsCommand, message)
        return command

    def stop(self) -> None:
        self._require()
        self._call("Stop", self._base.Stop)

    def apply_emergency_stop(self) -> None:
        self._require()
        self._call("ApplyEmergencyStop", self._base.ApplyEmergencyStop)

    def clear_faults(self) -> None:
        self._require()
        self._call("ClearFaults", self._base.ClearFaults)

    @property
    def servoing_mode(self) -> ServoingMode:
        self._require()
        return self._mode

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self._require()
        base_pb2 = self._api["Base_pb2"]
        info = base_pb2.ServoingModeInformation()
        info.servoing_mode = getattr(base_pb2, servoing_mode_name(mode))
        self._call("SetServoingMode", self._base.SetServoingMode, info)
        self._mode = ServoingMode(mode)
