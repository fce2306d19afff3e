"""The deployment loop: feedback → kinematics and phase → controller → safety filter → command.

Usage::

    python -m ahrm_stack.deploy --backend sim [--checkpoint RUN_DIR] [--duration S] [--rate HZ]
                                [--realtime | --fast] [--seed N] [--telemetry PATH]

Without ``--checkpoint`` the scripted mink controller drives the arm; with one, the run's
deterministic policy does (its ``config.yaml`` gives the task, so the arm model is the trained one).
Settings come from ``configs/deploy.yaml`` (:func:`load_deploy_settings`); the task, safety and
scripted sections from ``configs/*.yaml`` as in training.

Every control period (``1 / rate_hz`` s) :class:`DeployLoop` does, in this order:

1. ``refresh_feedback`` — a dropped frame, a stale frame (repeated id or older than
   ``watchdog.max_feedback_age`` periods) or a lost connection stops the arm; a NaN reading, a fault
   flag, a joint past its position limit or a joint speed beyond ``(1 + velocity_tolerance)`` times
   its limit e-stops it;
2. perception (cube and obstacle poses) into :class:`WorldModel`, which computes the phase k, the
   boundary distance x and the training observation with the task's own code;
3. the controller's nominal joint velocities (rad/s);
4. the QP safety filter with the obstacle rows on (a reported violation e-stops);
5. ``send_joint_speeds`` — the adapter re-checks the limits and e-stops on a bad command; a command
   not sent within ``watchdog.command_deadline`` periods of the tick is a missed deadline.

Ctrl-C (SIGINT) and SIGTERM stop the arm before the program exits. Every tick and every event is a
line of the JSONL telemetry log (time, phase, nominal and filtered command, active constraints,
loop latency); the run ends with a summary (success, duration, interventions, deadline misses,
latency p50/p99).

Perception: the sim backend's :meth:`~hardware.sim.SimArm.perception` stands in for a perception
module (exact poses from the simulator). The scripted controller needs object poses too; it runs on
the :class:`WorldModel`'s own mirror of the scene, fed only by feedback and perception, never on
the simulator's physics.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from ahrm_stack.config import CONFIG_DIR, Config, ConfigError, TaskConfig, load_config
from hardware.protocol import (ArmFaultError, CommandRefusedError, ConnectionLostError, FastClock,
                               FeedbackTimeoutError, HardwareError, ServoingMode, WallClock)

log = logging.getLogger("ahrm_stack.deploy")

DEPLOY_CONFIG = CONFIG_DIR / "deploy.yaml"


# ---------------------------------------------------------------------------------------------
# Settings (configs/deploy.yaml)
# ---------------------------------------------------------------------------------------------


class DeployConfigError(ValueError):
    """A deploy setting is missing, unknown or invalid; the message names the key."""


@dataclasses.dataclass(frozen=True)
class WatchdogSettings:
    max_feedback_age: float  # control periods
    command_deadline: float  # control periods after the tick
    max_deadline_misses: int  # tolerated before a stop (0: the first miss stops)
    velocity_tolerance: float  # fraction over the velocity limit a measured speed may reach


@dataclasses.dataclass(frozen=True)
class SimSettings:
    command_delay: float  # s


@dataclasses.dataclass(frozen=True)
class KortexSection:
    address: str | None
    port: int
    session_inactivity_timeout_ms: int
    connection_inactivity_timeout_ms: int
    credentials_file: str | None


@dataclasses.dataclass(frozen=True)
class DeploySettings:
    rate_hz: float
    duration: float  # s
    realtime: bool
    seed: int
    telemetry: str  # path; '' for none
    watchdog: WatchdogSettings
    sim: SimSettings
    kortex: KortexSection

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


def _number(value: Any, key: str, *, integer: bool = False, positive: bool = False,
            nonnegative: bool = False) -> float | int:
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not math.isfinite(value):
        raise DeployConfigError(f"deploy.{key} must be a finite {'integer' if integer else 'number'}, "
                                f"got {value!r}")
    if positive and value <= 0:
        raise DeployConfigError(f"deploy.{key} must be > 0, got {value!r}")
    if nonnegative and value < 0:
        raise DeployConfigError(f"deploy.{key} must be >= 0, got {value!r}")
    return int(value) if integer else float(value)


def _section(data: Any, key: str, fields: Sequence[str]) -> dict:
    if not isinstance(data, dict):
        raise DeployConfigError(f"deploy.{key} must be a mapping, got {data!r}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise DeployConfigError(f"unknown key deploy.{key + '.' if key else ''}{unknown[0]}; "
                                f"allowed: {sorted(fields)}")
    missing = [f for f in fields if f not in data]
    if missing:
        raise DeployConfigError(f"missing key deploy.{key + '.' if key else ''}{missing[0]}")
    return data


def _optional_str(value: Any, key: str) -> str | None:
    if value is not None and not isinstance(value, str):
        raise DeployConfigError(f"deploy.{key} must be a string or null, got {value!r}")
    return value


def deploy_settings_from_dict(data: Any) -> DeploySettings:
    """Validate a parsed ``deploy.yaml``; :class:`DeployConfigError` names the first bad key."""
    top = _section(data, "", [f.name for f in dataclasses.fields(DeploySettings)])
    wd = _section(top["watchdog"], "watchdog", [f.name for f in dataclasses.fields(WatchdogSettings)])
    sim = _section(top["sim"], "sim", [f.name for f in dataclasses.fields(SimSettings)])
    kx = _section(top["kortex"], "kortex", [f.name for f in dataclasses.fields(KortexSection)])
    if not isinstance(top["realtime"], bool):
        raise DeployConfigError(f"deploy.realtime must be true or false, got {top['realtime']!r}")
    if not isinstance(top["telemetry"], str):
        raise DeployConfigError(f"deploy.telemetry must be a path string ('' for none), "
                                f"got {top['telemetry']!r}")
    watchdog = WatchdogSettings(
        max_feedback_age=_number(wd["max_feedback_age"], "watchdog.max_feedback_age", positive=True),
        command_deadline=_number(wd["command_deadline"], "watchdog.command_deadline", positive=True),
        max_deadline_misses=_number(wd["max_deadline_misses"], "watchdog.max_deadline_misses",
                                    integer=True, nonnegative=True),
        velocity_tolerance=_number(wd["velocity_tolerance"], "watchdog.velocity_tolerance",
                                   nonnegative=True))
    if watchdog.command_deadline > 1.0:
        raise DeployConfigError("deploy.watchdog.command_deadline must be <= 1 period, got "
                                f"{watchdog.command_deadline!r}")
    kortex = KortexSection(
        address=_optional_str(kx["address"], "kortex.address"),
        port=_number(kx["port"], "kortex.port", integer=True, positive=True),
        session_inactivity_timeout_ms=_number(kx["session_inactivity_timeout_ms"],
                                              "kortex.session_inactivity_timeout_ms",
                                              integer=True, positive=True),
        connection_inactivity_timeout_ms=_number(kx["connection_inactivity_timeout_ms"],
                                                 "kortex.connection_inactivity_timeout_ms",
                                                 integer=True, positive=True),
        credentials_file=_optional_str(kx["credentials_file"], "kortex.credentials_file"))
    return DeploySettings(
        rate_hz=_number(top["rate_hz"], "rate_hz", positive=True),
        duration=_number(top["duration"], "duration", positive=True),
        realtime=top["realtime"],
        seed=_number(top["seed"], "seed", integer=True, nonnegative=True),
        telemetry=top["telemetry"],
        watchdog=watchdog,
        sim=SimSettings(command_delay=_number(sim["command_delay"], "sim.command_delay",
                                              nonnegative=True)),
        kortex=kortex)


def load_deploy_settings(path: Path | str = DEPLOY_CONFIG, **overrides: Any) -> DeploySettings:
    """Read and validate ``path``; ``overrides`` replace top-level keys (None values are ignored)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise DeployConfigError(f"cannot read {path}: {error.strerror}") from None
    except yaml.YAMLError as error:
        raise DeployConfigError(f"{path} is not valid YAML: {error}") from None
    if isinstance(data, dict):
        data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return deploy_settings_from_dict(data)
    except DeployConfigError as error:
        raise DeployConfigError(f"{path}: {error}") from None


