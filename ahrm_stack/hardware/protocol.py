"""The arm adapter protocol, in the vocabulary of Kinova's Kortex API.

One small abstract class, :class:`ArmAdapter`, whose docstrings are the contract every backend
meets (the shared suite in ``tests/test_hardware_contract.py`` checks it):

==========================  =====================================================================
Kortex                      here
==========================  =====================================================================
TCP transport + router +    :meth:`ArmAdapter.connect` / :meth:`ArmAdapter.disconnect`
SessionManager
BaseCyclic.RefreshFeedback  :meth:`ArmAdapter.refresh_feedback` -> :class:`Feedback`
Base.SendJointSpeedsCommand :meth:`ArmAdapter.send_joint_speeds` (all joints at once)
Base.Stop                   :meth:`ArmAdapter.stop`
Base.ApplyEmergencyStop     :meth:`ArmAdapter.apply_emergency_stop`
Base.ClearFaults            :meth:`ArmAdapter.clear_faults`
Base.SetServoingMode        :meth:`ArmAdapter.set_servoing_mode`
==========================  =====================================================================

Units are SI and radians everywhere in this protocol: positions in rad, velocities in rad/s,
torques in N·m, times in s. Only the Kortex backend converts to degrees, at its edge.

Every method but :meth:`ArmAdapter.connect` and the description properties raises
:class:`NotConnectedError` when the adapter is not connected. Every command passes one gate,
written once here (:meth:`ArmAdapter.send_joint_speeds`): a session, no fault, single-level
servoing, then the robot's limits (:func:`check_joint_speeds`): a command that is not real
numbers, non-finite, of the wrong size, or beyond a velocity limit is refused and the arm is
e-stopped. Each backend sends what passed (:meth:`ArmAdapter._send`).
"""

from __future__ import annotations

import abc
import dataclasses
import enum
import time
from typing import Any

import numpy as np


class HardwareError(RuntimeError):
    """Base class of adapter errors; the message names the bad value and never a credential."""


class NotConnectedError(HardwareError):
    """A call that needs a session was made without one (before connect or after disconnect)."""


class ConnectionLostError(HardwareError):
    """The session dropped. The arm's own watchdog stops it; the adapter is disconnected."""


class FeedbackTimeoutError(HardwareError):
    """No feedback came back in time (a dropped RefreshFeedback)."""


class CommandRefusedError(HardwareError):
    """A command failed the adapter's limit check; the arm was e-stopped."""


class ArmFaultError(HardwareError):
    """The arm is in fault (e.g. after an emergency stop): motion commands are refused until
    :meth:`ArmAdapter.clear_faults`."""


class ArmState(enum.Enum):
    """Kortex ``ArmState`` (Common.proto), the states an adapter reports."""

    BASE_INITIALIZATION = "base_initialization"
    IDLE = "idle"
    INITIALIZATION = "initialization"
    IN_FAULT = "in_fault"
    MAINTENANCE = "maintenance"
    SERVOING_LOW_LEVEL = "servoing_low_level"
    SERVOING_READY = "servoing_ready"
    SERVOING_PLAYING_SEQUENCE = "servoing_playing_sequence"
    SERVOING_MANUALLY_CONTROLLED = "servoing_manually_controlled"


class Fault(enum.IntFlag):
    """Fault flags of one feedback frame (a summary of Kortex's fault banks)."""

    NONE = 0
    EMERGENCY_STOP = 1  # ApplyEmergencyStop was called (by us or the adapter's limit check)
    LIMIT = 2  # a command was refused by the limit check, or a joint is past a limit
    HARDWARE = 4  # an actuator or base fault bank is non-zero
    COMMUNICATION = 8  # the link to the arm reported an error
    WATCHDOG = 16  # no fresh command within the command timeout; the arm was stopped


class ServoingMode(enum.Enum):
    """Kortex ``ServoingMode``: joint speed commands need single-level servoing."""

    SINGLE_LEVEL_SERVOING = "single_level_servoing"
    LOW_LEVEL_SERVOING = "low_level_servoing"


