"""The Kortex backend: a Kinova Gen3-family arm over the vendor's ``kortex_api``.

``kortex_api`` is not on PyPI; it is an optional extra (see :data:`INSTALL_HINT` and
docs/hardware.md). Kortex drives the Gen3 family (Gen3, Gen3 lite), not the JACO Gen2 the default
task models: the arm model the policy was trained on must match the arm deployed (joint count,
limits, kinematics); :meth:`KortexArm.connect` refuses an arm whose actuator count differs.

Safety of the link, each number from ``configs/deploy.yaml``'s ``kortex`` section
(:func:`kortex_options`):

* **Explicit timeouts.** Every RPC carries its own ``RouterClientSendOptions.timeout_ms``
  (``rpc_timeout_ms`` for feedback and motion, ``session_rpc_timeout_ms`` for the login), never the
  vendor's 10 s default: a hung call fails in time instead of freezing the control loop.
* **Command watchdog.** Kortex joint-speed commands never expire on the arm (``JointSpeed.duration``
  is not implemented; Kinovarobotics/ros_kortex issues 159 and 347): a client that stops sending
  leaves the arm moving. :class:`CommandWatchdog`, a thread of the adapter, sends ``Base.Stop`` when
  no fresh command came for ``watchdog_periods`` control periods while the arm was commanded to
  move, and latches (commands raise :class:`~hardware.protocol.ArmFaultError`, feedback carries
  ``Fault.COMMUNICATION``) until :meth:`KortexArm.clear_faults`. The arm's own
  ``connection_inactivity_timeout`` does not cover a stalled control loop: the vendor's
  ``SessionManager`` sends KeepAlive every 150 ms from its own thread while the process lives.
* **Staleness from the arm's own clock.** BaseCyclic's ``Feedback`` carries no timestamp; its
  ``frame_id`` counts the arm's cyclic frames. :class:`ArmClock` unwraps that counter (modulo
  ``frame_id_modulus``, one tick = ``feedback_tick_ms``) into the arm's time and maps it onto the
  adapter's clock, so a repeated, replayed or late frame has an old :attr:`Feedback.timestamp` and
  a non-increasing :attr:`Feedback.frame_id`: the deploy loop's stale check fires on it.
* **Faults.** Motion commands raise :class:`~hardware.protocol.ArmFaultError` while the arm reports
  a fault, after an e-stop, after a watchdog stop, or when the arm refuses them as in fault.
  :meth:`KortexArm.clear_faults` runs ros2_kortex's reset sequence (single-level servoing,
  ``ApplyEmergencyStop`` twice, ``ClearFaults``), then waits (polling feedback) until the arm has
  left fault, then restores the servoing mode and stops.

Everything that can be done without the vendor library is a pure function or class here and is
tested without it: degree/radian conversion (Kortex speaks degrees; this protocol radians),
unwrapping of continuous joints, the joint-speed message as plain values, the arm-state and fault
mapping, the arm clock, the watchdog, and the credentials (from environment variables or a file
outside the repository, never logged, never in an error message: :func:`scrub`). The adapter itself
is tested against a fake ``kortex_api`` (tests/fake_kortex_api) that simulates an arm.

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
import threading
import time
import types
import urllib.parse
import weakref
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ahrm_stack.robot import RobotDescription
from hardware.protocol import (DescribedArm, ArmFaultError, ArmState, CommandRefusedError,
                               ConnectionLostError, Fault, Feedback, FeedbackTimeoutError,
                               HardwareError, NotConnectedError, ServoingMode, WallClock,
                               check_joint_speeds, range_centres, unwrap_positions)

log = logging.getLogger(__name__)

REPOSITORY_ROOT = Path(__file__).resolve().parent.parent
USERNAME_ENV = "KORTEX_USERNAME"
PASSWORD_ENV = "KORTEX_PASSWORD"
CREDENTIALS_FILE_ENV = "KORTEX_CREDENTIALS_FILE"
INSTALL_HINT = (
    "kortex_api is not installed. It is not on PyPI: download Kinova's wheel "
    "kortex_api-2.6.0.post3-py3-none-any.whl from Kinova's Artifactory "
    "(https://artifactory.kinovaapps.com:443/artifactory/generic-public/kortex/API/2.6.0/"
    "kortex_api-2.6.0.post3-py3-none-any.whl) and run `python3 -m pip install "
    "kortex_api-2.6.0.post3-py3-none-any.whl`. That wheel pins protobuf==3.5.1, which fails to "
    "import on Python >= 3.10; there, Kinova's workaround is `pip install protobuf==3.20 "
    "deprecated==1.2.7` then `pip install kortex_api-2.6.0.post3-py3-none-any.whl --no-deps` "
    "(Kinovarobotics/Kinova-kortex2_Gen3_G3L issue 191). See docs/hardware.md.")


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


#: The vendor modules the backend uses, keyed as the adapter reads them.
KORTEX_MODULES = {
    "TCPTransport": "kortex_api.TCPTransport",
    "RouterClient": "kortex_api.RouterClient",
    "SessionManager": "kortex_api.SessionManager",
    "BaseClientRpc": "kortex_api.autogen.client_stubs.BaseClientRpc",
    "BaseCyclicClientRpc": "kortex_api.autogen.client_stubs.BaseCyclicClientRpc",
    "Base_pb2": "kortex_api.autogen.messages.Base_pb2",
    "Common_pb2": "kortex_api.autogen.messages.Common_pb2",
    "Session_pb2": "kortex_api.autogen.messages.Session_pb2",
    "Errors_pb2": "kortex_api.autogen.messages.Errors_pb2",
    "KServerException": "kortex_api.Exceptions.KServerException",
    "KClientException": "kortex_api.Exceptions.KClientException",
}


def import_kortex_api() -> dict:
    """The vendor modules the backend uses (:data:`KORTEX_MODULES`), or
    :class:`KortexNotInstalledError`."""
    try:
        return {key: importlib.import_module(module) for key, module in KORTEX_MODULES.items()}
    except ImportError:
        raise KortexNotInstalledError(INSTALL_HINT) from None


# ---------------------------------------------------------------------------------------------
# Settings, the arm's clock and the command watchdog (pure; tested without kortex_api)
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class KortexOptions:
    """The backend's numbers (``configs/deploy.yaml``, ``kortex``; see :func:`kortex_options`).

    Attributes:
        port: Kortex TCP port.
        session_inactivity_timeout_ms, connection_inactivity_timeout_ms: the arm closes the
            session / stops itself when the link is silent this long (ms).
        rpc_timeout_ms: timeout of every feedback, motion and mode RPC (ms).
        session_rpc_timeout_ms: timeout of CreateSession / CloseSession (ms).
        watchdog_timeout: s without a fresh command (while moving) before the watchdog stops the arm.
        watchdog_poll: s between two checks of the watchdog thread.
        reset_wait: s :meth:`KortexArm.clear_faults` waits for the arm to leave fault.
        reset_poll: s between two feedback polls during that wait.
        reset_estop_repeats: ApplyEmergencyStop calls before ClearFaults (ros2_kortex: 2).
        feedback_tick: s per step of ``Feedback.frame_id`` (the arm's cyclic period).
        frame_id_modulus: ``frame_id`` wraps to 0 at this value.
    """

    port: int
    session_inactivity_timeout_ms: int
    connection_inactivity_timeout_ms: int
    rpc_timeout_ms: int
    session_rpc_timeout_ms: int
    watchdog_timeout: float
    watchdog_poll: float
    reset_wait: float
    reset_poll: float
    reset_estop_repeats: int
    feedback_tick: float
    frame_id_modulus: int


def kortex_options(settings) -> KortexOptions:
    """:class:`KortexOptions` from validated deploy settings (``ahrm_stack.deploy.DeploySettings``:
    its ``kortex`` section and control ``period``, s)."""
    k, period = settings.kortex, settings.period
    return KortexOptions(
        port=k.port, session_inactivity_timeout_ms=k.session_inactivity_timeout_ms,
        connection_inactivity_timeout_ms=k.connection_inactivity_timeout_ms,
        rpc_timeout_ms=k.rpc_timeout_ms, session_rpc_timeout_ms=k.session_rpc_timeout_ms,
        watchdog_timeout=k.watchdog_periods * period, watchdog_poll=k.watchdog_poll_periods * period,
        reset_wait=k.reset_wait_ms / 1e3, reset_poll=k.reset_poll_ms / 1e3,
        reset_estop_repeats=k.reset_estop_repeats, feedback_tick=k.feedback_tick_ms / 1e3,
        frame_id_modulus=k.frame_id_modulus)


class ArmClock:
    """The arm's own time, from BaseCyclic ``Feedback.frame_id`` (which counts the arm's cyclic
    frames, ``tick`` s apart, wrapping at ``modulus``), mapped onto the adapter's clock.

    :meth:`update` unwraps the counter (a step of more than half the modulus backwards is a frame
    from the past, not a wrap) into ``ticks`` since the first frame, and keeps ``offset``, the
    smallest ``now - ticks * tick`` seen (the arm's clock plus the fastest round trip). A frame's
    timestamp is ``ticks * tick + offset``: a fresh frame is stamped about ``now``; a repeated,
    replayed or late frame keeps the arm's (old) measurement time, however late it arrives.
    """

    def __init__(self, tick: float, modulus: int) -> None:
        if not tick > 0 or int(modulus) < 2:
            raise ValueError(f"ArmClock needs tick > 0 and modulus >= 2, got {tick!r}, {modulus!r}")
        self.tick, self.modulus = float(tick), int(modulus)
        self._raw: int | None = None  # the last counter value that moved time forward
        self._ticks = 0
        self.offset = float("inf")

    def update(self, raw_frame_id: int, now: float) -> tuple[int, float]:
        """(frame id, timestamp in s on the adapter's clock) of a frame with counter
        ``raw_frame_id`` received at ``now`` (s). The frame id is the unwrapped tick count: it
        repeats for a repeated frame and goes back for an older one."""
        raw = int(raw_frame_id) % self.modulus
        if self._raw is None:
            ticks = 0
        else:
            step = (raw - self._raw) % self.modulus
            if step > self.modulus // 2:
                step -= self.modulus  # older than the last frame
            ticks = self._ticks + step
        if self._raw is None or ticks > self._ticks:
            self._raw, self._ticks = raw, ticks
        arm_time = ticks * self.tick
        self.offset = min(self.offset, now - arm_time)
        return ticks, arm_time + self.offset


class CommandWatchdog:
    """Stops the arm when commands stop coming (Kortex joint speeds never expire on the arm).

    :meth:`commanded` records each command (and whether it moves the arm). A daemon thread calls
    :meth:`check` every ``poll`` s: when the last moving command is older than ``timeout`` s it
    calls ``on_expire(age)`` once (age in s) and latches :attr:`tripped` until :meth:`reset`; a
    tripped watchdog refuses further commands (:meth:`commanded` returns False).

    Args:
        timeout: s without a fresh command before the arm is stopped.
        poll: s between two checks.
        on_expire: called from the watchdog thread with the command's age (s); sends the stop.
            A bound method is held weakly: the thread ends when its object is gone (an adapter
            dropped without :meth:`close` leaves no thread behind).
        clock: seconds, monotonic (``time.perf_counter``; tests pass their own).
    """

    def __init__(self, timeout: float, poll: float, on_expire, clock=time.perf_counter) -> None:
        if not (timeout > 0 and 0 < poll <= timeout):
            raise ValueError(f"CommandWatchdog needs 0 < poll <= timeout, got {poll!r}, {timeout!r}")
        self.timeout, self.poll = float(timeout), float(poll)
        self._on_expire = (weakref.WeakMethod(on_expire) if isinstance(on_expire, types.MethodType)
                           else (lambda: on_expire))
        self._clock = clock
        self._lock = threading.Lock()
        self._last: float | None = None
        self._armed = False
        self.tripped = False
        self.trips = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the checking thread (a no-op when it runs)."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="kortex-command-watchdog",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the checking thread (it is a no-op when called from that thread)."""
        self._stop.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=max(1.0, 10 * self.poll))
        self._thread = None

    def commanded(self, moving: bool) -> bool:
        """A command is about to be sent (``moving``: any non-zero speed). False when tripped:
        the command must not be sent."""
        with self._lock:
            if self.tripped:
                return False
            self._last = self._clock()
            self._armed = bool(moving)
            return True

    def disarm(self) -> None:
        """The arm was stopped: nothing to watch until the next moving command."""
        with self._lock:
            self._armed = False

    def reset(self) -> None:
        """Leave the tripped state (after the arm's faults were cleared)."""
        with self._lock:
            self.tripped = False
            self._armed = False

    def check(self) -> bool:
        """One check; True when it tripped now (``on_expire`` was called)."""
        with self._lock:
            if not self._armed or self._last is None:
                return False
            age = self._clock() - self._last
            if age <= self.timeout:
                return False
            self._armed = False
            self.tripped = True
            self.trips += 1
        on_expire = self._on_expire()
        if on_expire is not None:
            on_expire(age)
        return True

    def _run(self) -> None:
        while not self._stop.wait(self.poll):
            if self._on_expire() is None:  # the adapter is gone
                return
            try:
                self.check()
            except Exception:  # noqa: BLE001 - the thread must survive a failing stop
                log.exception("kortex: the command watchdog's stop failed")


# ---------------------------------------------------------------------------------------------
# The adapter
# ---------------------------------------------------------------------------------------------

#: Errors_pb2.SubErrorCodes names that mean "the arm is in fault / not accepting motion".
_FAULT_SUB_CODES = ("ROBOT_IN_FAULT", "ROBOT_IN_EMERGENCY_STOP", "WRONG_SERVOING_MODE")


class KortexArm(DescribedArm):
    """A Gen3-family arm over ``kortex_api`` (TCP transport, router, session, BaseClient,
    BaseCyclicClient).

    Args:
        robot: the arm model the controller was trained on; its joint count must match the arm.
        address: the arm's IP address, required (no default is ever contacted).
        credentials: the login (:func:`load_credentials`).
        options: every number of the link (:class:`KortexOptions`, :func:`kortex_options`).
        api: the vendor modules (default :func:`import_kortex_api`; tests pass fakes).
        clock: the adapter's clock (default :class:`WallClock`: real time); the watchdog and the
            feedback timestamps use it. Tests pass a ``FastClock`` shared with a fake arm.
    """

    def __init__(self, robot: RobotDescription, address: str, credentials: Credentials,
                 options: KortexOptions, *, api: dict | None = None,
                 clock: WallClock | None = None) -> None:
        if not isinstance(address, str) or not address.strip():
            raise HardwareError("the Kortex backend needs the arm's address explicitly "
                                f"(got {address!r}); there is no default")
        self._robot = robot
        self._address, self._options = address.strip(), options
        self._port = int(options.port)
        self._credentials = credentials
        self._api = api
        self._clock = clock if clock is not None else WallClock()
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._wanted_mode = ServoingMode.SINGLE_LEVEL_SERVOING  # what clear_faults restores
        self._previous: np.ndarray | None = None
        self._arm_clock = ArmClock(options.feedback_tick, options.frame_id_modulus)
        self._estopped = False  # we e-stopped the arm; latched until clear_faults()
        self._arm_in_fault = False  # the last feedback reported a fault
        self._watchdog = CommandWatchdog(options.watchdog_timeout, options.watchdog_poll,
                                         self._watchdog_expired, clock=self._clock.now)
        self._range_centre = range_centres(robot)

    @property
    def watchdog(self) -> CommandWatchdog:
        """The command watchdog (its :attr:`~CommandWatchdog.trips` count stops it made)."""
        return self._watchdog

    def _secret_free(self, error: BaseException) -> str:
        return scrub(f"{type(error).__name__}: {error}", [self._credentials.password])

    def _require(self) -> None:
        if not self._connected:
            raise NotConnectedError(f"KortexArm({self._address}) is not connected; call connect()")

    # ------------------------------------------------------------------ RPCs
    def _send_options(self, timeout_ms: int):
        options = self._api["RouterClient"].RouterClientSendOptions()
        options.timeout_ms = int(timeout_ms)
        return options

    def _classify(self, error: BaseException) -> str:
        """'timeout', 'fault', 'connection' or 'other' for a vendor exception."""
        if isinstance(error, TimeoutError):  # concurrent.futures.TimeoutError since 3.11
            return "timeout"
        server = getattr(self._api.get("KServerException"), "KServerException", None)
        client = getattr(self._api.get("KClientException"), "KClientException", None)
        if server is not None and isinstance(error, server):
            try:
                name = self._api["Errors_pb2"].SubErrorCodes.Name(error.get_error_sub_code())
            except Exception:  # noqa: BLE001 - an unknown code is a plain error
                name = ""
            if name == "METHOD_TIMEOUT":
                return "timeout"
            return "fault" if name in _FAULT_SUB_CODES else "other"
        if client is not None and isinstance(error, client):
            return "connection"
        lowered = f"{type(error).__name__}: {error}".lower()
        if "timeout" in lowered:
            return "timeout"
        if "connection" in lowered or "transport" in lowered:
            return "connection"
        return "other"

    def _call(self, what: str, fn, *args, timeout_ms: int):
        """``fn(*args, options=...)`` with an explicit ``timeout_ms``; a vendor exception becomes a
        scrubbed :class:`HardwareError` (timeout: :class:`FeedbackTimeoutError`; the arm in fault:
        :class:`ArmFaultError`; the link: :class:`ConnectionLostError`), raised outside the
        handler so the original (which may echo a secret) is not chained."""
        try:
            return fn(*args, options=self._send_options(timeout_ms))
        except Exception as error:
            kind, message = self._classify(error), self._secret_free(error)
        if kind == "timeout":
            raise FeedbackTimeoutError(f"{what}: no answer within {timeout_ms} ms ({message})")
        if kind == "fault":
            self._arm_in_fault = True
            raise ArmFaultError(f"{what}: the arm refused it in fault ({message}); "
                                "clear_faults() first")
        if kind == "connection":
            self._lose()
            raise ConnectionLostError(f"{what}: {message}")
        raise HardwareError(f"{what}: {message}")

    def _rpc(self, what: str, fn, *args):
        return self._call(what, fn, *args, timeout_ms=self._options.rpc_timeout_ms)

    def _lose(self) -> None:
        """The link dropped: the arm's own connection watchdog stops it; we are disconnected."""
        self._connected = False
        self._watchdog.close()

    # ------------------------------------------------------------------ session
    def connect(self) -> None:
        if self._connected:
            raise HardwareError(f"KortexArm({self._address}) is already connected")
        api = self._api if self._api is not None else import_kortex_api()
        self._api = api
        options = self._options
        try:
            self._transport = api["TCPTransport"].TCPTransport()
            self._router = api["RouterClient"].RouterClient(self._transport, lambda e: None)
            self._transport.connect(self._address, self._port)
            info = api["Session_pb2"].CreateSessionInfo()
            info.username = self._credentials.username
            info.password = self._credentials.password
            info.session_inactivity_timeout = options.session_inactivity_timeout_ms
            info.connection_inactivity_timeout = options.connection_inactivity_timeout_ms
            self._session = api["SessionManager"].SessionManager(self._router)
            self._session.CreateSession(
                info, options=self._send_options(options.session_rpc_timeout_ms))
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
        self._arm_clock = ArmClock(options.feedback_tick, options.frame_id_modulus)
        self._previous = None
        try:  # a failure from here on closes the session it opened (scrubbed, like every call)
            first = self._rpc("RefreshFeedback", self._cyclic.RefreshFeedback)
            actuators = len(first.actuators)
            if actuators != self._robot.num_joints:
                raise HardwareError(f"the arm at {self._address} has {actuators} actuators; the "
                                    f"deployed model {self._robot.name!r} has "
                                    f"{self._robot.num_joints} joints: the trained arm model must "
                                    "match the arm")
            self._arm_clock.update(first.frame_id, self._clock.now())
            self.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
            self.stop()
        except HardwareError:
            self.disconnect()
            raise
        self._watchdog.disarm()  # its thread starts with the first moving command
        log.info("kortex: connected to %s:%d as %s", self._address, self._port,
                 self._credentials.username)

    def disconnect(self) -> None:
        self._watchdog.close()
        if not self._connected:
            return
        try:
            self._rpc("Stop", self._base.Stop)
        except HardwareError as error:
            log.error("kortex: stop on disconnect failed: %s", error)
        try:
            self._session.CloseSession(
                options=self._send_options(self._options.session_rpc_timeout_ms))
            self._transport.disconnect()
        except Exception as error:
            log.error("kortex: closing the session failed: %s", self._secret_free(error))
        self._connected = False

    # ------------------------------------------------------------------ protocol
    def refresh_feedback(self) -> Feedback:
        self._require()
        raw = self._rpc("RefreshFeedback", self._cyclic.RefreshFeedback)
        frame_id, stamp = self._arm_clock.update(raw.frame_id, self._clock.now())
        names = self._api["Common_pb2"].ArmState.Name
        actuators = raw.actuators
        try:
            state_name = names(raw.base.active_state)
        except ValueError:
            state_name = "ARMSTATE_UNKNOWN"  # read as in fault
        frame = feedback_from_values(
            timestamp=stamp, frame_id=frame_id,
            positions_deg=[a.position for a in actuators],
            velocities_deg_s=[a.velocity for a in actuators],
            torques_nm=[a.torque for a in actuators],
            arm_state_name=state_name,
            base_bank_a=raw.base.fault_bank_a, base_bank_b=raw.base.fault_bank_b,
            actuator_banks=[a.fault_bank_a | a.fault_bank_b for a in actuators],
            reference=self._previous, continuous=~self._robot.limited,
            range_centre=self._range_centre)
        self._arm_in_fault = frame.arm_state == ArmState.IN_FAULT or frame.faults != Fault.NONE
        if self._watchdog.tripped:  # stopped by the client-side watchdog: a link fault
            frame = dataclasses.replace(frame, faults=frame.faults | Fault.COMMUNICATION)
        if np.isfinite(frame.position).all():
            self._previous = frame.position
        return frame

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        self._require()
        try:
            command = check_joint_speeds(speeds, self._robot.velocity_limit)
        except CommandRefusedError:
            self.apply_emergency_stop()
            raise
        if self._estopped or self._arm_in_fault:
            why = "e-stopped" if self._estopped else "reported by its feedback"
            raise ArmFaultError(f"the arm is in fault ({why}): clear_faults() first")
        if self._mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise ArmFaultError(f"joint speed commands need single-level servoing, not {self._mode}")
        message = self._api["Base_pb2"].JointSpeeds()
        for entry in joint_speeds_message(command):
            item = message.joint_speeds.add()
            item.joint_identifier = entry["joint_identifier"]
            item.value = entry["value"]
            item.duration = entry["duration"]
        moving = bool(np.any(command != 0.0))
        if moving:
            self._watchdog.start()  # a no-op once running
        if not self._watchdog.commanded(moving):
            raise ArmFaultError("the command watchdog stopped the arm (no command came in "
                                f"{self._options.watchdog_timeout * 1e3:.0f} ms): clear_faults() first")
        self._rpc("SendJointSpeedsCommand", self._base.SendJointSpeedsCommand, message)
        if self._watchdog.tripped:  # it fired while this command was on its way: stop again
            self._rpc("Stop", self._base.Stop)
            raise ArmFaultError("the command watchdog stopped the arm while a command was sent: "
                                "clear_faults() first")
        return command

    def _watchdog_expired(self, age: float) -> None:
        """From the watchdog thread: no fresh command for ``age`` s; stop the arm (Base.Stop,
        else zero joint speeds)."""
        log.error("kortex: WATCHDOG: no command for %.1f ms (limit %.1f ms): stopping the arm",
                  age * 1e3, self._options.watchdog_timeout * 1e3)
        if not self._connected:
            return
        try:
            self._rpc("Stop", self._base.Stop)
            return
        except HardwareError as error:
            log.error("kortex: watchdog Stop failed (%s); sending zero joint speeds", error)
        message = self._api["Base_pb2"].JointSpeeds()
        for entry in joint_speeds_message(np.zeros(self._robot.num_joints)):
            item = message.joint_speeds.add()
            item.joint_identifier = entry["joint_identifier"]
            item.value = entry["value"]
            item.duration = entry["duration"]
        self._rpc("SendJointSpeedsCommand", self._base.SendJointSpeedsCommand, message)

    def stop(self) -> None:
        self._require()
        self._rpc("Stop", self._base.Stop)
        self._watchdog.disarm()  # only once the stop got through

    def apply_emergency_stop(self) -> None:
        self._require()
        self._estopped = True
        self._rpc("ApplyEmergencyStop", self._base.ApplyEmergencyStop)
        self._watchdog.disarm()

    def clear_faults(self) -> None:
        """ros2_kortex's reset: single-level servoing, ``ApplyEmergencyStop``
        (``reset_estop_repeats`` times: once proved unreliable there), ``ClearFaults``; then poll feedback every
        ``reset_poll`` s until the arm has left fault (:class:`ArmFaultError` after ``reset_wait``
        s), restore the servoing mode, stop. Clears the e-stop and watchdog latches."""
        self._require()
        options = self._options
        self._set_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
        for _ in range(options.reset_estop_repeats):
            self._rpc("ApplyEmergencyStop", self._base.ApplyEmergencyStop)
        self._rpc("ClearFaults", self._base.ClearFaults)
        deadline = self._clock.now() + options.reset_wait
        while True:
            frame = self.refresh_feedback()
            arm_faults = frame.faults & ~Fault.COMMUNICATION
            if frame.arm_state != ArmState.IN_FAULT and arm_faults == Fault.NONE:
                break
            if self._clock.now() >= deadline:
                raise ArmFaultError(f"clear_faults: the arm is still in fault after "
                                    f"{options.reset_wait * 1e3:.0f} ms (state "
                                    f"{frame.arm_state.value}, flags {arm_faults!r})")
            self._clock.sleep(options.reset_poll)
        self._estopped = False
        self._arm_in_fault = False
        self._watchdog.reset()
        if self._wanted_mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            self._set_mode(self._wanted_mode)
        self.stop()

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self._require()
        self._set_mode(mode)
        self._wanted_mode = ServoingMode(mode)

    def _set_mode(self, mode: ServoingMode) -> None:
        base_pb2 = self._api["Base_pb2"]
        info = base_pb2.ServoingModeInformation()
        info.servoing_mode = getattr(base_pb2, servoing_mode_name(mode))
        self._rpc("SetServoingMode", self._base.SetServoingMode, info)
        self._watchdog.disarm()  # the arm stops when the mode changes
        self._mode = ServoingMode(mode)


# ---------------------------------------------------------------------------------------------
# Deploy wiring
# ---------------------------------------------------------------------------------------------


def make_kortex_backend(settings, robot: RobotDescription, *,
                        credentials: Credentials | None = None, api: dict | None = None,
                        env: Mapping[str, str] | None = None) -> KortexArm:
    """The Kortex adapter for a deploy run, not yet connected.

    Args:
        settings: validated deploy settings (``ahrm_stack.deploy.DeploySettings``): the
            ``kortex`` section (address, credentials file, timeouts, watchdog, reset) and the
            control period.
        robot: the deployed arm model (a checkpoint's own).
        credentials: the login; default :func:`load_credentials` from ``kortex.credentials_file``
            or the environment (``env``, default ``os.environ``).
        api: the vendor modules (default: imported at connect).

    Raises :class:`HardwareError` (one line, naming ``deploy.kortex.address``) without an address
    and :class:`CredentialsError` without credentials; nothing is contacted.
    """
    address = settings.kortex.address
    if not address or not str(address).strip():
        raise HardwareError("deploy.kortex.address is not set: give the arm's IP address in "
                            "configs/deploy.yaml (there is no default)")
    if credentials is None:
        credentials = load_credentials(settings.kortex.credentials_file, env=env)
    return KortexArm(robot, str(address), credentials, kortex_options(settings), api=api)


def kortex_deploy_blocker(settings, env: Mapping[str, str] | None = None) -> str:
    """Why ``python -m ahrm_stack.deploy --backend kortex`` cannot run yet, as one line naming what
    is missing: the address, credentials, real-time pacing, and in any case a scene source (a
    perception module for the cube and obstacle poses, which the controller and the safety filter
    need). A static layout is not used in its place: the cube moves when pushed, so a static pose
    would keep the controller pushing at where the cube was and miss success."""
    if not settings.kortex.address:
        return ("--backend kortex: deploy.kortex.address is not set (the arm's IP address; there "
                "is no default)")
    try:
        load_credentials(settings.kortex.credentials_file, env=env)
    except CredentialsError as error:
        return f"--backend kortex: {error}"
    if not settings.realtime:
        return "--backend kortex: --fast / deploy.realtime false is for the sim backend only"
    return ("--backend kortex: no scene source for the cube and obstacle poses (a perception "
            "module) exists yet; the arm was not contacted (hardware.kortex.make_kortex_backend "
            "builds the adapter once one does)")
