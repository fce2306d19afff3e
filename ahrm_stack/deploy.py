"""The deployment loop: feedback → kinematics and phase → controller → safety filter → command.

Usage::

    python -m ahrm_stack.deploy --backend sim|kinova-gen2 [--checkpoint RUN_DIR] [--duration S]
                                [--rate HZ] [--realtime | --fast] [--seed N] [--telemetry PATH]

Without ``--checkpoint`` the scripted mink controller drives the arm; with one, the run's
deterministic policy does (its ``config.yaml`` gives the task, so the arm model is the trained one).
Settings come from ``configs/deploy.yaml`` (:func:`load_deploy_settings`); the task, safety and
scripted sections from ``configs/*.yaml`` as in training.

The safety filter's settings are always deploy's own (``configs/safety.yaml``, plus ``key=value``
overrides for the scripted controller). A checkpoint's ``safety`` section may only tighten them
(:func:`merge_safety`: a larger margin, a lower limit, more rows, a smaller workspace box, a row
family turned on); a weaker value is ignored, and every difference is printed (a WARNING naming the
key for a weaker one) and written to the telemetry. Ignoring rather than refusing lets a policy
trained with a lighter filter (or none: an ablation) be deployed behind the full one.

Exit status: 0 success; 1 the run ended without success (duration, watchdog, hardware stop);
2 bad input (settings, command line, checkpoint, a refused pickle: a one-line error, nothing
written, the arm never touched); 3 a software fault stopped the arm (:class:`DeployFault`);
130 Ctrl-C / SIGTERM.

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

Ctrl-C (SIGINT) and SIGTERM stop the arm before the program exits. So does every fault: an
exception in start-up, perception, the world model, the controller or the filter, a wrong obstacle
count, or a controller request that is not finite (NaN from a policy is a fault, never zeroed):
the arm is commanded to zero velocity in the tick that sees it, the stop and its cause are logged,
and the run ends (:class:`DeployFault`). Every tick and every event is a line of the JSONL
telemetry log (time, phase, nominal and filtered command, active constraints, loop latency); every
run, however it ends, closes with a summary line (success, duration, interventions, deadline
misses, latency p50/p99, stop reason, fault).

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
from hardware.protocol import (ArmFaultError, CommandRefusedError, ConnectionLostError,
                               FeedbackTimeoutError, HardwareError, ServoingMode)

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
    rpc_timeout_ms: int  # every feedback / motion / mode RPC
    session_rpc_timeout_ms: int  # CreateSession / CloseSession
    watchdog_periods: float  # control periods without a fresh command before Stop
    watchdog_poll_periods: float  # control periods between two watchdog checks
    reset_wait_ms: int  # clear_faults waits this long for the arm to leave fault
    reset_poll_ms: int  # feedback polls during that wait
    reset_estop_repeats: int  # ApplyEmergencyStop calls before ClearFaults
    feedback_tick_ms: float  # the arm's cyclic period: one step of Feedback.frame_id
    frame_id_modulus: int  # Feedback.frame_id wraps at this value


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
    kinova_gen2: Any  # hardware.kinova_gen2.Gen2Settings (validated there)

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


def control_periods(duration: float, period: float) -> int:
    """Ticks of a run of ``duration`` s at ``period`` s per tick."""
    return int(round(duration / period))


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


def _kortex_link(kx: dict) -> dict:
    """The Kortex link's timeouts, watchdog and reset numbers of ``deploy.kortex``, validated."""
    def number(key: str, **kinds):
        return _number(kx[key], f"kortex.{key}", **kinds)

    link = {key: number(key, integer=True, positive=True)
            for key in ("rpc_timeout_ms", "session_rpc_timeout_ms", "reset_wait_ms",
                        "reset_poll_ms", "reset_estop_repeats", "frame_id_modulus")}
    link.update({key: number(key, positive=True)
                 for key in ("watchdog_periods", "watchdog_poll_periods", "feedback_tick_ms")})
    if link["watchdog_periods"] <= 1.0:
        raise DeployConfigError(f"deploy.kortex.watchdog_periods must be > 1 (a healthy loop sends "
                                f"one command per period), got {link['watchdog_periods']!r}")
    if link["watchdog_poll_periods"] > 0.5 * link["watchdog_periods"]:
        raise DeployConfigError("deploy.kortex.watchdog_poll_periods must be <= half of "
                                f"deploy.kortex.watchdog_periods, got {link['watchdog_poll_periods']!r}")
    if link["reset_poll_ms"] > link["reset_wait_ms"]:
        raise DeployConfigError("deploy.kortex.reset_poll_ms must be <= deploy.kortex.reset_wait_ms, "
                                f"got {link['reset_poll_ms']!r}")
    if link["frame_id_modulus"] < 2:
        raise DeployConfigError(f"deploy.kortex.frame_id_modulus must be >= 2, got "
                                f"{link['frame_id_modulus']!r}")
    return link


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
        credentials_file=_optional_str(kx["credentials_file"], "kortex.credentials_file"),
        **_kortex_link(kx))
    from hardware.kinova_gen2 import gen2_settings_from_dict

    try:
        kinova_gen2 = gen2_settings_from_dict(top["kinova_gen2"])
    except ValueError as error:
        raise DeployConfigError(str(error)) from None
    rate_hz = _number(top["rate_hz"], "rate_hz", positive=True)
    duration = _number(top["duration"], "duration", positive=True)
    if control_periods(duration, 1.0 / rate_hz) < 1:
        raise DeployConfigError(f"deploy.rate_hz {rate_hz!r} Hz with deploy.duration "
                                f"{duration!r} s gives no control period: the loop would not run")
    if 1e3 / rate_hz > kortex.connection_inactivity_timeout_ms:
        raise DeployConfigError(f"deploy.rate_hz {rate_hz!r} Hz: a control period of "
                                f"{1 / rate_hz:g} s is longer than deploy.kortex.connection_inactivity_timeout_ms "
                                f"({kortex.connection_inactivity_timeout_ms} ms), after which the "
                                "arm stops itself between two commands")
    return DeploySettings(
        rate_hz=rate_hz,
        duration=duration,
        realtime=top["realtime"],
        seed=_number(top["seed"], "seed", integer=True, nonnegative=True),
        telemetry=top["telemetry"],
        watchdog=watchdog,
        sim=SimSettings(command_delay=_number(sim["command_delay"], "sim.command_delay",
                                              nonnegative=True)),
        kortex=kortex,
        kinova_gen2=kinova_gen2)


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
        given = [f"{k}={v!r}" for k, v in overrides.items()
                 if v is not None and f"deploy.{k} " in f"{error} "]
        where = f"{path} with {', '.join(given)} (command line)" if given else str(path)
        raise DeployConfigError(f"{where}: {error}") from None