@dataclasses.dataclass(frozen=True)
class Feedback:
    """One feedback frame (BaseCyclic's ``Feedback``), SI units.

    Attributes:
        timestamp: s, on the adapter's clock, when the frame was measured.
        frame_id: increases by at least one per fresh frame; a repeated id is a stale frame.
        position: (n,) joint positions, rad (continuous joints unwrapped, not reduced mod 2π).
        velocity: (n,) joint velocities, rad/s.
        torque: (n,) joint torques, N·m.
        arm_state: the arm's state.
        faults: fault flags; ``Fault.NONE`` when healthy.
    """

    timestamp: float
    frame_id: int
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    arm_state: ArmState
    faults: Fault

    @property
    def healthy(self) -> bool:
        """No fault flag, not in fault, and every reading finite."""
        return (self.faults == Fault.NONE and self.arm_state != ArmState.IN_FAULT
                and bool(np.isfinite(self.position).all() and np.isfinite(self.velocity).all()
                         and np.isfinite(self.torque).all()))


@dataclasses.dataclass(frozen=True)
class ObjectPoses:
    """What a perception module gives: world-frame poses of the cube and the obstacles.

    Positions in m, quaternions (w, x, y, z), linear velocities in m/s; ``timestamp`` in s on the
    adapter's clock. Obstacle arrays have one row per obstacle.
    """

    timestamp: float
    cube_position: np.ndarray  # (3,)
    cube_quaternion: np.ndarray  # (4,)
    cube_velocity: np.ndarray  # (3,)
    obstacle_positions: np.ndarray  # (k, 3)
    obstacle_quaternions: np.ndarray  # (k, 4)
    obstacle_velocities: np.ndarray  # (k, 3)

    @property
    def finite(self) -> bool:
        return all(bool(np.isfinite(a).all()) for a in (
            self.cube_position, self.cube_quaternion, self.cube_velocity, self.obstacle_positions,
            self.obstacle_quaternions, self.obstacle_velocities))


class WallClock:
    """Real time: ``now`` is ``time.perf_counter`` (s), ``sleep`` really sleeps."""

    def now(self) -> float:
        return time.perf_counter()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def sleep_until(self, deadline: float) -> None:
        # Sleep coarsely, then spin the last half millisecond: time.sleep overshoots by ~0.1 ms.
        while True:
            left = deadline - self.now()
            if left <= 0:
                return
            if left > 5e-4:
                time.sleep(left - 5e-4)


class FastClock(WallClock):
    """As fast as possible: a virtual clock that moves only when slept on. A paced loop then runs
    unpaced with the same timing logic, and a simulation driven by it is deterministic (the
    computation between two sleeps takes no simulated time; only an explicit ``sleep``, e.g. an
    injected command delay, can make a deadline late)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        return self._now

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._now += seconds

    def sleep_until(self, deadline: float) -> None:
        self._now = max(self._now, float(deadline))


def check_joint_speeds(speeds: Any, velocity_limit: np.ndarray) -> np.ndarray:
    """The command as a float array if it is safe to send, else :class:`CommandRefusedError` —
    for every bad command, so that every backend e-stops on it.

    ``speeds``: joint velocities, rad/s, one per joint. Refused: anything that is not an array of
    real numbers (strings, booleans, complex numbers, objects, integers too large for a float,
    anything NumPy cannot read), anything but one flat vector with one entry per joint, any
    non-finite entry, or any ``|speed| > velocity_limit`` (rad/s). A speed exactly at its limit is
    accepted (the safety filter commands the limit itself when it saturates); the next float
    beyond it is refused. The message names the first bad joint.
    """
    limit = np.asarray(velocity_limit, dtype=float)
    try:
        raw = np.asarray(speeds)
    except Exception as error:  # any failure to read the command refuses it
        raise CommandRefusedError(f"joint speeds are not numbers: {error}") from None
    if raw.dtype.kind not in "iuf":
        raise CommandRefusedError(f"joint speeds are not real numbers: {_shown(speeds)} "
                                  f"(NumPy dtype {raw.dtype})")
    if raw.ndim != 1:
        raise CommandRefusedError(f"joint speeds must be one flat vector of {limit.size} entries, got "
                                  f"shape {raw.shape}")
    command = raw.astype(float)
    if command.shape != limit.shape:
        raise CommandRefusedError(f"joint speeds have {command.size} entries; the arm has "
                                  f"{limit.size} joints")
    bad = np.flatnonzero(~np.isfinite(command))
    if bad.size:
        raise CommandRefusedError(f"joint speed [{bad[0]}] is {command[bad[0]]} (non-finite)")
    over = np.flatnonzero(np.abs(command) > limit)
    if over.size:
        i = over[0]
        raise CommandRefusedError(f"joint speed [{i}] is {command[i]:.6g} rad/s, beyond its "
                                  f"limit {limit[i]:.6g} rad/s")
    return command


def _shown(value: Any) -> str:
    """A short repr of a refused command for a message (at most 80 characters)."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def unwrap_positions(measured: np.ndarray, reference: np.ndarray | None,
                     continuous: np.ndarray, range_centre: np.ndarray | None = None) -> np.ndarray:
    """Joint positions (rad) with each continuous joint moved by whole turns to lie within π of
    ``reference`` (the previous reading, rad), and each limited joint moved by whole turns to lie
    within π of the centre of its range (``range_centre``, rad, e.g. :func:`range_centres`; without
    it, in (-π, π]); no ``reference``: continuous joints as read. Both arm backends unwrap so.

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


def range_centres(robot: Any) -> np.ndarray:
    """The centre of each limited joint's position range (rad; 0 for a continuous joint) of a
    :class:`~ahrm_stack.robot.RobotDescription`: where :func:`unwrap_positions` puts a limited
    joint's reading."""
    limited = robot.limited
    return np.where(limited, 0.5 * (np.where(limited, robot.position_lower, 0.0)
                                     + np.where(limited, robot.position_upper, 0.0)), 0.0)


