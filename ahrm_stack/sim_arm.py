"""The sim backend: the training task's dm_control physics behind the Kortex-style protocol.

The arm is the same :class:`~ahrm_stack.env.task.PushOffTask` as in training, reset and stepped by
a :class:`~ahrm_stack.env.runner.TaskRunner` without a safety filter (``safety=None``): here the
deploy loop filters, as it would for a real arm. Physics time follows the adapter's clock: every
call first advances the physics (``physics_timestep`` steps, the last command held) up to
``clock.now()``. With a :class:`~ahrm_stack.hardware.protocol.WallClock` the simulation is paced to the wall
clock; with a :class:`~ahrm_stack.hardware.protocol.FastClock` it runs as fast as the caller does.

The simulated arm moves on the caller's CPU, but not inside the deploy loop's latency window
(feedback received -> command sent), as a real arm moves on its own: a command is stamped with the
clock's time and applied by the next call's advance (the physics stepped to that time with the
previous command held, then on with the new one: the same trajectory as applying it at once), and
:attr:`SimArm.clock`'s ``sleep_until(t)`` first steps the physics up to ``t`` (nothing can command
the arm while its caller sleeps), so the loop's next ``refresh_feedback`` finds it there.

The deploy loop sees only what a real arm gives (:meth:`SimArm.refresh_feedback`) plus what a
perception module would give (:meth:`SimArm.perception`: cube and obstacle poses).

A real arm's imperfections (``realism``, :class:`~ahrm_stack.realism.RealismConfig`;
``deploy.sim.realism`` names a set of ``configs/realism.yaml``), composed from the same objects as
training's (:mod:`ahrm_stack.realism`): a command reaches the actuators ``command_latency`` s after
it was sent and they follow it through a first-order lag of ``actuator_lag`` s
(:class:`~ahrm_stack.realism.ActuatorModel`, stepped per physics step as the training runner does);
the feedback's angles and velocities carry white noise and quantisation
(:class:`~ahrm_stack.realism.JointSensing`); perception gives ``perception_latency`` s old object
positions and velocities with white noise (:class:`~ahrm_stack.realism.PerceptionDelay`,
:class:`~ahrm_stack.realism.ObjectSensing`; orientations exact); each :meth:`SimArm.reset_scene`
draws the cube's and the obstacles' mass and friction (the task's, as in training). The noise is
seeded by the layout seed. :attr:`SimArm.truth` is what really
happened (the cube off the table, an obstacle touched), which a real deployment cannot see.

Fault injection for tests (:meth:`SimArm.inject`, :class:`InjectedFault`): stale or dropped
feedback, a delayed command, NaN in a reading, a fault flag, a lost connection. A lost connection
stops the simulated arm at once, as the real arm's connection watchdog does. The sim has no
command watchdog (the protocol's ``Fault.WATCHDOG`` never appears): a command holds until the
next one, a stop or a lost connection; the deploy loop's own deadline checks cover a stall.

:attr:`SimArm.violations` counts limit violations that reached the simulated actuators or joints
(a command beyond the velocity limits or non-finite, a joint past a position limit by more than
``position_tolerance``); the adapter's own check should keep it at zero.
"""

from __future__ import annotations

import dataclasses
import enum
import logging

import numpy as np

from ahrm_stack.config import TaskConfig
from ahrm_stack.env.rewards import obstacle_touched
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.hardware.protocol import (ArmState, ConnectionLostError, DescribedArm, Fault, Feedback,
                               FeedbackTimeoutError, NotConnectedError, ObjectPoses, ServoingMode,
                               WallClock)
from ahrm_stack.realism import ActuatorModel, JointSensing, ObjectSensing, PerceptionDelay, RealismConfig

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