# ---------------------------------------------------------------------------------------------
# The deploy side's picture of the world
# ---------------------------------------------------------------------------------------------


class WorldModel:
    """A mirror of the scene built only from feedback and perception.

    It holds its own :class:`~ahrm_stack.env.task.PushOffTask` on its own physics; each
    :meth:`update` writes the measured joint state and the perceived object poses into that
    physics, runs MuJoCo's forward kinematics, and lets the task measure the step exactly as in
    training (Pinocchio tip pose, :func:`~ahrm_stack.kinematics.phases.phase_geometry` for the
    phase k and the boundary distance x, success). :meth:`observation` is then the training
    observation vector (:meth:`PushOffTask.flat_observation`), with the previous action recorded
    by :meth:`record_command` from the command actually sent.
    """

    def __init__(self, task_config: TaskConfig, seed: int = 0) -> None:
        import mujoco
        from dm_control import mjcf

        from ahrm_stack.env.task import PushOffTask

        self._mujoco = mujoco
        self.task = PushOffTask(task_config)
        self.physics = mjcf.Physics.from_mjcf_model(self.task.root_entity.mjcf_model)
        self.random_state = np.random.RandomState(seed)
        self.task.initialize_episode(self.physics, self.random_state)  # binds the task's indices
        physics, model = self.physics, self.physics.model
        self._arm_qpos = np.asarray(physics.bind(self.task.arm.joints).qposadr, dtype=int)
        self._arm_dof = np.asarray(physics.bind(self.task.arm.joints).dofadr, dtype=int)

        def free(prop):
            joint = int(model.body_jntadr[int(physics.bind(prop.geom).bodyid)])
            return (int(model.jnt_qposadr[joint]) + np.arange(7),
                    int(model.jnt_dofadr[joint]) + np.arange(3))

        self._cube_qpos, self._cube_dof = free(self.task.cube)
        pairs = [free(o) for o in self.task.obstacles]
        self._obstacle_qpos = np.array([p[0] for p in pairs], dtype=int).reshape(-1, 7)
        self._obstacle_dof = np.array([p[1] for p in pairs], dtype=int).reshape(-1, 3)
        self._start = float(physics.data.time)

    @property
    def robot(self):
        return self.task.robot

    def update(self, feedback, poses, elapsed: float):
        """Write ``feedback`` (joint state) and ``poses`` (objects) into the mirror; returns the
        task's :class:`~ahrm_stack.env.task.StepInfo` for this state. ``elapsed``: s since start."""
        if len(poses.obstacle_positions) != len(self._obstacle_qpos):
            raise ValueError(f"perception gave {len(poses.obstacle_positions)} obstacles; the task "
                             f"has {len(self._obstacle_qpos)}")
        data = self.physics.data
        data.qpos[self._arm_qpos] = feedback.position
        data.qvel[self._arm_dof] = feedback.velocity
        data.qpos[self._cube_qpos[:3]] = poses.cube_position
        data.qpos[self._cube_qpos[3:]] = poses.cube_quaternion
        data.qvel[self._cube_dof] = poses.cube_velocity
        data.qpos[self._obstacle_qpos[:, :3]] = poses.obstacle_positions
        data.qpos[self._obstacle_qpos[:, 3:]] = poses.obstacle_quaternions
        data.qvel[self._obstacle_dof] = poses.obstacle_velocities
        data.time = self._start + elapsed
        self._mujoco.mj_kinematics(self.physics.model.ptr, data.ptr)
        self.task.after_step(self.physics, self.random_state)
        return self.task.step_info

    def observation(self) -> np.ndarray:
        """The training observation vector (layout: ``task.observation_order``)."""
        return self.task.flat_observation(self.physics)

    def record_command(self, command: np.ndarray) -> None:
        """The command actually sent (rad/s): the next observation's previous action."""
        self.task.before_step(self.physics, command, self.random_state)

    def make_collision_scene(self):
        return self.task.make_collision_scene(self.physics)

    def place_objects(self, scene) -> None:
        self.task.place_objects(scene, self.physics)


