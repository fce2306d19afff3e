"""The sim backend: the training task's dm_control physics behind the Kortex-style protocol.

The arm is the same :class:`~ahrm_stack.env.task.PushOffTask` as in training, reset and stepped by
a :class:`~ahrm_stack.env.runner.TaskRunner` without a safety filter (``safety=None``): here the
deploy loop filters, as it would for a real arm. Physics time follows the adapter's clock: every
call first advances the physics (``physics_timestep`` steps, the last command held) up to
``clock.now()``. With a :class:`~hardware.protocol.WallClock` the simulation is paced to the wall
clock; with a :class:`~hardware.protocol.FastClock` it runs as fast as the caller does.

The simulated arm moves on the caller's CPU, but not inside the deploy loop's latency window
(feedback received -> command sent), as a real arm moves on its own: a command is stamped with the
clock's time and applied by the next call's advance (the physics stepped to that time with the
previous command held, then on with the new one: the same trajectory as applying it at once), and
:attr:`SimArm.clock`'s ``sleep_until(t)`` first steps the physics up to ``t`` (nothing can command
the arm while its caller sleeps), so the loop's next ``refresh_feedback`` finds it there.

The deploy loop sees only what a real arm gives (:meth:`SimArm.refresh_feedback`) plus what a
perception module would give (:meth:`SimArm.perception`: cube and obstacle poses).

Fault injection for tests (:meth:`SimArm.inject`, :class:`InjectedFault`): stale or dropped
feedback, a delayed command, NaN in a reading, a fault flag, a lost connection. A lost connection
stops the simulated arm at once, as the real arm's connection watchdog does.

:attr:`SimArm.violations` counts limit violations that reached the simulated actuators or joints
(a command beyond the velocity limits or non-finite, a joint past a position limit by more than
``position_tolerance``); the adapter's own check should keep it at zero.
"""

from __future__ import annotations

import enum
import logging

import numpy as np

from ahrm_stack.config import TaskConfig
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from hardware.protocol import (DescribedArm, ArmFaultError, ArmState, CommandRefusedError,
                               ConnectionLostError, Fault, Feedback, FeedbackTimeoutError,
                               NotConnectedError, ObjectPoses, ServoingMode, WallClock,
                               check_joint_speeds)

log = logging.getLogger(__name__)

#: rad a limited joint may sit past its bound before it counts as a violation: MuJoCo's joint
#: limits are soft constraints and sag by a fraction of a milliradian under load.
POSITION_TOLERANCE = 0.01


class InjectedFault(enum.Enum):
    """Faults :meth:`SimArm.inject` can arm; each fires once, on the next relevant call."""

    STALE_FEEDBACK = "stale_feedback"  # the next refresh returns the previous frame again
    DROPPED_FEEDBACK = "dropped_feedback"  # the next refresh times out
    DELAYED_COMMAND = "delayed_command"  # the next command takes ``command_delay`` s to arrive
    NAN_READING = "nan_reading"  # the next frame has a NaN joint velocity
    FAULT_FLAG = "fault_flag"  # the arm enters fault with Fault.HARDWARE
    LOST_CONNECTION = "lost_connection"  # the session drops; every call raises ConnectionLost