# ---------------------------------------------------------------------------------------------
# The safety filter's settings: deploy's own, a checkpoint may only tighten them
# ---------------------------------------------------------------------------------------------

#: Safety settings with a stricter direction, and which direction that is. A checkpoint's value
#: is used where it is stricter (per entry for vectors); where it is weaker it is ignored.
HIGHER_IS_STRICTER = ("position_margin", "velocity_margin", "table_margin", "wrist_table_margin",
                      "obstacle_safe_distance", "obstacle_activation_distance",
                      "max_obstacle_rows", "workspace_lower")
LOWER_IS_STRICTER = ("acceleration_limit", "workspace_upper")
ON_IS_STRICTER = ("enabled", "braking_horizon", "table_rows", "workspace_rows",
                  "table_distance_rows", "obstacle_rows")
# Every other key (solver, osqp_eps, osqp_max_iter, cartesian_regularization,
# cartesian_orientation_weight, and any key added later) is no bound: deploy's value is used.


@dataclasses.dataclass(frozen=True)
class SafetyNote:
    """One difference between deploy's and a checkpoint's safety setting ``key``: ``kind`` is
    ``stricter`` (the checkpoint's value, or its stricter entries, used), ``weaker`` (ignored)
    or ``other`` (no stricter direction: deploy's value used); ``text`` is the printed line."""

    key: str
    kind: str
    text: str


def _show(value: Any) -> str:
    return repr(list(value)) if isinstance(value, tuple) else repr(value)


def require_filter(safety) -> None:
    """:class:`DeployConfigError` unless ``safety`` (a SafetyConfig) turns the filter on."""
    if not safety.enabled:
        raise DeployConfigError("safety.enabled is false: the deploy loop never runs without the "
                                "safety filter")