class ArmAdapter(abc.ABC):
    """A connection to one arm, Kortex style. Contract (every backend):

    * ``joint_names``, ``velocity_limit`` describe the arm without a connection.
    * :meth:`connect` opens the session and leaves the arm in single-level servoing, stopped; it is
      an error to connect twice. :meth:`disconnect` stops the arm and closes the session; it is
      idempotent.
    * While not connected, every other method raises :class:`NotConnectedError`.
    * :meth:`send_joint_speeds` is the one command gate, here; in this order it (1) requires a
      session (:meth:`_require`: :class:`NotConnectedError`, or the backend's lost-link error);
      (2) refuses while in fault (:meth:`_fault_state`): :class:`ArmFaultError` naming the flags
      and the reason, nothing sent and no further e-stop; (3) refuses unless in single-level
      servoing (:class:`ArmFaultError`); (4) checks the command (:func:`check_joint_speeds`
      against ``velocity_limit``; a speed exactly at its limit passes): a refused command
      e-stops the arm (:meth:`apply_emergency_stop`), adds ``Fault.LIMIT`` with the refusal as
      the reason (:meth:`_add_fault`) and raises :class:`CommandRefusedError`; (5) sends it
      (:meth:`_send`, the backend's transport and scaling) and returns what was sent (rad/s).
    * :meth:`apply_emergency_stop` stops the arm and puts it in fault until :meth:`clear_faults`.
    * A **command watchdog** (a backend whose joint speeds do not expire by themselves on the arm
      has one; its docstring says so, or why not): when moving commands stop arriving for longer
      than the backend's command timeout, the adapter stops the arm by itself, records why,
      latches ``Fault.WATCHDOG`` (in :meth:`_fault_state` and every feedback frame) and so
      refuses commands (:class:`ArmFaultError`) until :meth:`clear_faults`: a stalled control
      loop never resumes motion silently. A zero command or :meth:`stop` disarms it (nothing
      moves, nothing to watch); the next moving command arms it again.

    Backend hooks (abstract): :meth:`_require`, :meth:`_fault_state`, :meth:`_add_fault`,
    :meth:`_send`.
    """

    @property
    @abc.abstractmethod
    def joint_names(self) -> tuple[str, ...]:
        """Names of the joints, in command and feedback order."""

    @property
    @abc.abstractmethod
    def velocity_limit(self) -> np.ndarray:
        """(n,) rad/s: the adapter refuses any command beyond it."""

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def clock(self) -> WallClock:
        """The clock of :attr:`Feedback.timestamp`; the deploy loop paces itself with it."""
        return WallClock()

    @property
    def torque_every_frame(self) -> bool:
        """Each feedback frame's torques were measured with its positions (the deploy loop's
        contact stop needs that); a backend that reads them less often says False."""
        return True

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool:
        """A session is open."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the session (transport, router, session, clients); raise :class:`HardwareError`
        if it cannot."""

    @abc.abstractmethod
    def disconnect(self) -> None:
        """Stop the arm (best effort) and close the session; a no-op when not connected."""

    @abc.abstractmethod
    def refresh_feedback(self) -> Feedback:
        """A fresh feedback frame; :class:`FeedbackTimeoutError` when none came in time,
        :class:`ConnectionLostError` when the session dropped."""

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        """Command joint velocities (rad/s, all joints at once) and return what was sent: the
        command gate (see the class docstring for its order), then :meth:`_send`."""
        self._require()
        self._refuse_in_fault()
        mode = self.servoing_mode
        if mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise ArmFaultError(f"joint speed commands need single-level servoing, not {mode}")
        try:
            command = check_joint_speeds(speeds, self.velocity_limit)
        except CommandRefusedError as error:
            self.apply_emergency_stop()
            self._add_fault(Fault.LIMIT, f"refused command: {error}")
            raise
        return self._send(command)

    def _refuse_in_fault(self) -> None:
        """Raise :class:`ArmFaultError` naming the flags and the reason while the adapter is in
        fault (:meth:`_fault_state`); the gate's second step, and any other motion's."""
        faults, reason = self._fault_state()
        if faults != Fault.NONE:
            raise ArmFaultError(f"the arm is in fault ({faults!r}: {reason or 'no reason given'}); "
                                "clear_faults() first")

    @abc.abstractmethod
    def _require(self) -> Any:
        """Raise :class:`NotConnectedError` (or the backend's lost-link error) unless connected."""

    @abc.abstractmethod
    def _fault_state(self) -> tuple[Fault, str]:
        """The adapter's fault flags as of now and why (``(Fault.NONE, '')`` when healthy): the
        flags the next feedback frame carries, latched until :meth:`clear_faults`."""

    @abc.abstractmethod
    def _add_fault(self, flag: Fault, reason: str) -> None:
        """Latch ``flag`` (until :meth:`clear_faults`), ``reason`` saying why."""

    @abc.abstractmethod
    def _send(self, command: np.ndarray) -> np.ndarray:
        """Send a command that passed the gate (rad/s, checked, float) over the backend's own
        transport; return what was sent (rad/s)."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Command zero velocity on every joint (Base.Stop). Allowed in fault."""

    @abc.abstractmethod
    def apply_emergency_stop(self) -> None:
        """Stop now and enter fault (Fault.EMERGENCY_STOP); motion is refused until cleared."""

    @abc.abstractmethod
    def clear_faults(self) -> None:
        """Leave fault: back to servoing-ready, the arm stopped."""

    @property
    @abc.abstractmethod
    def servoing_mode(self) -> ServoingMode:
        """The current servoing mode."""

    @abc.abstractmethod
    def set_servoing_mode(self, mode: ServoingMode) -> None:
        """Switch servoing mode; joint speed commands need ``SINGLE_LEVEL_SERVOING``."""

    def __enter__(self) -> "ArmAdapter":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()


class DescribedArm(ArmAdapter):
    """An adapter holding its arm model in ``_robot`` (a
    :class:`~ahrm_stack.robot.RobotDescription`), its clock in ``_clock`` and its session flag in
    ``_connected``: the description properties, written once for every backend; its servoing
    mode in ``_mode`` (read through :meth:`_require`, which refuses an adapter not connected)."""

    _robot: Any
    _clock: WallClock
    _connected: bool
    _mode: ServoingMode

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._robot.joint_names

    @property
    def velocity_limit(self) -> np.ndarray:
        return self._robot.velocity_limit.copy()

    @property
    def clock(self) -> WallClock:
        return self._clock

    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def servoing_mode(self) -> ServoingMode:
        self._require()
        return self._mode