# ---------------------------------------------------------------------------------------------
# Controllers: world -> nominal joint velocities (rad/s, all joints)
# ---------------------------------------------------------------------------------------------


class ScriptedController:
    """The scripted mink pusher, run on the :class:`WorldModel`'s mirror physics."""

    name = "scripted"
    cartesian = False  # returns joint velocities, rad/s

    def __init__(self, world: WorldModel, config: Config) -> None:
        from ahrm_stack.env.scripted import ScriptedPusher

        self.world = world
        self.pusher = ScriptedPusher(world.task, config.scripted)

    def reset(self) -> None:
        """Plan the episode from the current world (after the first update)."""
        self.pusher.reset(self.world.physics)

    def __call__(self) -> np.ndarray:
        return self.pusher(self.world.physics)

    @property
    def stage(self) -> str:
        return self.pusher.stage


class PolicyController:
    """A trained policy (deterministic action) on the training observation vector. Its request is
    what training's environment made of the action: joint velocities (rad/s, ``action.mode:
    joint``) or a pusher-tip velocity (m/s, world frame, ``cartesian``: :attr:`cartesian` is
    then true and the loop hands it to the filter's differential IK)."""

    name = "policy"

    def __init__(self, world: WorldModel, actor, config: Config) -> None:
        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        from ahrm_stack.env.torchrl_env import action_to_command

        self.cartesian = config.task.action.mode == "cartesian"
        self._max_tip_speed = config.task.action.cartesian_max_speed
        self.world = world
        self.actor = actor
        self._torch, self._tensordict = torch, TensorDict
        self._deterministic, self._exploration = set_exploration_type, ExplorationType
        self._to_command = action_to_command
        robot = world.robot
        self._limit, self._commanded = robot.velocity_limit, robot.commanded_joints

    def reset(self) -> None:
        pass

    def __call__(self) -> np.ndarray:
        torch = self._torch
        observation = torch.as_tensor(self.world.observation(), dtype=torch.float32)
        with torch.no_grad(), self._deterministic(self._exploration.DETERMINISTIC):
            action = self.actor(self._tensordict({"observation": observation}, batch_size=[]))
        action = action["action"].numpy()
        if self.cartesian:
            finite = np.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)
            return np.clip(finite, -1.0, 1.0) * self._max_tip_speed
        return self._to_command(action, self._limit, self._commanded)

    @property
    def stage(self) -> str:
        return "policy"