def merge_safety(deploy, checkpoint) -> tuple[Any, list[SafetyNote]]:
    """The safety settings a checkpoint run is deployed with: ``deploy``'s (configs/safety.yaml as
    deploy reads it), tightened wherever ``checkpoint`` (the run's ``config.yaml``) is stricter;
    a weaker checkpoint value is ignored. Both are :class:`~ahrm_stack.config.SafetyConfig`.

    Returns the merged settings and one :class:`SafetyNote` per differing key. Raises
    :class:`DeployConfigError` when deploy's own settings turn the filter off, or when the
    tightened settings contradict each other (an empty workspace box, an activation distance not
    above the safe distance)."""
    require_filter(deploy)
    merged, notes = {}, []
    for field in dataclasses.fields(deploy):
        key, ours, theirs = field.name, getattr(deploy, field.name), getattr(checkpoint, field.name)
        if ours == theirs:
            continue
        name = f"safety.{key}"
        said = f"{name}: the checkpoint's {_show(theirs)}"
        if key in ON_IS_STRICTER:
            if theirs:
                merged[key] = True
                notes.append(SafetyNote(key, "stricter", f"{said} is stricter than deploy's "
                                        f"{_show(ours)}: using {_show(theirs)}"))
            else:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)}: ignored, using {_show(ours)}"))
        elif key in HIGHER_IS_STRICTER or key in LOWER_IS_STRICTER:
            pick = max if key in HIGHER_IS_STRICTER else min
            vector = isinstance(ours, tuple)
            a, b = (ours, theirs) if vector else ((ours,), (theirs,))
            if len(a) != len(b):
                notes.append(SafetyNote(key, "weaker", f"{said} has {len(b)} entries, deploy's "
                                        f"{len(a)}: ignored, using {_show(ours)}"))
                continue
            if not all(math.isfinite(y) for y in b):
                notes.append(SafetyNote(key, "weaker", f"{said} is not finite: ignored, using "
                                        f"{_show(ours)}"))
                continue
            best = tuple(pick(x, y) for x, y in zip(a, b))
            value = best if vector else best[0]
            weaker = [i for i, (x, y) in enumerate(zip(a, b)) if pick(x, y) == x != y]
            stricter = [i for i, (x, y) in enumerate(zip(a, b)) if pick(x, y) == y != x]
            if value != ours:
                merged[key] = value
            if weaker and stricter:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)} in entries {weaker} (ignored there) and "
                                        f"stricter in entries {stricter}: using {_show(value)}"))
            elif weaker:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)}: ignored, using {_show(ours)}"))
            else:
                notes.append(SafetyNote(key, "stricter", f"{said} is stricter than deploy's "
                                        f"{_show(ours)}: using {_show(value)}"))
        else:
            notes.append(SafetyNote(key, "other", f"{said} differs from deploy's {_show(ours)} "
                                    f"(not a safety bound): using {_show(ours)}"))
    result = dataclasses.replace(deploy, **merged)
    for i, (lo, hi) in enumerate(zip(result.workspace_lower, result.workspace_upper)):
        if not lo < hi:
            raise DeployConfigError(f"safety.workspace_lower/workspace_upper: deploy's workspace "
                                    f"box and the checkpoint's do not overlap on axis {i} "
                                    f"([{lo}, {hi}] after tightening)")
    if result.obstacle_activation_distance <= result.obstacle_safe_distance:
        raise DeployConfigError(
            f"safety.obstacle_activation_distance {result.obstacle_activation_distance} must "
            f"exceed safety.obstacle_safe_distance {result.obstacle_safe_distance} after taking "
            "the checkpoint's stricter values")
    return result, notes


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
        from ahrm_stack.learning.ppo import lean_actor

        self.cartesian = config.task.action.mode == "cartesian"
        self._max_tip_speed = config.task.action.cartesian_max_speed
        self.world = world
        self.actor = actor
        # An actor of make_modules (or its LeanActor, what load_policy gives) runs as one plain
        # torch forward on the observation tensor: the same deterministic action, no TensorDict.
        lean = lean_actor(actor)
        self._act = None if lean is None else lean.act
        self._torch, self._tensordict = torch, TensorDict
        self._deterministic, self._exploration = set_exploration_type, ExplorationType
        self._to_command = action_to_command
        robot = world.robot
        self._limit, self._commanded = robot.velocity_limit, robot.commanded_joints

    def reset(self) -> None:
        pass

    def __call__(self) -> np.ndarray:
        """The request for this tick: joint velocities (rad/s) or the tip velocity (m/s, world
        frame); an entry whose action was NaN or infinite is NaN (the loop stops on it)."""
        torch = self._torch
        observation = torch.as_tensor(self.world.observation(), dtype=torch.float32)
        if self._act is not None:
            action = self._act(observation)
        else:  # any other policy: the TensorDict call
            with torch.no_grad(), self._deterministic(self._exploration.DETERMINISTIC):
                action = self.actor(self._tensordict({"observation": observation}, batch_size=[]))["action"]
        action = np.asarray(action.numpy(), dtype=float).reshape(-1)
        bad = ~np.isfinite(action)
        if self.cartesian:
            command = np.clip(action, -1.0, 1.0) * self._max_tip_speed
            command[bad] = np.nan
            return command
        command = self._to_command(action, self._limit, self._commanded)
        # a non-finite action is a fault, not a zero: it stays NaN for the loop to flag
        command[np.asarray(self._commanded, dtype=int)[bad[:len(self._commanded)]]] = np.nan
        return command

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
    fault: str = ""  # the software fault that stopped the run (exception, NaN request), or ''

    def __str__(self) -> str:
        return (f"deploy summary: success {self.success} | duration {self.duration:.2f} s | "
                f"ticks {self.ticks} | interventions {self.interventions} | fallbacks "
                f"{self.fallbacks} | deadline misses {self.deadline_misses} | latency p50 "
                f"{self.latency_p50_ms:.3f} ms p99 {self.latency_p99_ms:.3f} ms | e-stops "
                f"{self.emergency_stops} | stop: {self.stop_reason}")