class SimArm(DescribedArm):
    """The simulated arm.

    Args:
        task_config: the task (arm, table, cube, obstacles) as in training.
        seed: seeds the layout of :meth:`reset_scene`.
        clock: a :class:`WallClock` (real time) or a :class:`FastClock` (as fast as possible).
        command_delay: s that an injected delayed command takes to arrive.
    """

    def __init__(self, task_config: TaskConfig, seed: int = 0, clock: WallClock | None = None,
                 command_delay: float = 0.03) -> None:
        self.task = PushOffTask(task_config)
        self.runner = TaskRunner(self.task, seed=seed, safety=None)
        self._clock = clock if clock is not None else WallClock()
        self._robot = self.task.robot
        self._timestep = task_config.episode.physics_timestep
        self.command_delay = float(command_delay)
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._faults = Fault.NONE
        self._pending: set[InjectedFault] = set()
        self._lost = False
        self._last: Feedback | None = None
        self._frame = 0
        self._start = 0.0  # clock time of physics time 0
        self._command = np.zeros(self._robot.num_joints)
        self._queued: tuple[float, np.ndarray] | None = None  # (clock s, rad/s) not yet applied
        self._sleeper = _SimClock(self._clock, self)
        self.violations = 0
        self.commands_sent = 0
        self.runner.reset()
        self._bind()

    # ------------------------------------------------------------------ description
    @property
    def physics(self):
        """The simulator's physics (tests and the sim's own bookkeeping; never the deploy loop)."""
        return self.runner.physics

    # ------------------------------------------------------------------ session
    def connect(self) -> None:
        if self._connected:
            raise RuntimeError("SimArm is already connected")
        self._connected = True  # faults persist across sessions until clear_faults()
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._start = self._clock.now() - self.physics.data.time
        self._set_command(np.zeros(self._robot.num_joints))

    def disconnect(self) -> None:
        if self._connected:
            self._advance()
            self._set_command(np.zeros(self._robot.num_joints))
        self._connected = False
        self._pending.discard(InjectedFault.LOST_CONNECTION)

    def reset_scene(self, seed: int | None = None) -> None:
        """A new episode: the layout re-drawn (seeded by ``seed``), the arm at home, stopped.
        Sim only; the physics clock restarts at the adapter clock's now."""
        if seed is not None:
            self.runner.seed(seed)
        self._queued = None  # a command of the last episode never reaches the new one
        self.runner.reset()
        self._set_command(np.zeros(self._robot.num_joints))
        self._start = self._clock.now() - self.physics.data.time
        self._last = None

    # ------------------------------------------------------------------ fault injection
    def inject(self, fault: InjectedFault) -> None:
        """Arm ``fault`` for the next relevant call (see :class:`InjectedFault`)."""
        self._pending.add(InjectedFault(fault))
        if fault == InjectedFault.LOST_CONNECTION and self._connected:
            self._lose_connection()
        elif fault == InjectedFault.FAULT_FLAG:
            self._faults |= Fault.HARDWARE
            self._set_command(np.zeros(self._robot.num_joints))  # the arm stops itself
            self._pending.discard(fault)

    def _lose_connection(self) -> None:
        self._advance()
        self._set_command(np.zeros(self._robot.num_joints))  # the arm's connection watchdog
        self._connected = False
        self._pending.discard(InjectedFault.LOST_CONNECTION)
        self._lost = True
        log.error("sim: connection to the arm lost")

    def _require(self) -> None:
        if self._lost and not self._connected:
            self._lost = False
            raise ConnectionLostError("the session to the simulated arm was lost")
        if not self._connected:
            raise NotConnectedError("SimArm is not connected; call connect() first")

    # ------------------------------------------------------------------ protocol
    def refresh_feedback(self) -> Feedback:
        self._require()
        self._advance()
        if self._take(InjectedFault.DROPPED_FEEDBACK):
            raise FeedbackTimeoutError("no feedback frame from the simulated arm (dropped)")
        if self._take(InjectedFault.STALE_FEEDBACK) and self._last is not None:
            return self._last
        q, dq = self.task.arm_state(self.physics)
        if self._take(InjectedFault.NAN_READING):
            dq[0] = np.nan
        self._frame += 1
        data = self.physics.data
        torque = np.asarray(data.actuator_force[self._actuators], dtype=float).copy()
        in_fault = self._faults != Fault.NONE
        frame = Feedback(timestamp=self._clock.now(), frame_id=self._frame, position=q, velocity=dq,
                         torque=torque,
                         arm_state=ArmState.IN_FAULT if in_fault else ArmState.SERVOING_READY,
                         faults=self._faults)
        self._last = frame
        return frame

    def perception(self) -> ObjectPoses:
        """Cube and obstacle poses and linear velocities, world frame, as a perception module
        would give them (exact here)."""
        self._require()
        data = self.physics.data
        qpos, qvel = data.qpos, data.qvel
        return ObjectPoses(
            timestamp=self._clock.now(),
            cube_position=qpos[self._cube_qpos[:3]].copy(),
            cube_quaternion=qpos[self._cube_qpos[3:]].copy(),
            cube_velocity=qvel[self._cube_dof].copy(),
            obstacle_positions=qpos[self._obstacle_qpos[:, :3]].copy(),
            obstacle_quaternions=qpos[self._obstacle_qpos[:, 3:]].copy(),
            obstacle_velocities=qvel[self._obstacle_dof].copy())

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        self._require()
        if self._faults != Fault.NONE:
            raise ArmFaultError(f"arm in fault ({self._faults!r}): clear_faults() first")
        if self._mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise ArmFaultError(f"joint speed commands need single-level servoing, not {self._mode}")
        try:
            command = check_joint_speeds(speeds, self._robot.velocity_limit)
        except CommandRefusedError:
            self.apply_emergency_stop()
            self._faults |= Fault.LIMIT
            raise
        if self._take(InjectedFault.DELAYED_COMMAND):
            self._clock.sleep(self.command_delay)
        # Applied by the next advance, at this time (the physics is not stepped here: see the
        # module docstring); a command still queued is applied first, at its own time.
        if self._queued is not None:
            self._advance(self._queued[0])
        self._queued = (self._clock.now(), command)
        self.commands_sent += 1
        return command.copy()

    def stop(self) -> None:
        self._require()
        self._advance()
        self._set_command(np.zeros(self._robot.num_joints))

    def apply_emergency_stop(self) -> None:
        self._require()
        self._advance()
        self._set_command(np.zeros(self._robot.num_joints))
        self._faults |= Fault.EMERGENCY_STOP

    def clear_faults(self) -> None:
        self._require()
        self._advance()
        self._faults = Fault.NONE
        self._set_command(np.zeros(self._robot.num_joints))

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self._require()
        self._mode = ServoingMode(mode)
        self._set_command(np.zeros(self._robot.num_joints))

    # ------------------------------------------------------------------ physics
    @property
    def clock(self) -> WallClock:
        """The adapter's clock; its ``sleep_until(t)`` steps the physics up to ``t`` first."""
        return self._sleeper

    @property
    def command(self) -> np.ndarray:
        """The joint velocities the simulated actuators hold now, rad/s."""
        self._advance()
        return self._command.copy()

    def _bind(self) -> None:
        physics, task = self.physics, self.task
        self._actuators = np.asarray(physics.bind(task.arm.actuators).element_id, dtype=int)
        addresses = task.addresses  # bound to this physics by the runner's reset
        self._arm_qpos = addresses.arm_qpos
        self._cube_qpos, self._cube_dof = addresses.cube_qpos, addresses.cube_dof
        self._obstacle_qpos, self._obstacle_dof = addresses.obstacle_qpos, addresses.obstacle_dof
        self._lower = np.where(self._robot.limited, self._robot.position_lower, -np.inf)
        self._upper = np.where(self._robot.limited, self._robot.position_upper, np.inf)

    def _set_command(self, command: np.ndarray) -> None:
        """Apply ``command`` (rad/s) now; a command still queued is applied first, at its time."""
        if self._queued is not None:
            self._advance()
        if not (np.isfinite(command).all()
                and (np.abs(command) <= self._robot.velocity_limit).all()):
            self.violations += 1  # never reached: check_joint_speeds guards every path here
            log.error("sim: VIOLATION: command %s reached the actuators", command)
            command = np.zeros_like(command)
        self._command = np.asarray(command, dtype=float).copy()
        self.task.before_step(self.physics, self._command, self.runner.random_state)

    def _advance(self, until: float | None = None) -> None:
        """Step the physics up to clock time ``until`` (default: the clock's now): the queued
        command applied at its own time, the last command held between commands."""
        now = self._clock.now()
        until = now if until is None else until
        if self._queued is not None and self._queued[0] <= until:
            stamp, command = self._queued
            self._queued = None
            self._step_to(stamp)
            self._set_command(command)
        self._step_to(until)

    def _step_to(self, until: float) -> None:
        """Step the physics, the current command held, up to clock time ``until``."""
        data = self.physics.data
        target = int((until - self._start) / self._timestep + 1e-9)
        steps = target - int(round(data.time / self._timestep))
        if steps <= 0:
            return
        self.physics.step(steps)
        q = data.qpos[self._arm_qpos]
        past = np.maximum(self._lower - q, q - self._upper)
        if (past > POSITION_TOLERANCE).any():
            self.violations += 1
            log.error("sim: VIOLATION: joint %d is %.4f rad past its position limit",
                      int(np.argmax(past)), float(past.max()))

    def _take(self, fault: InjectedFault) -> bool:
        if fault in self._pending:
            self._pending.discard(fault)
            return True
        return False


class _SimClock(WallClock):
    """The sim's clock as the deploy loop sees it: ``inner``'s time; ``sleep_until(t)`` steps the
    arm's physics up to ``t`` (the command held) before sleeping, so that the simulation runs while
    the loop waits for its next tick, as a real arm moves while its controller waits."""

    def __init__(self, inner: WallClock, arm: SimArm) -> None:
        self._inner, self._arm = inner, arm

    def now(self) -> float:
        return self._inner.now()

    def sleep(self, seconds: float) -> None:
        self._inner.sleep(seconds)

    def sleep_until(self, deadline: float) -> None:
        if self._arm._connected and deadline > self._inner.now():
            self._arm._advance(deadline)
        self._inner.sleep_until(deadline)