# ---------------------------------------------------------------------------------------------
# The loop
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class DeploySummary:
    success: bool
    duration: float  # s of loop time
    ticks: int
    interventions: int  # ticks whose command the safety filter modified
    fallbacks: int
    deadline_misses: int
    latency_p50_ms: float  # feedback received -> command sent
    latency_p99_ms: float
    stop_reason: str
    emergency_stops: int
    adapter_refusals: int

    def __str__(self) -> str:
        return (f"deploy summary: success {self.success} | duration {self.duration:.2f} s | "
                f"ticks {self.ticks} | interventions {self.interventions} | fallbacks "
                f"{self.fallbacks} | deadline misses {self.deadline_misses} | latency p50 "
                f"{self.latency_p50_ms:.3f} ms p99 {self.latency_p99_ms:.3f} ms | e-stops "
                f"{self.emergency_stops} | stop: {self.stop_reason}")


class _Halt(Exception):
    """Internal: end the run; the arm was already stopped or e-stopped."""


class DeployLoop:
    """One deployment run on ``arm`` (a connected :class:`~hardware.protocol.ArmAdapter` with a
    ``perception()`` method), paced by the adapter's clock.

    Args:
        arm: the adapter; its ``clock`` paces the loop and stamps the feedback.
        world: the :class:`WorldModel` of the deployed task.
        controller: a :class:`ScriptedController` or :class:`PolicyController`.
        safety: the ``safety`` config; the loop turns the obstacle rows on.
        settings: the deploy settings (rate, watchdog).
        telemetry: an open text file for the JSONL log, or None.
    """

    def __init__(self, arm, world: WorldModel, controller, safety, settings: DeploySettings,
                 telemetry=None) -> None:
        from ahrm_stack.safety import InterventionStats, make_filter

        if not safety.enabled:
            raise DeployConfigError("safety.enabled is false: the deploy loop never runs without "
                                    "the safety filter")
        self.arm, self.world, self.controller = arm, world, controller
        self.settings = settings
        self.period = settings.period
        self.clock = arm.clock
        self.telemetry = telemetry
        task = world.task
        robot = task.robot
        self._lower, self._upper = robot.position_lower, robot.position_upper
        self._speed_alarm = robot.velocity_limit * (1.0 + settings.watchdog.velocity_tolerance)
        self.scene = world.make_collision_scene()
        self.filter = make_filter(robot, task.kinematics,
                                  dataclasses.replace(safety, obstacle_rows=True),
                                  control_period=self.period, table_height=task.config.table.height,
                                  tip_site=task.pusher.tip_site, wrist_site=task.arm.wrist_site,
                                  scene=self.scene)
        # a Cartesian request (tip velocity, m/s) goes through the same QP as differential IK
        self._solve = self.filter.cartesian if getattr(controller, "cartesian", False) else self.filter
        self.stats = InterventionStats()
        self.latencies: list[float] = []  # s, feedback received -> command sent
        self.deadline_misses = 0
        self.emergency_stops = 0
        self.adapter_refusals = 0
        self.success = False
        self.stop_reason = ""
        self.stopped_at: float | None = None  # clock time the arm was stopped / e-stopped
        self.halted = False
        self.interrupted = False
        self._sent = np.zeros(robot.num_joints)
        self._last_frame = -1
        self._ticks = 0
        self._t0 = 0.0
        self._started = False

    # ------------------------------------------------------------------ helpers
    def _event(self, level: int, kind: str, message: str) -> None:
        log.log(level, "deploy: %s: %s", kind.upper(), message)
        if self.telemetry is not None:
            self.telemetry.write(json.dumps({"t": round(self.clock.now() - self._t0, 6),
                                             "event": kind, "reason": message}) + "\n")

    def _halt(self, reason: str, emergency: bool, level: int = logging.WARNING) -> None:
        """Stop (or e-stop) the arm, log why (``level``; e-stops at ERROR), end the run."""
        self.stop_reason = reason
        self.halted = True
        self._sent = np.zeros_like(self._sent)
        try:
            if emergency:
                self.arm.apply_emergency_stop()
                self.emergency_stops += 1
            else:
                self.arm.stop()
        except HardwareError as error:  # e.g. the link is gone: the arm's own watchdog stops it
            log.error("deploy: could not %s the arm (%s)", "e-stop" if emergency else "stop",
                      type(error).__name__)
        self.stopped_at = self.clock.now()
        self._event(logging.ERROR if emergency else level,
                    "emergency stop" if emergency else "stop", reason)
        raise _Halt(reason)

    def _check_feedback(self, feedback) -> None:
        age = self.clock.now() - feedback.timestamp
        max_age = self.settings.watchdog.max_feedback_age * self.period
        if feedback.frame_id <= self._last_frame or age > max_age:
            self._halt(f"watchdog: stale feedback (frame {feedback.frame_id}, age "
                       f"{age * 1e3:.1f} ms > {max_age * 1e3:.1f} ms)", emergency=False)
        self._last_frame = feedback.frame_id
        for name, values in (("position", feedback.position), ("velocity", feedback.velocity),
                             ("torque", feedback.torque)):
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                self._halt(f"non-finite feedback: {name}[{bad[0]}] = {values[bad[0]]}",
                           emergency=True)
        if not feedback.healthy:
            self._halt(f"arm fault: state {feedback.arm_state.value}, flags {feedback.faults!r}",
                       emergency=True)
        past = np.flatnonzero((feedback.position < self._lower) | (feedback.position > self._upper))
        if past.size:
            i = past[0]
            self._halt(f"limit violation: joint {i} at {feedback.position[i]:.4f} rad, outside "
                       f"[{self._lower[i]:.4f}, {self._upper[i]:.4f}]", emergency=True)
        fast = np.flatnonzero(np.abs(feedback.velocity) > self._speed_alarm)
        if fast.size:
            i = fast[0]
            self._halt(f"limit violation: joint {i} moving at {feedback.velocity[i]:.3f} rad/s, "
                       f"alarm at {self._speed_alarm[i]:.3f} rad/s", emergency=True)

    def _deadline(self, tick_time: float, where: str) -> None:
        late = self.clock.now() - (tick_time + self.settings.watchdog.command_deadline * self.period)
        if late > 0:
            self.deadline_misses += 1
            message = f"missed deadline {where} by {late * 1e3:.2f} ms"
            if self.deadline_misses > self.settings.watchdog.max_deadline_misses:
                self._halt(f"watchdog: {message}", emergency=False)
            self._event(logging.WARNING, "deadline", message)

    @property
    def next_tick_time(self) -> float:
        """Clock time (s) at which the next :meth:`tick` begins."""
        return self._t0 + self._ticks * self.period

    # ------------------------------------------------------------------ the loop
    def start(self) -> None:
        """Synchronise with the arm: first feedback, plan, warm the controller and filter (so
        their first-call costs do not hit a deadline), then schedule tick 0 at the clock's now."""
        if self.arm.servoing_mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            self.arm.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
        self.arm.stop()
        feedback = self.arm.refresh_feedback()
        self._last_frame = feedback.frame_id - 1
        self._t0 = self.clock.now()
        self.world.update(feedback, self.arm.perception(), 0.0)
        self.controller.reset()
        self.world.place_objects(self.scene)
        self._solve(feedback.position, feedback.velocity, self.controller(), u_prev=self._sent)
        self.filter.reset()
        self.controller.reset()
        self._sent = np.zeros_like(self._sent)
        self._t0 = self.clock.now()
        self._started = True

    def resume(self) -> None:
        """Continue after a halt (the caller cleared the arm's faults / reconnected it)."""
        self.halted = False
        self.stop_reason = ""
        self._sent = np.zeros_like(self._sent)
        self.filter.reset()
        feedback = self.arm.refresh_feedback()
        self._last_frame = feedback.frame_id - 1
        self._ticks = int(math.ceil((self.clock.now() - self._t0) / self.period))

    def tick(self) -> bool:
        """One control period; False when the run ended (success or a halt)."""
        tick_time = self._t0 + self._ticks * self.period
        self.clock.sleep_until(tick_time)
        self._ticks += 1
        try:
            try:
                feedback = self.arm.refresh_feedback()
            except FeedbackTimeoutError:
                self._halt("watchdog: feedback dropped (no frame in time)", emergency=False)
            except ConnectionLostError:
                self._halt("connection lost: the arm's own watchdog stops it", emergency=False)
            received = time.perf_counter()
            self._check_feedback(feedback)
            poses = self.arm.perception()
            if not poses.finite:
                self._halt("non-finite perception (object poses)", emergency=False)
            elapsed = tick_time - self._t0
            info = self.world.update(feedback, poses, elapsed)
            if info.success:
                self.success = True
                self._halt("success: the cube left the table", emergency=False, level=logging.INFO)
            u_nom = self.controller()
            self.world.place_objects(self.scene)
            result = self._solve(feedback.position, feedback.velocity, u_nom, u_prev=self._sent)
            self.stats.add(result)
            if result.violated:
                self._halt(f"safety filter reports violated constraints {list(result.violated)}",
                           emergency=True)
            self._deadline(tick_time, "before the command")
            try:
                sent = self.arm.send_joint_speeds(result.command)
            except CommandRefusedError as error:
                self.adapter_refusals += 1
                self.emergency_stops += 1
                self._halt(f"adapter refused the command and e-stopped: {error}", emergency=False)
            except ArmFaultError as error:
                self._halt(f"arm in fault: {error}", emergency=True)
            except ConnectionLostError:
                self._halt("connection lost: the arm's own watchdog stops it", emergency=False)
            latency = time.perf_counter() - received
            self.latencies.append(latency)
            self._sent = sent
            self._deadline(tick_time, "sending the command")
            self.world.record_command(sent)
            if self.telemetry is not None:
                self.telemetry.write(json.dumps({
                    "t": round(elapsed, 6), "phase": int(info.phase), "x": round(float(info.x), 6),
                    "stage": self.controller.stage,
                    "u_nom": [round(float(v), 6) for v in u_nom],
                    "u": [round(float(v), 6) for v in sent], "active": list(result.active),
                    "status": result.status, "latency_ms": round(latency * 1e3, 4)}) + "\n")
            return True
        except _Halt:
            return False
        except HardwareError as error:  # anything else from the adapter: stop, never continue
            try:
                self._halt(f"adapter error {type(error).__name__}: {error}", emergency=True)
            except _Halt:
                return False

    def run(self, duration: float) -> DeploySummary:
        """Tick until success, a halt or ``duration`` s, then stop the arm. Ctrl-C (SIGINT) stops
        the arm too, sets :attr:`interrupted` and returns the summary."""
        ticks = int(round(duration / self.period))
        try:
            if not self._started:
                self.start()
            while self._ticks < ticks and self.tick():
                pass
            if not self.halted:
                try:
                    self._halt(f"duration of {duration:g} s reached", emergency=False,
                               level=logging.INFO)
                except _Halt:
                    pass
        except KeyboardInterrupt:
            self.interrupted = True
            try:
                self._halt("interrupted (Ctrl-C / SIGINT / SIGTERM)", emergency=False)
            except _Halt:
                pass
        finally:
            if self.telemetry is not None:
                self.telemetry.flush()
        return self.summary()

    def summary(self) -> DeploySummary:
        latencies = np.asarray(self.latencies) * 1e3
        p50, p99 = (np.percentile(latencies, [50, 99]) if latencies.size else (math.nan, math.nan))
        return DeploySummary(
            success=self.success, duration=self._ticks * self.period, ticks=self._ticks,
            interventions=self.stats.interventions, fallbacks=self.stats.fallbacks,
            deadline_misses=self.deadline_misses, latency_p50_ms=float(p50),
            latency_p99_ms=float(p99), stop_reason=self.stop_reason,
            emergency_stops=self.emergency_stops, adapter_refusals=self.adapter_refusals)