class DeployFault(RuntimeError):
    """A software fault stopped the run: an exception in start-up, perception, the world model,
    the controller, the safety filter or the loop itself, or a non-finite controller request. The
    arm was commanded to zero velocity and the stop and the summary were recorded before this is
    raised. ``summary`` is the run's :class:`DeploySummary`; ``__cause__`` the original exception
    (None for a NaN request)."""

    def __init__(self, message: str, summary: DeploySummary) -> None:
        super().__init__(message)
        self.summary = summary


class _Halt(Exception):
    """Internal: end the run; the arm was already stopped or e-stopped."""


class DeployLoop:
    """One deployment run on ``arm`` (a connected :class:`~hardware.protocol.ArmAdapter` with a
    ``perception()`` method), paced by the adapter's clock.

    Every way a run ends commands the arm to stop (zero velocity, or an e-stop), writes a stop
    event with its cause to the log and the telemetry, and (through :meth:`run`) the summary: the
    watchdog and hardware checks, the safety filter's report, an adapter error, success, the
    duration, Ctrl-C, and any exception in start-up or in a tick's stages (a *fault*: the stop
    reason names the stage, ``perception fault: ValueError: ...``; :meth:`run` then raises
    :class:`DeployFault`). A controller request that is not finite (NaN from a policy) is a fault
    too, never a silent zero.

    Args:
        arm: the adapter; its ``clock`` paces the loop and stamps the feedback.
        world: the :class:`WorldModel` of the deployed task.
        controller: a :class:`ScriptedController` or :class:`PolicyController`.
        safety: the ``safety`` config; the loop turns the obstacle rows on.
        settings: the deploy settings (rate, watchdog).
        telemetry: an open text file for the JSONL log, or None.
        scene: where perception comes from: a scene source (``poses()`` -> ObjectPoses, e.g.
            :mod:`ahrm_stack.perception`'s camera scene), or None for the adapter's
            ``perception()``. An exception from it is a perception fault (the arm stops).
    """

    def __init__(self, arm, world: WorldModel, controller, safety, settings: DeploySettings,
                 telemetry=None, scene=None) -> None:
        from ahrm_stack.safety import InterventionStats, make_filter

        require_filter(safety)
        self.arm, self.world, self.controller = arm, world, controller
        self._perceive = scene.poses if scene is not None else arm.perception
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
        cartesian = getattr(controller, "cartesian", False)
        self._solve = self.filter.cartesian if cartesian else self.filter
        self._request_size = 3 if cartesian else robot.num_joints
        self.stats = InterventionStats()
        self.latencies: list[float] = []  # s, feedback received -> command sent
        self.deadline_misses = 0
        self.emergency_stops = 0
        self.adapter_refusals = 0
        self.success = False
        self.stop_reason = ""
        self.fault = ""  # the stop reason when a software fault stopped the run
        self.error: BaseException | None = None  # the exception behind the fault, if any
        self.stopped_at: float | None = None  # clock time the arm was stopped / e-stopped
        self.tick_time: float | None = None  # clock time the current (or last) tick began
        self.halted = False
        self.interrupted = False
        self._sent = np.zeros(robot.num_joints)
        self._last_frame = -1
        self._ticks = 0
        self._t0 = 0.0
        self._started = False
        self._stage = "start-up"

    # ------------------------------------------------------------------ helpers
    def _write(self, record: dict) -> None:
        """A telemetry line; a failing log never stops the stop logic (the error is logged)."""
        if self.telemetry is None:
            return
        try:
            self.telemetry.write(json.dumps(record) + "\n")
        except (OSError, ValueError) as error:  # disk full, a closed file
            log.error("deploy: telemetry write failed (%s: %s)", type(error).__name__, error)

    def _event(self, level: int, kind: str, message: str) -> None:
        log.log(level, "deploy: %s: %s", kind.upper(), message)
        self._write({"t": round(self.clock.now() - self._t0, 6), "event": kind, "reason": message})

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
        except Exception as error:  # e.g. the link is gone: the arm's own watchdog stops it
            log.error("deploy: could not %s the arm (%s)", "e-stop" if emergency else "stop",
                      type(error).__name__)
            if emergency:  # a plain stop is the next best command
                try:
                    self.arm.stop()
                except Exception:  # noqa: BLE001 - nothing more to try from here
                    pass
        self.stopped_at = self.clock.now()
        self._event(logging.ERROR if emergency else level,
                    "emergency stop" if emergency else "stop", reason)
        raise _Halt(reason)

    def _stop_on_fault(self, error: BaseException | None, reason: str) -> None:
        """Record a software fault (``reason``; ``error`` the exception, if any), stop the arm."""
        self.fault = reason
        self.error = error
        try:
            self._halt(reason, emergency=False, level=logging.ERROR)
        except _Halt:
            pass

    def _fault_reason(self, error: BaseException) -> str:
        text = (str(error).splitlines() or [""])[0][:300]
        return f"{self._stage} fault: {type(error).__name__}" + (f": {text}" if text else "")

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

    def _check_request(self, u_nom) -> np.ndarray:
        """The controller's request as a float vector; a wrong size or a non-finite entry (NaN
        from a policy) is a controller fault: the arm stops and the run ends."""
        try:
            request = np.asarray(u_nom, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            request = None
        if request is None or request.size != self._request_size:
            reason = (f"controller fault: request {u_nom!r:.80} is not {self._request_size} "
                      "numbers")
            self._stop_on_fault(None, reason)
            raise _Halt(reason)
        bad = np.flatnonzero(~np.isfinite(request))
        if bad.size:
            reason = (f"controller fault: non-finite request u_nom[{bad[0]}] = {request[bad[0]]} "
                      f"({bad.size} of {request.size} entries)")
            self._stop_on_fault(None, reason)
            raise _Halt(reason)
        return request

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
        self._stage = "start-up"
        self._t0 = self.clock.now()
        if self.arm.servoing_mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            self.arm.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
        self.arm.stop()
        feedback = self.arm.refresh_feedback()
        self._last_frame = feedback.frame_id - 1
        self._t0 = self.clock.now()
        self.world.update(feedback, self._perceive(), 0.0)
        self.controller.reset()
        self.world.place_objects(self.scene)
        request = np.asarray(self.controller(), dtype=float).reshape(-1)
        if request.size != self._request_size:
            raise ValueError(f"the controller's request has {request.size} entries, not "
                             f"{self._request_size}")
        if not np.isfinite(request).all():  # never sent: each tick checks its own request
            log.warning("deploy: the controller's warm-up request is not finite: %s", request)
            request = np.zeros_like(request)
        self._solve(feedback.position, feedback.velocity, request, u_prev=self._sent)
        self.filter.reset()
        self.controller.reset()
        self._sent = np.zeros_like(self._sent)
        self._t0 = self.clock.now()
        self._started = True

    def resume(self) -> None:
        """Continue after a halt (the caller cleared the arm's faults / reconnected it)."""
        self.halted = False
        self.stop_reason = ""
        self.fault = ""
        self.error = None
        self._sent = np.zeros_like(self._sent)
        self.filter.reset()
        feedback = self.arm.refresh_feedback()
        self._last_frame = feedback.frame_id - 1
        self._ticks = int(math.ceil((self.clock.now() - self._t0) / self.period))

    def tick(self) -> bool:
        """One control period; False when the run ended (success, a halt or a fault: the arm is
        then stopped and the stop recorded). Never raises but for Ctrl-C (KeyboardInterrupt)."""
        tick_time = self._t0 + self._ticks * self.period
        self.clock.sleep_until(tick_time)
        self.tick_time = tick_time
        self._ticks += 1
        try:
            self._stage = "feedback"
            try:
                feedback = self.arm.refresh_feedback()
            except FeedbackTimeoutError:
                self._halt("watchdog: feedback dropped (no frame in time)", emergency=False)
            except ConnectionLostError:
                self._halt("connection lost: the arm's own watchdog stops it", emergency=False)
            received = time.perf_counter()
            self._check_feedback(feedback)
            self._stage = "perception"
            poses = self._perceive()
            if not poses.finite:
                self._halt("non-finite perception (object poses)", emergency=False)
            elapsed = tick_time - self._t0
            info = self.world.update(feedback, poses, elapsed)
            if info.success:
                self.success = True
                self._halt("success: the cube left the table", emergency=False, level=logging.INFO)
            self._stage = "controller"
            u_nom = self._check_request(self.controller())
            self._stage = "safety filter"
            self.world.place_objects(self.scene)
            result = self._solve(feedback.position, feedback.velocity, u_nom, u_prev=self._sent)
            self.stats.add(result)
            if result.violated:
                self._halt(f"safety filter reports violated constraints {list(result.violated)}",
                           emergency=True)
            self._deadline(tick_time, "before the command")
            self._stage = "command"
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
            self._stage = "telemetry"
            self.world.record_command(sent)
            self._write({
                "t": round(elapsed, 6), "phase": int(info.phase), "x": round(float(info.x), 6),
                "stage": self.controller.stage,
                "u_nom": [round(float(v), 6) for v in u_nom],
                "u": [round(float(v), 6) for v in sent], "active": list(result.active),
                "status": result.status, "latency_ms": round(latency * 1e3, 4)})
            return True
        except _Halt:
            return False
        except HardwareError as error:  # anything else from the adapter: stop, never continue
            try:
                self._halt(f"adapter error {type(error).__name__}: {error}", emergency=True)
            except _Halt:
                return False
        except Exception as error:  # noqa: BLE001 - a crash in a stage: stop, record, end the run
            self._stop_on_fault(error, self._fault_reason(error))
            return False

    def run(self, duration: float) -> DeploySummary:
        """Tick until success, a halt or ``duration`` s, then stop the arm; the summary is the
        telemetry's last line. Ctrl-C (SIGINT) stops the arm too, sets :attr:`interrupted` and
        returns the summary. A software fault (start-up, a stage's exception, a NaN request)
        raises :class:`DeployFault` once the arm is stopped and the summary written; any other
        exception escaping the loop (e.g. SystemExit) stops the arm, is recorded, and propagates."""
        ticks = control_periods(duration, self.period)
        try:
            if not self._started:
                try:
                    self.start()
                except HardwareError as error:
                    self._stage = "start-up"
                    self._stop_on_fault(error, f"start-up fault: adapter error "
                                               f"{type(error).__name__}: {error}")
                except Exception as error:  # noqa: BLE001 - perception, controller, filter
                    self._stop_on_fault(error, self._fault_reason(error))
            while not self.halted and self._ticks < ticks and self.tick():
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
        except BaseException as error:  # SystemExit, MemoryError, a bug in the loop itself
            if not self.halted:
                self._stop_on_fault(error, self._fault_reason(error))
            self._finish()
            raise
        summary = self._finish()
        if self.fault:
            raise DeployFault(self.fault, summary) from self.error
        return summary

    def _finish(self) -> DeploySummary:
        summary = self.summary()
        self._write({"summary": dataclasses.asdict(summary)})
        if self.telemetry is not None:
            try:
                self.telemetry.flush()
            except (OSError, ValueError):
                pass
        return summary

    def summary(self) -> DeploySummary:
        latencies = np.asarray(self.latencies) * 1e3
        p50, p99 = (np.percentile(latencies, [50, 99]) if latencies.size else (math.nan, math.nan))
        return DeploySummary(
            success=self.success, duration=self._ticks * self.period, ticks=self._ticks,
            interventions=self.stats.interventions, fallbacks=self.stats.fallbacks,
            deadline_misses=self.deadline_misses, latency_p50_ms=float(p50),
            latency_p99_ms=float(p99), stop_reason=self.stop_reason,
            emergency_stops=self.emergency_stops, adapter_refusals=self.adapter_refusals,
            fault=self.fault)


# ---------------------------------------------------------------------------------------------
# Building a run, and the command line
# ---------------------------------------------------------------------------------------------


def make_controller(world: WorldModel, config: Config, actor=None):
    return ScriptedController(world, config) if actor is None else PolicyController(world, actor, config)


def load_controller_config(checkpoint: Path | None, overrides: Sequence[str] = (),
                           notes: list[SafetyNote] | None = None) -> tuple[Config, object]:
    """The config (and actor) of a checkpoint run, or the repository's config with ``overrides``
    (``key=value``, e.g. ``task.robot=j2s6s200``) and no actor. A checkpoint fixes its own task
    (the arm it was trained on), so it takes no overrides; its safety section never weakens the
    repository's ``configs/safety.yaml`` (:func:`merge_safety`: each difference is logged, and
    appended to ``notes``). Errors are one line: :class:`ConfigError` (the run folder or its
    ``config.yaml``), :class:`~ahrm_stack.learning.checkpoint.CheckpointError` (``policy.pt``,
    e.g. a refused pickle), :class:`DeployConfigError` (the merged safety settings)."""
    if checkpoint is None:
        config = load_config(overrides)
        require_filter(config.safety)
        return config, None
    if overrides:
        raise ConfigError(f"overrides {list(overrides)} cannot change a checkpoint's config "
                          f"({checkpoint}/config.yaml fixes the arm and the task)")
    run = Path(checkpoint)
    for name in ("config.yaml", "policy.pt"):
        if not (run / name).is_file():
            raise ConfigError(f"--checkpoint {run}: no {name} there (a training run folder holds "
                              "config.yaml and policy.pt)")
    deploy_safety = load_config().safety
    import torch

    from ahrm_stack.learning.checkpoint import CheckpointError
    from ahrm_stack.learning.rollouts import load_policy

    torch.set_num_threads(1)
    try:
        config, actor = load_policy(run, runnable=False)  # its safety section is replaced below
    except (ConfigError, CheckpointError):
        raise
    except yaml.YAMLError as error:
        raise ConfigError(f"{run / 'config.yaml'} is not valid YAML "
                          f"({str(error).splitlines()[0]})") from None
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        first = (str(error).splitlines() or [""])[0][:200]
        raise CheckpointError(f"{run / 'policy.pt'} does not fit {run / 'config.yaml'} "
                              f"({type(error).__name__}: {first})") from None
    safety, differences = merge_safety(deploy_safety, config.safety)
    for note in differences:
        log.log(logging.WARNING if note.kind == "weaker" else logging.INFO, "deploy: %s", note.text)
    if notes is not None:
        notes.extend(differences)
    return dataclasses.replace(config, safety=safety), actor


def open_telemetry(path: str):
    """The JSONL telemetry file opened for writing (its folder made), or None for ''; a path that
    cannot be written is a one-line :class:`DeployConfigError`."""
    if not path:
        return None
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        return target.open("w")
    except OSError as error:
        raise DeployConfigError(f"deploy.telemetry: cannot write {target}: "
                                f"{error.strerror or error}") from None


def _start_up_fault(arm, telemetry, error: BaseException) -> DeployFault:
    """A fault before the loop existed (building the sim, the world model, the controller, the
    filter): stop the arm if it is connected, record the stop and a summary; the DeployFault to
    raise."""
    text = (str(error).splitlines() or [""])[0][:300]
    reason = f"start-up fault: {type(error).__name__}" + (f": {text}" if text else "")
    if arm is not None and arm.is_connected:
        try:
            arm.stop()
        except Exception as stop_error:  # noqa: BLE001 - disconnecting stops it as well
            log.error("deploy: could not stop the arm (%s)", type(stop_error).__name__)
    log.error("deploy: STOP: %s", reason)
    summary = DeploySummary(success=False, duration=0.0, ticks=0, interventions=0, fallbacks=0,
                            deadline_misses=0, latency_p50_ms=math.nan, latency_p99_ms=math.nan,
                            stop_reason=reason, emergency_stops=0, adapter_refusals=0, fault=reason)
    if telemetry is not None:
        try:
            telemetry.write(json.dumps({"t": 0.0, "event": "stop", "reason": reason}) + "\n")
            telemetry.write(json.dumps({"summary": dataclasses.asdict(summary)}) + "\n")
        except (OSError, ValueError):
            pass
    return DeployFault(reason, summary)


def deploy_sim(settings: DeploySettings, checkpoint: Path | None = None,
               overrides: Sequence[str] = (), scene: str = "sim",
               layout_file: Path | str | None = None) -> DeployLoop:
    """:func:`deploy` against the sim backend."""
    return deploy(settings, checkpoint, overrides, backend="sim", scene=scene, layout_file=layout_file)


def deploy(settings: DeploySettings, checkpoint: Path | None = None,
           overrides: Sequence[str] = (), backend: str = "sim", scene: str = "sim",
           layout_file: Path | str | None = None) -> DeployLoop:
    """One run of the deploy loop against ``backend`` (a name of
    :data:`hardware.backends.BACKENDS`); returns the finished loop (its
    :meth:`DeployLoop.summary`, :attr:`DeployLoop.interrupted`). ``overrides``: config
    ``key=value`` pairs for the scripted controller's run (no checkpoint).

    ``scene``: ``sim`` (the simulator's exact object poses) or ``camera``
    (:mod:`ahrm_stack.perception`: the cube from the AprilTag on MuJoCo frames of the perception
    camera, ``configs/perception.yaml``; the obstacles from ``layout_file``, or
    ``perception.layout_file``, or else surveyed from the simulator at the start into
    ``layout.yaml`` beside the telemetry).

    Bad input (the settings, the checkpoint, its safety settings, the telemetry path) raises a
    one-line error before anything is written or the arm is touched. From then on every end is
    recorded: a fault in set-up, start-up or the loop stops the arm, writes the stop event and the
    summary to the telemetry and raises :class:`DeployFault`."""
    from hardware import backends

    notes: list[SafetyNote] = []
    config, actor = load_controller_config(checkpoint, overrides, notes)
    chosen = backends.get(backend)
    try:
        chosen.check(config, settings)
    except ValueError as error:
        raise DeployConfigError(str(error)) from None
    if scene == "camera" and backend != "sim":
        raise DeployConfigError(f"--scene camera renders the simulator's table: it runs with --backend "
                                f"sim only (no frame source for a real camera exists), got {backend}")
    perception = None
    if scene == "camera":  # bad settings or a bad layout file: one line, nothing written
        from ahrm_stack.perception.scene_source import LayoutFileObstacles
        from ahrm_stack.perception.settings import load_perception_settings

        perception = load_perception_settings()
        layout_file = layout_file or perception.layout_file or None
        if layout_file:
            LayoutFileObstacles(layout_file, count=len(config.task.obstacles.fixed_layout))
    elif scene != "sim":
        raise DeployConfigError(f"--scene {scene!r}: choose sim or camera")
    control_period = config.task.episode.control_period
    if not math.isclose(settings.period, control_period, rel_tol=1e-9):
        log.warning("deploy: the loop runs at %g Hz; the controller was built for %g Hz "
                    "(task.episode.control_period %g s)", settings.rate_hz, 1.0 / control_period,
                    control_period)
    telemetry = open_telemetry(settings.telemetry)
    arm = source = None
    try:
        for note in notes if telemetry is not None else ():
            telemetry.write(json.dumps({"t": 0.0, "event": "safety setting", "key": note.key,
                                        "kind": note.kind, "reason": note.text}) + "\n")
        try:
            arm = chosen.make(config, settings)
            world = WorldModel(config.task, seed=settings.seed)
            controller = make_controller(world, config, actor)
            arm.connect()
            if perception is not None:
                from ahrm_stack.perception.sim_camera import sim_camera_scene, survey_obstacles

                if not layout_file:  # a survey of the simulated table stands in for a measurement
                    import tempfile

                    folder = (Path(settings.telemetry).parent if settings.telemetry
                              else Path(tempfile.mkdtemp(prefix="deploy-layout-")))
                    layout_file = survey_obstacles(arm, folder / "layout.yaml")
                source = sim_camera_scene(arm, config.task, perception, layout_file)
            loop = DeployLoop(arm, world, controller, config.safety, settings, telemetry, source)
        except Exception as error:  # noqa: BLE001 - recorded, then raised as a fault
            raise _start_up_fault(arm, telemetry, error) from error
        loop.run(settings.duration)
    finally:
        if arm is not None and arm.is_connected:
            arm.disconnect()  # stops the arm as well
        if source is not None:
            source.close()
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
    from hardware.backends import BACKENDS

    parser.add_argument("--backend", choices=list(BACKENDS), required=True,
                        help="arm adapter: " + "; ".join(f"{b.name}: {b.help}"
                                                         for b in BACKENDS.values()))
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
    parser.add_argument("--scene", choices=["sim", "camera"], default="sim",
                        help="object poses: the simulator's (sim) or the AprilTag camera's for the "
                             "cube and a measured layout file for the obstacles (camera; "
                             "configs/perception.yaml)")
    parser.add_argument("--layout-file", type=Path, help="with --scene camera: the measured obstacle "
                        "layout (default: perception.layout_file, else surveyed from the sim)")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides without --checkpoint, e.g. task.robot=j2s6s200")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(__import__("ahrm_stack.cli").cli.quiet_argv(argv))  # --verbose: library warnings too
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

    from ahrm_stack.learning.checkpoint import CheckpointError

    if args.scene == "camera":  # offscreen rendering: MUJOCO_GL must be chosen before mujoco loads
        from ahrm_stack.config import VideoConfig, load_extra
        from ahrm_stack.env.video import RenderError, select_gl_backend

        try:
            select_gl_backend(load_extra(VideoConfig, "video").gl_backends)
        except (RenderError, ConfigError) as error:
            print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
            return 2
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        loop = deploy(settings, args.checkpoint, args.overrides, backend=args.backend,
                      scene=args.scene, layout_file=args.layout_file)
    except (ConfigError, DeployConfigError, CheckpointError) as error:  # before anything moved
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2
    except DeployFault as error:  # the arm was stopped; the stop and the summary are recorded
        print(error.summary)
        print(f"python -m ahrm_stack.deploy: error: the arm was stopped on a fault: {error}",
              file=sys.stderr)
        return 3
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