@dataclasses.dataclass
class SimTruth:
    """What happened in the simulated world during one episode (checked after each physics
    advance, i.e. at least once per control tick). Times in s of physics time."""

    success: bool = False  # the cube's centre left the table top (as training's task judges it)
    success_time: float | None = None
    touched: bool = False  # the arm or the cube touched an obstacle, or an obstacle moved
    touch_time: float | None = None
    cube_position: np.ndarray | None = None  # m, world frame, at the last check


class SimArm(DescribedArm):
    """The simulated arm.

    Args:
        task_config: the task (arm, table, cube, obstacles) as in training.
        seed: seeds the layout of :meth:`reset_scene`.
        clock: a :class:`WallClock` (real time) or a :class:`FastClock` (as fast as possible).
        command_delay: s that an injected delayed command takes to arrive.
        realism: the arm's and the camera's imperfections (default: none).
    """

    def __init__(self, task_config: TaskConfig, seed: int = 0, clock: WallClock | None = None,
                 command_delay: float = 0.03, realism: RealismConfig | None = None) -> None:
        self.realism = RealismConfig.ideal() if realism is None else realism
        # the task's own realism is this arm's: its episodes draw the dynamics
        self.task = PushOffTask(dataclasses.replace(task_config, realism=self.realism))  # type: ignore[type-var]
        self._rng = np.random.default_rng(seed)
        r = self.realism
        # the imperfections, as training composes them (ahrm_stack.realism)
        self._actuation = ActuatorModel(r, task_config.episode.physics_timestep, self.task.robot.num_joints)
        self._joints = JointSensing(r)
        self._objects = ObjectSensing(r)
        # (positions, quaternions, velocities) by physics time: perception reads the one
        # perception_latency old
        self._seen: PerceptionDelay[tuple[np.ndarray, np.ndarray, np.ndarray]] = PerceptionDelay(
            r.perception_latency)
        self.truth = SimTruth()
        self.runner = TaskRunner(self.task, seed=seed, safety=None, imperfections=False)
        self._clock = clock if clock is not None else WallClock()
        self._robot = self.task.robot
        self._timestep = task_config.episode.physics_timestep
        self.command_delay = float(command_delay)
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._faults = Fault.NONE
        self._fault_reason = ""
        self._pending: set[InjectedFault] = set()
        self._lost = False
        self._last: Feedback | None = None
        self._frame = 0
        self._start = 0.0  # clock time of physics time 0
        self._sleeper = _SimClock(self._clock, self)
        self.violations = 0
        self.commands_sent = 0
        self.runner.reset()
        self._bind()
        self._begin_truth()

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
            self._rng = np.random.default_rng(seed)
        self._actuation.reset()  # a command of the last episode never reaches the new one
        self._seen.clear()
        self.runner.reset()
        self._set_command(np.zeros(self._robot.num_joints))
        self._start = self._clock.now() - self.physics.data.time
        self._last = None
        self._begin_truth()

    def set_state(self, q: np.ndarray, cube: np.ndarray, obstacles: np.ndarray) -> None:
        """Sim only (a replay's start): the arm at joint angles ``q`` (rad), the cube at ``cube``
        (position m and quaternion w x y z, world frame), obstacle i at ``obstacles[i]`` (the same
        seven numbers), everything at rest and stopped; the physics clock restarts at the adapter
        clock's now."""
        obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 7)
        if len(obstacles) != len(self._obstacle_qpos) or np.shape(cube) != (7,) or np.shape(q) != self._arm_qpos.shape:
            raise ValueError(f"set_state: {len(self._obstacle_qpos)} obstacles and a cube of 7 numbers "
                             f"expected, got {len(obstacles)} obstacles and {np.shape(cube)}")
        data = self.physics.data
        data.qpos[self._arm_qpos] = np.asarray(q, dtype=float)
        data.qpos[self._cube_qpos] = np.asarray(cube, dtype=float)
        for address, pose in zip(self._obstacle_qpos, obstacles):
            data.qpos[address] = pose
        data.qvel[:] = 0.0
        self.physics.forward()
        self._actuation.reset()
        self._seen.clear()
        self._set_command(np.zeros(self._robot.num_joints))
        self._start = self._clock.now() - data.time
        self._last = None
        self._begin_truth()

    # ------------------------------------------------------------------ fault injection
    def inject(self, fault: InjectedFault) -> None:
        """Arm ``fault`` for the next relevant call (see :class:`InjectedFault`)."""
        self._pending.add(InjectedFault(fault))
        if fault == InjectedFault.LOST_CONNECTION and self._connected:
            self._lose_connection()
        elif fault == InjectedFault.FAULT_FLAG:
            self._add_fault(Fault.HARDWARE, "injected fault flag")
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
        if self.realism.senses:  # as the arm's sensors give them
            q = self._joints.angles(q, self._rng)
            dq = self._joints.velocities(dq, self._rng)
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
        would give them: exact, or with the realism's latency and noise (positions, velocities;
        the orientations exact)."""
        self._require()
        self._advance()
        if self.realism.perception_latency > 0 and self._seen:
            positions, quaternions, velocities = self._seen.seen(self.physics.data.time)
        else:
            _, positions, quaternions, velocities = self._snapshot()
        positions = self._objects.positions(positions, self._rng)
        velocities = self._objects.velocities(velocities, self._rng)
        return ObjectPoses(
            timestamp=self._clock.now(),
            cube_position=positions[0], cube_quaternion=quaternions[0].copy(), cube_velocity=velocities[0],
            obstacle_positions=positions[1:], obstacle_quaternions=quaternions[1:].copy(),
            obstacle_velocities=velocities[1:])

    def _snapshot(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(physics time, positions (k, 3), quaternions (k, 4), velocities (k, 3)) of the
        cube (row 0) and the obstacles, world frame."""
        data = self.physics.data
        qpos, qvel = data.qpos, data.qvel
        positions = np.vstack([qpos[self._cube_qpos[:3]], qpos[self._obstacle_qpos[:, :3]]])
        quaternions = np.vstack([qpos[self._cube_qpos[3:]], qpos[self._obstacle_qpos[:, 3:]]])
        velocities = np.vstack([qvel[self._cube_dof], qvel[self._obstacle_dof]])
        return float(data.time), positions, quaternions, velocities

    def _begin_truth(self) -> None:
        """A new episode's :attr:`truth`; the obstacles' resting positions remembered."""
        self.truth = SimTruth()
        self._seen.clear()
        time, positions, quaternions, velocities = self._snapshot()
        self._rest = positions[1:].copy()
        self._seen.push(time, (positions, quaternions, velocities))
        self._check_truth()

    def _check_truth(self) -> None:
        """Update :attr:`truth` from the physics now (the task's own success rule; a touch: a
        contact of the arm or the cube with an obstacle, an obstacle moving faster than the task's
        threshold, or one moved 2 mm from where it rested)."""
        task, data, truth = self.task, self.physics.data, self.truth
        cube = data.xpos[task._cube_body].copy()
        truth.cube_position = cube
        config = task.config
        if not truth.success:
            (hx, hy) = config.table.half_extent
            if abs(cube[0]) > hx or abs(cube[1]) > hy or cube[2] < config.table.height:
                truth.success, truth.success_time = True, float(data.time)
        if not truth.touched:
            velocities = data.qvel[task._obstacle_linear_dofs]
            speeds = np.sqrt((velocities * velocities).sum(axis=1))
            moved = np.linalg.norm(data.xpos[task._obstacle_bodies] - self._rest, axis=1)
            if (obstacle_touched(data.ptr.contact.geom, task._is_obstacle, task._is_toucher, speeds,
                                 config.rewards.obstacle_speed_threshold) or (moved > 0.002).any()):
                truth.touched, truth.touch_time = True, float(data.time)

    def _fault_state(self) -> tuple[Fault, str]:
        return self._faults, self._fault_reason

    def _add_fault(self, flag: Fault, reason: str) -> None:
        self._faults |= flag
        self._fault_reason = reason

    def _send(self, command: np.ndarray) -> np.ndarray:
        """Queue a command that passed the gate (:meth:`ArmAdapter.send_joint_speeds`)."""
        if self._take(InjectedFault.DELAYED_COMMAND):
            self._clock.sleep(self.command_delay)
        # Applied by an advance, command_latency after this time (the physics is not stepped here:
        # see the module docstring): the clock may be ahead of the physics stepped so far.
        if not self._within_limits(command):
            command = np.zeros_like(command)
        ahead = self._step_index(self._clock.now()) - self._steps_taken()
        self._actuation.command(command, after=max(0, ahead))
        # the task's record of the command sent (its previous action), as the training runner keeps
        # it; the actuators' input is the model's output, set at every physics step
        self.task.before_step(self.physics, command, self.runner.random_state)
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
        self._add_fault(Fault.EMERGENCY_STOP, "emergency stop applied")

    def clear_faults(self) -> None:
        self._require()
        self._advance()
        self._faults, self._fault_reason = Fault.NONE, ""
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
        """The joint velocities the simulated actuators hold now (the latest command to reach
        them; under a lag they converge to it), rad/s."""
        self._advance()
        return self._actuation.upcoming(self._step_index(self._clock.now()) - self._steps_taken())

    def _bind(self) -> None:
        physics, task = self.physics, self.task
        self._actuators = np.asarray(physics.bind(task.arm.actuators).element_id, dtype=int)
        addresses = task.addresses  # bound to this physics by the runner's reset
        self._arm_qpos = addresses.arm_qpos
        self._cube_qpos, self._cube_dof = addresses.cube_qpos, addresses.cube_dof
        self._obstacle_qpos, self._obstacle_dof = addresses.obstacle_qpos, addresses.obstacle_dof
        self._lower = np.where(self._robot.limited, self._robot.position_lower, -np.inf)
        self._upper = np.where(self._robot.limited, self._robot.position_upper, np.inf)

    def _within_limits(self, command: np.ndarray) -> bool:
        if np.isfinite(command).all() and (np.abs(command) <= self._robot.velocity_limit).all():
            return True
        self.violations += 1  # never reached: check_joint_speeds guards every path here
        log.error("sim: VIOLATION: command %s reached the actuators", command)
        return False

    def _step_index(self, time: float) -> int:
        """The physics step a clock time falls in."""
        return int((time - self._start) / self._timestep + 1e-9)

    def _steps_taken(self) -> int:
        return int(round(self.physics.data.time / self._timestep))

    def _set_command(self, command: np.ndarray) -> None:
        """The actuators take ``command`` (rad/s) at once, through their lag (the arm's own stop):
        commands in flight until now are applied first, at their steps, and later ones dropped
        (nothing sent before it moves the arm)."""
        if self._actuation.in_flight:
            self._advance()
        if not self._within_limits(command):
            command = np.zeros_like(command)
        command = np.asarray(command, dtype=float).copy()
        self._actuation.hold(command)
        self.task.before_step(self.physics, command, self.runner.random_state)

    def _advance(self, until: float | None = None) -> None:
        """Step the physics up to clock time ``until`` (default: the clock's now), the actuators
        stepped with it (commands in flight taking effect at their steps)."""
        self._step_to(self._clock.now() if until is None else until)

    def _step_to(self, until: float) -> None:
        """Step the physics and the actuators (:class:`~ahrm_stack.realism.ActuatorModel`, as the
        training runner steps them) up to clock time ``until``."""
        data = self.physics.data
        steps = self._step_index(until) - self._steps_taken()
        if steps <= 0:
            return
        ctrl = data.ctrl
        for count, output in self._actuation.run(steps):
            ctrl[self._actuators] = output
            self.physics.step(count)
        self._check_truth()
        if self.realism.perception_latency > 0:
            _, positions, quaternions, velocities = self._snapshot()
            self._seen.push(float(data.time), (positions, quaternions, velocities))
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