# ---------------------------------------------------------------------------------------------
# Building a run, and the command line
# ---------------------------------------------------------------------------------------------


def make_controller(world: WorldModel, config: Config, actor=None):
    return ScriptedController(world, config) if actor is None else PolicyController(world, actor, config)


def load_controller_config(checkpoint: Path | None,
                           overrides: Sequence[str] = ()) -> tuple[Config, object]:
    """The config (and actor) of a checkpoint run, or the repository's config with ``overrides``
    (``key=value``, e.g. ``task.robot=j2s6s200``) and no actor. A checkpoint fixes its own config
    (the arm it was trained on), so it takes no overrides."""
    if checkpoint is None:
        return load_config(overrides), None
    if overrides:
        raise ConfigError(f"overrides {list(overrides)} cannot change a checkpoint's config "
                          f"({checkpoint}/config.yaml fixes the arm and the task)")
    import torch

    from ahrm_stack.learning.evaluation import load_policy

    torch.set_num_threads(1)
    return load_policy(Path(checkpoint))


def deploy_sim(settings: DeploySettings, checkpoint: Path | None = None,
               overrides: Sequence[str] = ()) -> DeployLoop:
    """One run of the deploy loop against the sim backend; returns the finished loop (its
    :meth:`DeployLoop.summary`, :attr:`DeployLoop.interrupted`). ``overrides``: config
    ``key=value`` pairs for the scripted controller's run (no checkpoint)."""
    from hardware.sim import SimArm

    config, actor = load_controller_config(checkpoint, overrides)
    clock = WallClock() if settings.realtime else FastClock()
    arm = SimArm(config.task, seed=settings.seed, clock=clock,
                 command_delay=settings.sim.command_delay)
    world = WorldModel(config.task, seed=settings.seed)
    controller = make_controller(world, config, actor)
    telemetry = None
    if settings.telemetry:
        path = Path(settings.telemetry)
        path.parent.mkdir(parents=True, exist_ok=True)
        telemetry = path.open("w")
    try:
        with arm:
            loop = DeployLoop(arm, world, controller, config.safety, settings, telemetry)
            summary = loop.run(settings.duration)
        if telemetry is not None:
            telemetry.write(json.dumps({"summary": dataclasses.asdict(summary)}) + "\n")
    finally:
        if telemetry is not None:
            telemetry.close()
    return loop


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = _Parser(prog="python -m ahrm_stack.deploy",
                     description="Run the deployment loop (policy or scripted controller → safety "
                                 "filter → arm adapter).")
    parser.add_argument("--backend", choices=["sim"], required=True,
                        help="arm adapter (the kortex backend has no perception module yet)")
    parser.add_argument("--checkpoint", type=Path, help="run folder with config.yaml and policy.pt "
                        "(default: the scripted controller)")
    parser.add_argument("--duration", type=float, help="s (default: deploy.yaml)")
    parser.add_argument("--rate", type=float, dest="rate_hz", help="loop rate, Hz (default: deploy.yaml)")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--realtime", dest="realtime", action="store_const", const=True,
                      help="pace to the wall clock")
    pace.add_argument("--fast", dest="realtime", action="store_const", const=False,
                      help="as fast as possible (sim only)")
    parser.add_argument("--seed", type=int, help="sim layout seed (default: deploy.yaml)")
    parser.add_argument("--telemetry", help="JSONL log path ('' for none; default: deploy.yaml)")
    parser.add_argument("--config", type=Path, default=DEPLOY_CONFIG, help="deploy settings YAML")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides without --checkpoint, e.g. task.robot=j2s6s200")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("ahrm_stack.env.runner").setLevel(logging.ERROR)  # the sim filters nothing:
    # by design, the deploy loop does
    try:
        settings = load_deploy_settings(args.config, rate_hz=args.rate_hz, duration=args.duration,
                                        realtime=args.realtime, seed=args.seed,
                                        telemetry=args.telemetry)
    except DeployConfigError as error:
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2

    def terminate(signum, frame):  # SIGTERM stops the arm like Ctrl-C
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        loop = deploy_sim(settings, args.checkpoint, args.overrides)
    except ConfigError as error:
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # during set-up, before the arm moved
        print("interrupted before the loop started", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    summary = loop.summary()
    print(summary)
    if loop.interrupted:
        return 130
    return 0 if summary.success else 1


if __name__ == "__main__":
    sys.exit(main())
