"""Typed, validated configuration read from the YAML files in ``configs/``.

Every tunable number of the project lives in ``configs/*.yaml``; this module turns those files into
frozen dataclasses once, at start-up, and rejects anything it does not recognise with an error that
names the file, the dotted key and the allowed keys or values.

Overrides use dotted keys, e.g. ``task.layout.mode=random`` or ``task.episode.duration=30``; values
are parsed as YAML scalars/lists.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
import typing
from pathlib import Path
from typing import Any, Literal, Sequence

import yaml

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
OBJECTIVE_NAMES = ("avoid", "manipulate", "time")


class ConfigError(ValueError):
    """A configuration file, key or value is invalid; the message names which."""


# ----------------------------------------------------------------------------------------------
# Schema.  Field docs state units.  Defaults are NOT given here: every value comes from YAML.
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TableConfig:
    half_extent: tuple[float, float]  # (x, y) half-size of the table top, m
    height: float  # z of the table top surface, m
    thickness: float  # m


@dataclasses.dataclass(frozen=True)
class StartIKConfig:
    """The random start's damped-least-squares IK (``ahrm_stack/env/start_pose.py``)."""

    tries: int  # targets drawn before the home posture is kept
    iterations: int  # IK iterations per target
    damping: float  # of the least-squares step, (m or rad)^2
    max_step: float  # rad, the largest joint change of one iteration
    position_tolerance: float  # m, tip from its target
    tilt_tolerance: float  # rad, pusher axis from straight down


@dataclasses.dataclass(frozen=True)
class ArmConfig:
    base_position: tuple[float, float, float]  # world position of the arm base, m
    base_yaw: float  # rotation of the base about world z, rad
    home: tuple[float, ...]  # initial joint angles of the chosen robot, rad: ``home_deg`` is a
    # mapping robot name -> degrees (or one list for the chosen robot); the entry of ``task.robot``
    # is converted
    joint_jitter: float  # uniform per-joint jitter of the initial posture, rad
    start: Literal["home", "random"]  # home: the jittered home posture; random: the pusher tip
    # placed by IK at a uniform point of ``start_region`` with the pusher pointing down
    start_region: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]  # random
    # start: (lo, hi) of the tip's world x, y and z, m
    start_ik: StartIKConfig


@dataclasses.dataclass(frozen=True)
class PusherConfig:
    radius: float  # m
    length: float  # full length of the cylinder, m
    mass: float  # kg


@dataclasses.dataclass(frozen=True)
class CubeConfig:
    size: float  # edge length, m
    mass: float  # kg
    position: tuple[float, float]  # nominal (x, y) of the cube centre on the table, m
    jitter: float  # uniform (x, y) jitter of the cube position, m


@dataclasses.dataclass(frozen=True)
class ObstacleConfig:
    size: tuple[float, float, float]  # full edge lengths (x, y, z), m
    mass: float  # kg
    fixed_layout: tuple[tuple[float, float], ...]  # (x, y) centres of the default layout, m;
    # its length is the number of obstacles in every mode


@dataclasses.dataclass(frozen=True)
class LayoutConfig:
    mode: Literal["fixed", "random"]
    cube_region: tuple[tuple[float, float], tuple[float, float]]  # random mode: the cube centre
    # uniform in x in [lo, hi] and y in [lo, hi], m (fixed mode: cube.position +- cube.jitter)
    obstacle_draws_per_cube: int  # random mode: obstacle draws before the cube is drawn again
    radial_range: tuple[float, float]  # obstacle distance from the cube centre in random mode, m
    min_gap: float  # smallest allowed gap between two obstacles / obstacle and cube, m
    lane_width: float  # width of the free lane the initializer must keep, m
    approach_room: float  # free length behind the cube (opposite the lane) for the pusher, m
    lane_directions: tuple[str, ...]  # lane directions considered reachable: "+x" and/or "-x"
    max_tries: int  # rejection-sampling attempts before giving up
    settle_steps: int  # physics steps run at reset so the free bodies come to rest


@dataclasses.dataclass(frozen=True)
class RegionConfig:
    target_half_width: float  # m
    target_height: float  # m above the table top
    obstacle_margin: float  # m
    obstacle_height: float  # m above the table top
    distance_clip: float  # m; the reported region distances are exact within +-this, saturated beyond


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    duration: float  # s of simulated time
    control_period: float  # s
    physics_timestep: float  # s


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    obstacle_speed_threshold: float  # m/s; a faster obstacle counts as touched
    progress_eps: float  # m; f2 needs progress above the best so far by more than this


@dataclasses.dataclass(frozen=True)
class ActionConfig:
    mode: Literal["joint", "cartesian"]
    cartesian_max_speed: float  # m/s, scale of a normalised Cartesian action


@dataclasses.dataclass(frozen=True)
class ObservationConfig:
    relative: bool  # append the tip and each obstacle relative to the cube (m, world frame)
    lanes: bool  # append each reachable lane's clearance (m; see env.layout.lane_clearance)
    lane_clip: tuple[float, float]  # m, the lane clearance saturates at these


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    robot: Literal["jaco", "j2s6s200"]  # an arm of ahrm_stack.robot.ARMS
    table: TableConfig
    arm: ArmConfig
    pusher: PusherConfig
    cube: CubeConfig
    obstacles: ObstacleConfig
    layout: LayoutConfig
    regions: RegionConfig
    episode: EpisodeConfig
    rewards: RewardConfig
    action: ActionConfig
    observation: ObservationConfig

    @property
    def substeps(self) -> int:
        return int(round(self.episode.control_period / self.episode.physics_timestep))

    @property
    def max_steps(self) -> int:
        return int(round(self.episode.duration / self.episode.control_period))


@dataclasses.dataclass(frozen=True)
class ScriptedConfig:
    """The mink differential-IK waypoint controller (classical baseline). Positions: pusher tip."""

    travel_speed: float  # m/s, top tip speed toward a waypoint (lift, travel, descend)
    push_speed: float  # m/s, tip speed along the push direction
    position_gain: float  # 1/s, proportional gain toward a waypoint / onto the push line
    tilt_gain: float  # 1/s, rate of turning the pusher axis toward straight down
    tilt_speed: float  # rad/s, top rate of that turn
    tilt_tolerance: float  # rad, largest pusher tilt from vertical at which the push may start
    orientation_cost: float  # weight of the pusher-pointing-down task (position task weight 1)
    roll_cost: float  # weight of holding the pusher's spin about its own axis at zero
    damping: float  # Levenberg-Marquardt damping of the IK
    clearance: float  # m, tip height of the travel plane above the obstacles' tops
    standoff: float  # m, gap between the pusher and the cube face where the descent ends
    push_height: float  # m, tip height above the table while pushing
    push_overshoot: float  # m, the push stops this far past the table edge
    steer_gain: float  # 1/m, tan of the push direction's lean toward the lane line per metre of
    # the cube's offset from that line
    max_heading: float  # rad, largest lean of the push direction from the lane
    realign_distance: float  # m, the push stops advancing while the tip is this far off its line
    waypoint_tolerance: float  # m
    collision_margin: float  # m, distance the IK keeps between the arm/pusher and the obstacles
    collision_detection: float  # m, distance at which that constraint becomes active
    collision_gain: float  # fraction of the gap beyond the margin one control step may close
    solver: str  # QP solver name for mink (qpsolvers), e.g. daqp


@dataclasses.dataclass(frozen=True)
class SelfCollisionPairs:
    """Per arm (``task.robot``), the pairs of arm parts that get a self-collision distance row.
    Parts are named ``base``, ``link1`` ... ``link6`` (the body each joint turns) and ``pusher``."""

    jaco: tuple[tuple[str, str], ...]
    j2s6s200: tuple[tuple[str, str], ...]


SELF_COLLISION_PART = re.compile(r"^(base|pusher|link[1-9])$")


@dataclasses.dataclass(frozen=True)
class SafetyConfig:
    """The QP action filter (spec §5). Joint limits and velocity limits come from the robot
    description; only margins and the extra limits the description lacks live here."""

    enabled: bool  # false only for an explicit ablation (logged as such)
    solver: Literal["osqp", "daqp"]
    position_margin: float  # rad, kept from each finite joint limit
    velocity_margin: float  # fraction of each joint's velocity limit left unused: headroom for the
    # velocity controller, whose joints run faster than commanded under gravity (servo error)
    acceleration_limit: tuple[float, ...]  # rad/s^2 per joint, |u - u_prev| <= a_max dt
    braking_horizon: bool  # true: position and Cartesian rows look ahead max(dt, max_i v_i/a_i) s
    # (the time to brake from full speed), which keeps them satisfiable under the acceleration
    # limits; false: one control period dt, the literal one-step rows
    table_rows: bool  # the tip and wrist stay table_margin above the table top
    table_margin: float  # m, the pusher tip stays this far above the table top
    wrist_table_margin: float  # m, the wrist point (the pusher's attachment, inside the wrist
    # ring) stays this far above the table top: the ring's radius plus a clearance
    workspace_rows: bool  # the tip and wrist stay inside the workspace box
    workspace_lower: tuple[float, float, float]  # m, world-frame box the tip and wrist stay in
    workspace_upper: tuple[float, float, float]
    table_distance_rows: bool  # distance rows robot part-table (pusher body, link capsules)
    obstacle_rows: bool  # distance rows robot part-obstacle (off in training, on in deployment)
    obstacle_safe_distance: float  # m, d_safe
    obstacle_activation_distance: float  # m, pairs farther than this add no row
    max_obstacle_rows: int  # the nearest pairs within the activation distance get a row
    self_collision_rows: bool  # distance rows between the arm's own parts (the pairs below), with
    # the obstacle rows' safe distance, activation distance and horizon
    self_collision_pairs: SelfCollisionPairs
    osqp_eps: float  # OSQP absolute and relative tolerance
    osqp_max_iter: int
    cartesian_regularization: float  # lambda of ||u||^2 in cartesian mode, (m/rad)^2
    cartesian_orientation_weight: float  # weight of holding the pusher's axis direction, m^2


@dataclasses.dataclass(frozen=True)
class MechanismConfig:
    """Reward mechanisms of spec §4. Orders list objective names: avoid, manipulate, time."""

    method: Literal["ahrm", "mhrm", "fhrm", "ls"]
    fixed_order: tuple[str, str, str]  # FHRM: one order for every phase
    manual_orders: tuple[tuple[str, str, str], tuple[str, str, str], tuple[str, str, str]]  # MHRM
    initial_orders: tuple[tuple[str, str, str], tuple[str, str, str], tuple[str, str, str]]  # AHRM
    convergence_window: int  # W episodes
    convergence_tolerance: float  # relative to max(1, |mean|)
    constraint_window: int  # episodes averaged for tau
    constraint_min_steps: int  # steps in a phase before the constraint is checked
    constraint_margin: float  # a per-step average below tau - margin ends the episode
    priority_period: int  # P: visiting episodes between priority determinations
    blend_band: float  # delta, m
    blend_slope: float  # alpha, 1/m


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters (spec §6). ``configs/ppo.yaml`` holds the learnability study's choices;
    the paper's Table I values are ``configs/profiles/paper.yaml``."""

    gamma: float
    gae_lambda: float
    frames_per_batch: int
    mini_batch_size: int
    epochs: int
    learning_rate: float
    clip_epsilon: float
    entropy_coeff: float
    critic_coeff: float
    max_grad_norm: float
    hidden_sizes: tuple[int, ...]  # actor and critic
    activation: Literal["tanh", "relu", "elu"]
    init_std: float  # initial standard deviation of the (pre-tanh) Gaussian policy
    std_mode: Literal["learned", "fixed", "scheduled"]  # scheduled: init_std -> final_std
    final_std: float  # std_mode scheduled: the standard deviation reached after std_schedule_frames
    std_schedule_frames: int  # frames over which the std goes (log-linearly) to final_std
    target_kl: float  # stop a batch's epochs once the approximate KL exceeds 1.5x this (0: off)
    normalize_advantage: bool  # scale each mini-batch's advantages to zero mean, unit std
    normalize_observations: bool
    normalizer_clip: float  # normalised observations are clipped to +-this
    update_normalizer: bool  # keep updating its statistics from every batch (false: frozen once set)
    bc_coeff: float  # weight of a behaviour-cloning term toward the demonstrations (0: off)
    bc_coeff_final: float  # the anchor's weight goes linearly from bc_coeff to this ...
    bc_decay_frames: int  # ... over this many frames (0: constant bc_coeff)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    episodes: int  # training stops after this many completed episodes
    seed: int
    runs_dir: str  # run folders are created here (relative to the working directory)
    checkpoint_every: int  # batches between checkpoints
    keep_checkpoints: int  # most recent checkpoints kept on disk
    eval_episodes: int  # deterministic evaluation episodes at the end of training (0: none)
    eval_every: int  # also evaluate (eval_episodes) every this many training episodes (0: never)
    threads: int  # torch intra-op threads
    warm_start: Literal["none", "bc"]  # bc: behaviour cloning from scripted demonstrations first
    demo_episodes: int  # scripted-controller episodes recorded for warm start and the BC anchor
    bc_epochs: int  # passes over the demonstrations for behaviour cloning and the critic refit
    bc_learning_rate: float
    demo_noise: float  # std of noise on the executed demonstration actions (normalised; labels clean)
    num_envs: int  # environments stepped together (in one process, sharing the reward mechanism)
    env_workers: int  # processes the num_envs environments are split over (1: the trainer's own)
    dagger_rounds: int  # after cloning: rounds of (run the clone, label its states with the
    # scripted controller, refit on all data so far); 0: none
    dagger_episodes: int  # episodes per round
    dagger_duration: float  # s, a round's episode is cut after this much simulated time


@dataclasses.dataclass(frozen=True)
class Config:
    task: TaskConfig
    scripted: ScriptedConfig
    safety: SafetyConfig
    mechanism: MechanismConfig
    ppo: PPOConfig
    train: TrainConfig


# ----------------------------------------------------------------------------------------------
# Parsing.
# ----------------------------------------------------------------------------------------------

_DEG_KEYS = {"home_deg": "home", "base_yaw_deg": "base_yaw"}


def _convert(tp: Any, value: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, key)
    if origin is Literal:
        allowed = typing.get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{key}: {value!r} is not allowed; choose one of {list(allowed)}")
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}: {value!r}")
        return tuple(_convert(a, v, f"{key}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is float:
        if isinstance(value, str):  # YAML 1.1 reads "1e-4" as a string
            try:
                value = float(value)
            except ValueError:
                raise ConfigError(f"{key}: expected a number, got {value!r}") from None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{key}: must be finite, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true/false, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {tp!r} at {key}")  # a bug in the schema, not input


def _select_home(data: dict, key: str) -> dict:
    """``data`` (a task section) with ``arm.home_deg`` reduced to the list of ``data['robot']``
    when it is given per robot (a mapping robot name -> degrees)."""
    arm = data.get("arm")
    if not isinstance(arm, dict) or not isinstance(arm.get("home_deg"), dict):
        return data
    robot = data.get("robot")
    choices = typing.get_args(typing.get_type_hints(TaskConfig)["robot"])
    if robot not in choices:
        raise ConfigError(f"{key}.robot: {robot!r} is not allowed; choose one of {list(choices)}")
    where = f"{key}.arm.home_deg"
    unknown = sorted(set(arm["home_deg"]) - set(choices), key=str)
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: no such robot; choose among {list(choices)}")
    if robot in choices and robot not in arm["home_deg"]:
        raise ConfigError(f"{where} has no entry for robot {robot!r} (task.robot); "
                          f"entries: {sorted(arm['home_deg'])}")
    return {**data, "arm": {**arm, "home_deg": arm["home_deg"].get(robot)}}


def _build(cls: type, data: Any, key: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{key or 'config'}: expected a mapping, got {data!r}")
    data = dict(data)
    if cls is TaskConfig:
        data = _select_home(data, key)
    for deg_key, rad_key in _DEG_KEYS.items():
        if deg_key in data:
            raw = data.pop(deg_key)
            if isinstance(raw, (list, tuple)):
                data[rad_key] = [math.radians(_convert(float, v, f"{key}.{deg_key}[{i}]"))
                                 for i, v in enumerate(raw)]
            else:
                data[rad_key] = math.radians(_convert(float, raw, f"{key}.{deg_key}"))
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - fields)
    prefix = f"{key}." if key else ""
    if unknown:
        raise ConfigError(f"unknown config key '{prefix}{unknown[0]}'; allowed keys here: {sorted(fields)}")
    missing = sorted(fields - set(data))
    if missing:
        raise ConfigError(f"missing config key '{prefix}{missing[0]}'")
    values = {name: _convert(hints[name], data[name], f"{prefix}{name}") for name in fields}
    obj = cls(**values)
    _check_ranges(obj, key)
    _check_limits(obj, key)
    return obj


def _positive(obj: Any, key: str, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        for i, v in enumerate(value if isinstance(value, tuple) else (value,)):
            if not v > 0:
                where = f"{key}.{name}" + (f"[{i}]" if isinstance(value, tuple) else "")
                raise ConfigError(f"{where} must be > 0, got {v!r}")


def _check_ranges(obj: Any, key: str) -> None:
    """Value checks that the types alone cannot express."""
    if isinstance(obj, TableConfig):
        _positive(obj, key, "half_extent", "thickness")
    elif isinstance(obj, PusherConfig):
        _positive(obj, key, "radius", "length", "mass")
    elif isinstance(obj, CubeConfig):
        _positive(obj, key, "size", "mass")
    elif isinstance(obj, ObstacleConfig):
        _positive(obj, key, "size", "mass")
    elif isinstance(obj, RegionConfig):
        _positive(obj, key, "target_half_width", "target_height", "obstacle_height", "distance_clip")
        if obj.obstacle_margin < 0:
            raise ConfigError(f"{key}.obstacle_margin must be >= 0, got {obj.obstacle_margin}")
    elif isinstance(obj, EpisodeConfig):
        _positive(obj, key, "duration", "control_period", "physics_timestep")
        ratio = obj.control_period / obj.physics_timestep
        if abs(ratio - round(ratio)) > 1e-9:
            raise ConfigError(f"{key}.control_period ({obj.control_period}) must be a whole multiple "
                              f"of {key}.physics_timestep ({obj.physics_timestep})")
    elif isinstance(obj, LayoutConfig):
        for axis, (lo, hi) in zip("xy", obj.cube_region):
            if not lo <= hi:
                raise ConfigError(f"{key}.cube_region ({axis}): min {lo} must be <= max {hi}")
        lo, hi = obj.radial_range
        if not 0 < lo <= hi:
            raise ConfigError(f"{key}.radial_range must satisfy 0 < min <= max, got {obj.radial_range}")
        _positive(obj, key, "lane_width", "approach_room", "max_tries", "obstacle_draws_per_cube")
        bad = [d for d in obj.lane_directions if d not in ("+x", "-x")]
        if bad or not obj.lane_directions:
            raise ConfigError(f"{key}.lane_directions: {list(obj.lane_directions)} must be a non-empty "
                              "subset of ['+x', '-x']")
        if obj.settle_steps < 0:
            raise ConfigError(f"{key}.settle_steps must be >= 0, got {obj.settle_steps}")
    elif isinstance(obj, RewardConfig):
        _positive(obj, key, "obstacle_speed_threshold", "progress_eps")
    elif isinstance(obj, ActionConfig):
        _positive(obj, key, "cartesian_max_speed")
    elif isinstance(obj, StartIKConfig):
        _positive(obj, key, "tries", "iterations", "damping", "max_step", "position_tolerance",
                  "tilt_tolerance")
    elif isinstance(obj, ObservationConfig):
        if not obj.lane_clip[0] < obj.lane_clip[1]:
            raise ConfigError(f"{key}.lane_clip must satisfy min < max, got {list(obj.lane_clip)}")
    elif isinstance(obj, ArmConfig):
        if obj.joint_jitter < 0:
            raise ConfigError(f"{key}.joint_jitter must be >= 0, got {obj.joint_jitter}")
        for axis, (lo, hi) in zip("xyz", obj.start_region):
            if not lo <= hi:
                raise ConfigError(f"{key}.start_region ({axis}): min {lo} must be <= max {hi}")
    elif isinstance(obj, SafetyConfig):
        _positive(obj, key, "acceleration_limit", "osqp_eps", "osqp_max_iter",
                  "cartesian_regularization")
        for name in ("position_margin", "table_margin", "wrist_table_margin", "obstacle_safe_distance",
                     "cartesian_orientation_weight", "max_obstacle_rows"):
            if getattr(obj, name) < 0:
                raise ConfigError(f"{key}.{name} must be >= 0, got {getattr(obj, name)!r}")
        if not 0 <= obj.velocity_margin < 1:
            raise ConfigError(f"{key}.velocity_margin must be in [0, 1), got {obj.velocity_margin!r}")
        if obj.obstacle_activation_distance <= obj.obstacle_safe_distance:
            raise ConfigError(f"{key}.obstacle_activation_distance ({obj.obstacle_activation_distance}) "
                              f"must exceed {key}.obstacle_safe_distance ({obj.obstacle_safe_distance})")
        for i, (lo, hi) in enumerate(zip(obj.workspace_lower, obj.workspace_upper)):
            if not lo < hi:
                raise ConfigError(f"{key}.workspace_lower[{i}] ({lo}) must be < workspace_upper[{i}] ({hi})")
    elif isinstance(obj, SelfCollisionPairs):
        for robot in (f.name for f in dataclasses.fields(obj)):
            for i, pair in enumerate(getattr(obj, robot)):
                where = f"{key}.{robot}[{i}]"
                for name in pair:
                    if not SELF_COLLISION_PART.match(name):
                        raise ConfigError(f"{where}: {name!r} is not an arm part; use base, link1 ... "
                                          "link9 or pusher")
                if pair[0] == pair[1]:
                    raise ConfigError(f"{where}: a part cannot be paired with itself ({list(pair)})")
    elif isinstance(obj, MechanismConfig):
        orders = [("fixed_order", obj.fixed_order)]
        orders += [(f"manual_orders[{k}]", o) for k, o in enumerate(obj.manual_orders)]
        orders += [(f"initial_orders[{k}]", o) for k, o in enumerate(obj.initial_orders)]
        for name, order in orders:
            if sorted(order) != sorted(OBJECTIVE_NAMES):
                raise ConfigError(f"{key}.{name}: {list(order)} must be a permutation of "
                                  f"{list(OBJECTIVE_NAMES)}")
        _positive(obj, key, "convergence_window", "convergence_tolerance", "constraint_window",
                  "priority_period", "blend_band", "blend_slope")
        if obj.constraint_min_steps < 1 or obj.constraint_margin < 0:
            raise ConfigError(f"{key}.constraint_min_steps must be >= 1 and constraint_margin >= 0")
    elif isinstance(obj, PPOConfig):
        _positive(obj, key, "frames_per_batch", "mini_batch_size", "epochs", "learning_rate",
                  "clip_epsilon", "max_grad_norm", "hidden_sizes", "init_std", "normalizer_clip",
                  "final_std", "std_schedule_frames")
        if obj.target_kl < 0:
            raise ConfigError(f"{key}.target_kl must be >= 0 (0: off), got {obj.target_kl}")
        for name in ("gamma", "gae_lambda"):
            if not 0 <= getattr(obj, name) <= 1:
                raise ConfigError(f"{key}.{name} must be in [0, 1], got {getattr(obj, name)}")
        if obj.bc_coeff_final < 0 or obj.bc_decay_frames < 0:
            raise ConfigError(f"{key}.bc_coeff_final and {key}.bc_decay_frames must be >= 0")
        if obj.entropy_coeff < 0 or obj.critic_coeff < 0 or obj.bc_coeff < 0:
            raise ConfigError(f"{key}.entropy_coeff, critic_coeff and bc_coeff must be >= 0")
        if obj.frames_per_batch % obj.mini_batch_size:
            raise ConfigError(f"{key}.frames_per_batch ({obj.frames_per_batch}) must be a multiple of "
                              f"{key}.mini_batch_size ({obj.mini_batch_size})")
    elif isinstance(obj, TrainConfig):
        _positive(obj, key, "episodes", "checkpoint_every", "keep_checkpoints", "threads")
        if obj.eval_episodes < 0 or obj.eval_every < 0:
            raise ConfigError(f"{key}.eval_episodes and {key}.eval_every must be >= 0, got "
                              f"{obj.eval_episodes} and {obj.eval_every}")
        _positive(obj, key, "demo_episodes", "bc_epochs", "bc_learning_rate", "num_envs", "env_workers")
        if obj.num_envs % obj.env_workers:
            raise ConfigError(f"{key}.num_envs ({obj.num_envs}) must be a multiple of "
                              f"{key}.env_workers ({obj.env_workers})")
        if obj.demo_noise < 0:
            raise ConfigError(f"{key}.demo_noise must be >= 0, got {obj.demo_noise}")
        if obj.dagger_rounds < 0:
            raise ConfigError(f"{key}.dagger_rounds must be >= 0, got {obj.dagger_rounds}")
        _positive(obj, key, "dagger_episodes", "dagger_duration")
    elif isinstance(obj, ScriptedConfig):
        _positive(obj, key, "travel_speed", "push_speed", "position_gain", "tilt_gain", "tilt_speed",
                  "tilt_tolerance", "orientation_cost", "damping", "clearance", "push_height",
                  "waypoint_tolerance", "collision_detection", "realign_distance")
        for name in ("standoff", "push_overshoot", "steer_gain", "max_heading", "collision_margin",
                     "roll_cost"):
            if getattr(obj, name) < 0:
                raise ConfigError(f"{key}.{name} must be >= 0, got {getattr(obj, name)!r}")
        if not 0 < obj.collision_gain <= 1:
            raise ConfigError(f"{key}.collision_gain must be in (0, 1], got {obj.collision_gain!r}")
        if obj.collision_detection <= obj.collision_margin:
            raise ConfigError(f"{key}.collision_detection ({obj.collision_detection}) must exceed "
                              f"{key}.collision_margin ({obj.collision_margin})")
        import qpsolvers  # the solver list is only known at run time
        if obj.solver not in qpsolvers.available_solvers:
            raise ConfigError(f"{key}.solver: {obj.solver!r} is not installed; choose one of "
                              f"{sorted(qpsolvers.available_solvers)}")


# Upper bounds: values past these would run (nearly) forever or exhaust the machine. They are
# limits of this program, not tunables, and sit far above any configuration in use.
LIMITS = {
    "substeps": 1000,  # physics steps per control step (control_period / physics_timestep)
    "control_period": 1.0,  # s
    "episode_steps": 100_000,  # control steps per episode (duration / control_period)
    "episodes": 1_000_000,  # training episodes
    "demo_episodes": 10_000,
    "demo_steps": 5_000_000,  # demo_episodes x episode steps: the demonstrations held in memory
    "bc_epochs": 100_000,
    "eval_episodes": 100_000,
    "num_envs": 256,
    "threads": 256,  # torch threads; training also stays within the machine's CPU count
    "keep_checkpoints": 1000,
    "seed": 2**31 - 1,  # numpy seeds are < 2**32; environment i adds i x 10_000
    "frames_per_batch": 1_000_000,  # the replay buffer holds one batch
    "epochs": 1000,
    "hidden_layers": 16,
    "hidden_width": 8192,
    "max_tries": 1_000_000,  # layout rejection sampling
    "settle_steps": 100_000,  # physics steps at reset
    "osqp_max_iter": 1_000_000,
    "max_obstacle_rows": 100,
    "window": 1_000_000,  # mechanism windows and periods, episodes or steps
}


def _at_most(obj: Any, key: str, name: str, limit: float, what: str = "") -> None:
    value = getattr(obj, name)
    if value > limit:
        raise ConfigError(f"{key}.{name} must be <= {limit}{what}, got {value!r}")


def _check_limits(obj: Any, key: str) -> None:
    """Upper bounds (:data:`LIMITS`) and the checks that span several keys or sections."""
    if isinstance(obj, EpisodeConfig):
        _at_most(obj, key, "control_period", LIMITS["control_period"], " s")
        if obj.physics_timestep > obj.control_period:
            raise ConfigError(f"{key}.physics_timestep ({obj.physics_timestep} s) must be <= "
                              f"{key}.control_period ({obj.control_period} s): substeps is an integer >= 1")
        if obj.control_period / obj.physics_timestep > LIMITS["substeps"] + 0.5:
            raise ConfigError(f"{key}.physics_timestep ({obj.physics_timestep} s) gives "
                              f"{obj.control_period / obj.physics_timestep:.4g} physics steps per "
                              f"control period; at most {LIMITS['substeps']} (>= "
                              f"{obj.control_period / LIMITS['substeps']:g} s)")
        if obj.duration < obj.control_period:
            raise ConfigError(f"{key}.duration ({obj.duration} s) must be >= {key}.control_period "
                              f"({obj.control_period} s): an episode has at least one step")
        if obj.duration / obj.control_period > LIMITS["episode_steps"] + 0.5:
            raise ConfigError(f"{key}.duration ({obj.duration} s) gives more than "
                              f"{LIMITS['episode_steps']} control steps per episode")
    elif isinstance(obj, LayoutConfig):
        _at_most(obj, key, "max_tries", LIMITS["max_tries"])
        _at_most(obj, key, "settle_steps", LIMITS["settle_steps"])
    elif isinstance(obj, TaskConfig):
        import numpy as np

        from ahrm_stack.env.layout import Layout, LayoutError, validate_layout  # imports this module

        layout = Layout(np.asarray(obj.cube.position, float),
                        np.asarray(obj.obstacles.fixed_layout, float).reshape(-1, 2))
        if obj.layout.mode == "fixed":  # random mode never uses the fixed layout
            try:
                validate_layout(layout, obj.table, obj.cube, obj.obstacles, obj.layout)
            except LayoutError as error:
                raise ConfigError(f"{key}.obstacles.fixed_layout / {key}.cube.position: {error}") from None
        if obj.layout.mode == "random":  # the nearest allowed obstacle centre must fit on the table
            room = np.asarray(obj.table.half_extent) - np.asarray(obj.obstacles.size[:2]) / 2
            corners = np.array([[sx * room[0], sy * room[1]] for sx in (-1, 1) for sy in (-1, 1)])
            middle = np.mean(np.asarray(obj.layout.cube_region, float), axis=1)  # the region's centre
            reach = float(np.max(np.linalg.norm(corners - middle, axis=1)))
            if obj.layout.radial_range[0] > reach:
                raise ConfigError(f"{key}.layout.radial_range {list(obj.layout.radial_range)}: no "
                                  f"obstacle that far from the cube fits on the table (at most "
                                  f"{reach:.3f} m)")
    elif isinstance(obj, SafetyConfig):
        _at_most(obj, key, "osqp_max_iter", LIMITS["osqp_max_iter"])
        _at_most(obj, key, "max_obstacle_rows", LIMITS["max_obstacle_rows"])
    elif isinstance(obj, MechanismConfig):
        for name in ("convergence_window", "constraint_window", "constraint_min_steps",
                     "priority_period"):
            _at_most(obj, key, name, LIMITS["window"])
    elif isinstance(obj, PPOConfig):
        _at_most(obj, key, "frames_per_batch", LIMITS["frames_per_batch"])
        _at_most(obj, key, "epochs", LIMITS["epochs"])
        if not 1 <= len(obj.hidden_sizes) <= LIMITS["hidden_layers"]:
            raise ConfigError(f"{key}.hidden_sizes must list 1 to {LIMITS['hidden_layers']} layer "
                              f"widths, got {list(obj.hidden_sizes)}")
        if max(obj.hidden_sizes) > LIMITS["hidden_width"]:
            raise ConfigError(f"{key}.hidden_sizes: layer widths must be <= {LIMITS['hidden_width']}, "
                              f"got {list(obj.hidden_sizes)}")
    elif isinstance(obj, TrainConfig):
        for name in ("episodes", "demo_episodes", "bc_epochs", "eval_episodes", "num_envs",
                     "keep_checkpoints", "seed"):
            _at_most(obj, key, name, LIMITS[name])
        if obj.seed < 0:
            raise ConfigError(f"{key}.seed must be >= 0, got {obj.seed}")
        _at_most(obj, key, "threads", LIMITS["threads"], " (train.py also refuses more than this "
                 "machine's CPU count)")
        if not obj.runs_dir.strip():
            raise ConfigError(f"{key}.runs_dir must name a folder, got {obj.runs_dir!r}")
    elif isinstance(obj, Config):
        ppo, train, episode = obj.ppo, obj.train, obj.task.episode
        if ppo.frames_per_batch % train.num_envs:
            raise ConfigError(f"ppo.frames_per_batch ({ppo.frames_per_batch}) must be a multiple of "
                              f"train.num_envs ({train.num_envs})")
        steps = round(episode.duration / episode.control_period)
        uses_demos = train.warm_start == "bc" or ppo.bc_coeff > 0
        if uses_demos and train.demo_episodes * steps > LIMITS["demo_steps"]:
            raise ConfigError(f"train.demo_episodes ({train.demo_episodes}) x {steps} steps per "
                              f"episode (task.episode.duration) exceeds {LIMITS['demo_steps']} "
                              "demonstration steps held in memory")
        if len(obj.safety.acceleration_limit) != len(obj.task.arm.home):
            raise ConfigError(f"safety.acceleration_limit has {len(obj.safety.acceleration_limit)} "
                              f"values, task.arm.home_deg {len(obj.task.arm.home)}: both give one "
                              f"value per joint of task.robot ({obj.task.robot})")
        if obj.task.regions.distance_clip < obj.mechanism.blend_band:
            raise ConfigError(f"task.regions.distance_clip ({obj.task.regions.distance_clip} m) must "
                              f"be >= mechanism.blend_band ({obj.mechanism.blend_band} m)")


# ----------------------------------------------------------------------------------------------
# Loading and overrides.
# ----------------------------------------------------------------------------------------------

SECTIONS = {"task": "task.yaml", "scripted": "scripted.yaml", "safety": "safety.yaml",
            "mechanism": "mechanism.yaml", "ppo": "ppo.yaml", "train": "train.yaml"}


def _read_yaml(path: Path) -> dict:
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def apply_override(data: dict, override: str) -> None:
    """Apply one ``dotted.key=value`` override to a nested dict, in place."""
    if "=" not in override:
        raise ConfigError(f"override {override!r} must look like key.sub=value")
    dotted, raw = override.split("=", 1)
    parts = dotted.strip().split(".")
    node = data
    for i, part in enumerate(parts):
        if not isinstance(node, dict):
            raise ConfigError(f"config key '{'.'.join(parts[:i])}' in override {override!r} is a value, "
                              "not a section with keys")
        if part not in node:
            raise ConfigError(f"unknown config key '{'.'.join(parts[: i + 1])}' in override {override!r}; "
                              f"allowed keys here: {sorted(node)}")
        if i < len(parts) - 1:
            node = node[part]
    try:
        node[parts[-1]] = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ConfigError(f"override {override!r}: value is not valid YAML") from None


PROFILE_DIR = "profiles"  # under the config folder: named sets of overrides


def _flatten(mapping: dict, prefix: str = "") -> list[str]:
    """``{"ppo": {"epochs": 3}}`` -> ``["ppo.epochs=3"]`` (values written back as YAML)."""
    items = []
    for key, value in mapping.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            items += _flatten(value, f"{dotted}.")
        else:
            items.append(f"{dotted}={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}")
    return items


def profile_overrides(name: str, config_dir: Path | str = CONFIG_DIR) -> list[str]:
    """The overrides of profile ``name`` (``configs/profiles/<name>.yaml``), as ``key=value``."""
    folder = Path(config_dir) / PROFILE_DIR
    path = folder / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []
        raise ConfigError(f"profile={name}: no file {path}; known profiles: {known}")
    return _flatten(_read_yaml(path))


def apply_overrides(data: dict, overrides: Sequence[str], config_dir: Path | str = CONFIG_DIR) -> None:
    """Apply ``key=value`` overrides in order; ``profile=NAME`` applies that profile's overrides at
    its place in the list (so later overrides win over it)."""
    for override in overrides:
        if override.strip().startswith("profile="):
            for item in profile_overrides(override.split("=", 1)[1].strip(), config_dir):
                apply_override(data, item)
        else:
            apply_override(data, override)


def load_raw(config_dir: Path | str = CONFIG_DIR) -> dict:
    config_dir = Path(config_dir)
    return {section: _read_yaml(config_dir / name) for section, name in SECTIONS.items()}


def load_config(overrides: Sequence[str] = (), config_dir: Path | str = CONFIG_DIR) -> Config:
    """Read ``configs/*.yaml``, apply ``overrides`` (``profile=NAME`` among them) and validate."""
    data = load_raw(config_dir)
    apply_overrides(data, overrides, config_dir)
    return config_from_dict(data)


# Keys added after runs were recorded: a run's config.yaml that lacks them takes them from the
# repository's configs (so the committed run folders and older checkpoints still load).
BACKFILLED = {"safety": ("self_collision_rows", "self_collision_pairs"), "train": ("env_workers",)}


def _legacy_fill(data: dict) -> dict:
    """A run folder's config.yaml written before the task distribution (2026-12-01) lacks its
    keys: fill them so that the run keeps its old behaviour — the home start, the cube at
    ``cube.position`` ± ``cube.jitter`` in random mode, no DAgger, a constant BC anchor."""
    def section(*path):
        node = data
        for key in path:
            node = node.get(key) if isinstance(node, dict) else None
        return node if isinstance(node, dict) else None

    arm, layout, cube = section("task", "arm"), section("task", "layout"), section("task", "cube")
    train, ppo = section("train"), section("ppo")
    observation = section("task", "observation")
    if not any(s is not None and any(k not in s for k in keys) for s, keys in (
            (arm, ("start", "start_ik")), (layout, ("cube_region", "obstacle_draws_per_cube")),
            (train, ("dagger_rounds",)), (ppo, ("bc_coeff_final",)), (section("task"), ("observation",)),
            (observation, ("lane_clip",)))):
        return data
    data = copy.deepcopy(data)
    defaults = {name: _read_yaml(CONFIG_DIR / file) for name, file in SECTIONS.items()}
    if arm is not None and "start" not in arm:
        data["task"]["arm"].setdefault("start", "home")
        data["task"]["arm"].setdefault("start_region", defaults["task"]["arm"]["start_region"])
    if arm is not None:
        data["task"]["arm"].setdefault("start_ik", defaults["task"]["arm"]["start_ik"])
    if layout is not None:
        data["task"]["layout"].setdefault("obstacle_draws_per_cube",
                                          defaults["task"]["layout"]["obstacle_draws_per_cube"])
    if layout is not None and "cube_region" not in layout and cube is not None:
        try:
            (x, y), jitter = cube["position"], float(cube["jitter"])
            data["task"]["layout"]["cube_region"] = [[x - jitter, x + jitter], [y - jitter, y + jitter]]
        except (KeyError, TypeError, ValueError):
            pass  # the schema check names what is wrong
    if train is not None:
        for key in ("dagger_rounds", "dagger_episodes", "dagger_duration"):
            data["train"].setdefault(key, 0 if key == "dagger_rounds" else defaults["train"][key])
    if isinstance(data.get("task"), dict) and "observation" not in data["task"]:
        data["task"]["observation"] = {"relative": False, "lanes": False}
    if isinstance(data.get("task"), dict) and isinstance(data["task"].get("observation"), dict):
        data["task"]["observation"].setdefault("lane_clip", defaults["task"]["observation"]["lane_clip"])
    if ppo is not None and "bc_coeff_final" not in ppo and "bc_coeff" in ppo:
        data["ppo"].setdefault("bc_coeff_final", ppo["bc_coeff"])
        data["ppo"].setdefault("bc_decay_frames", 0)
    return data


def config_from_dict(data: dict, runnable: bool = True) -> Config:
    if isinstance(data, dict):
        data = _legacy_fill(data)
    if isinstance(data, dict) and any(isinstance(data.get(section), dict) and
                                      any(k not in data[section] for k in keys)
                                      for section, keys in BACKFILLED.items()):
        data = dict(data)
        for section, keys in BACKFILLED.items():
            if isinstance(data.get(section), dict):
                defaults = _read_yaml(CONFIG_DIR / SECTIONS[section])
                data[section] = {**{k: defaults[k] for k in keys}, **data[section]}
    config = _build(Config, data, "")
    if runnable and config.task.action.mode == "cartesian" and not config.safety.enabled:
        # a rule for running the task, not for reading a run's file: deploy reads a checkpoint's
        # config (and replaces its safety settings with its own) with runnable=False
        raise ConfigError("safety.enabled: false needs task.action.mode: joint (cartesian "
                          "actions are turned into joint velocities by the safety filter)")
    return config


# ----------------------------------------------------------------------------------------------
# Evaluation videos and the four-method experiment: their own files, outside a run's config.yaml
# (so run folders written before these existed still load).
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class VideoConfig:
    """Offscreen evaluation videos (``configs/video.yaml``)."""

    camera: str  # a named camera of the arena
    width: int  # px, even
    height: int  # px, even
    frame_every: int  # control steps per frame
    shadows: bool  # shadows cost most of the rendering time in software OpenGL
    quality: int  # imageio-ffmpeg quality 0..10
    gl_backends: tuple[str, ...]  # MUJOCO_GL values tried in order when MUJOCO_GL is unset


@dataclasses.dataclass(frozen=True)
class PaperRow:
    """One method's row of the paper's Table II."""

    successes: int
    episodes: int
    touched: int  # episodes touching an obstacle
    time: tuple[float, float]  # mean, std time to success, s
    travel: tuple[float, float]  # mean, std cube travel, m


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """The four-method grid, its budgets and its report (``configs/experiment.yaml``)."""

    methods: tuple[str, ...]  # mechanism.method values
    seeds: int  # training seeds 0 .. seeds-1
    episodes: int  # training episodes per run
    eval_episodes: int  # deterministic evaluation episodes per run
    scripted_episodes: int  # evaluation episodes of the scripted controller (0: no row)
    eval_layout: str  # a name in configs/layouts.yaml
    video_episode: int  # evaluation episode rendered per method (-1: no videos)
    cpus_per_run: float  # Ray num_cpus of one run
    ray_temp_dir: str
    ray_object_store_mb: int
    success_threshold: float  # fraction of successes for "episodes to reach it"
    success_window: int  # trailing training episodes of that fraction
    curve_window: int  # trailing window of the learning curves, episodes
    suite: bool  # also evaluate every run (and its clone, and the scripted controller) on the suite
    bootstrap_samples: int  # resamples of the bootstrap intervals on differences between methods
    paper_table2: dict[str, PaperRow]


def _check_extra(obj: Any, where: str) -> None:
    if isinstance(obj, VideoConfig):
        _positive(obj, where, "width", "height", "frame_every")
        for name in ("width", "height"):
            if getattr(obj, name) % 2:
                raise ConfigError(f"{where}.{name} must be even (H.264), got {getattr(obj, name)}")
        if not 0 <= obj.quality <= 10:
            raise ConfigError(f"{where}.quality must be in 0..10, got {obj.quality}")
        bad = [b for b in obj.gl_backends if b not in ("egl", "osmesa", "glfw")]
        if bad or not obj.gl_backends:
            raise ConfigError(f"{where}.gl_backends: {list(obj.gl_backends)} must be a non-empty list "
                              "of egl, osmesa, glfw")
    elif isinstance(obj, ExperimentConfig):
        allowed = typing.get_args(typing.get_type_hints(MechanismConfig)["method"])
        bad = [m for m in obj.methods if m not in allowed]
        if bad or not obj.methods or len(set(obj.methods)) != len(obj.methods):
            raise ConfigError(f"{where}.methods: {list(obj.methods)} must be distinct values of "
                              f"{list(allowed)}")
        _positive(obj, where, "seeds", "episodes", "eval_episodes", "cpus_per_run",
                  "ray_object_store_mb", "success_window", "curve_window")
        if obj.scripted_episodes < 0 or obj.video_episode < -1:
            raise ConfigError(f"{where}.scripted_episodes must be >= 0 and video_episode >= -1")
        if obj.video_episode >= obj.eval_episodes:
            raise ConfigError(f"{where}.video_episode ({obj.video_episode}) must be < eval_episodes "
                              f"({obj.eval_episodes})")
        if not 0 < obj.success_threshold <= 1:
            raise ConfigError(f"{where}.success_threshold must be in (0, 1], got {obj.success_threshold}")


def _convert_extra(tp: Any, value: Any, key: str) -> Any:
    if typing.get_origin(tp) is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping, got {value!r}")
        item = typing.get_args(tp)[1]
        return {str(k): _build(item, v, f"{key}.{k}") for k, v in value.items()}
    return _convert(tp, value, key)


def load_extra(cls: type, name: str, overrides: Sequence[str] = (),
               config_dir: Path | str = CONFIG_DIR) -> Any:
    """Load ``configs/<name>.yaml`` into ``cls`` (VideoConfig, ExperimentConfig) with ``key=value``
    overrides (keys relative to the file), validated."""
    path = Path(config_dir) / f"{name}.yaml"
    data = _read_yaml(path)
    for override in overrides:
        apply_override(data, override)
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(f"{path}: unknown key '{name}.{unknown[0]}'; allowed keys: {sorted(fields)}")
    missing = sorted(fields - set(data))
    if missing:
        raise ConfigError(f"{path}: missing key '{name}.{missing[0]}'")
    obj = cls(**{k: _convert_extra(hints[k], data[k], f"{name}.{k}") for k in fields})
    _check_extra(obj, name)
    return obj


# ----------------------------------------------------------------------------------------------
# Arms built from a URDF: ``configs/robots/<name>.yaml``.
# ----------------------------------------------------------------------------------------------

ROBOTS_DIR = CONFIG_DIR / "robots"


@dataclasses.dataclass(frozen=True)
class UrdfArmConfig:
    """How to build a simulated arm from a URDF of the ``example-robot-data`` package. Joint
    limits, velocity limits, efforts, inertias and meshes come from the URDF; this file holds only
    the simulation parameters a URDF does not carry, and which links to use."""

    urdf: str  # path under example-robot-data's share folder, e.g. robots/.../kinova.urdf
    root_link: str  # the link placed at the arm's base frame
    flange_link: str  # the last link kept: the hand mounts here and the pusher replaces it
    end_effector_link: str  # a link below the flange: the pusher points from the flange toward it
    hand_meshes: tuple[str, ...]  # mesh file names of the hand on the flange link (not built)
    velocity_gain: float  # kv of the velocity actuators, N m s/rad
    min_velocity_margin: float  # lower bound on safety.velocity_margin for this arm (fraction of
    # each velocity limit): the filter keeps max(safety.velocity_margin, this) as servo headroom
    joint_damping: float  # N m s/rad, every actuated joint
    armature: tuple[float, ...]  # kg m^2, per actuated joint (rotor inertia)
    frictionloss: tuple[float, ...]  # N m, per actuated joint


def _check_urdf_arm(obj: UrdfArmConfig, key: str) -> None:
    _positive(obj, key, "velocity_gain")
    if not 0 <= obj.min_velocity_margin < 1:
        raise ConfigError(f"{key}.min_velocity_margin must be in [0, 1), got {obj.min_velocity_margin!r}")
    for name in ("joint_damping", "armature", "frictionloss"):
        value = getattr(obj, name)
        for i, v in enumerate(value if isinstance(value, tuple) else (value,)):
            if v < 0:
                raise ConfigError(f"{key}.{name} must be >= 0, got {v!r}")
    if len(obj.armature) != len(obj.frictionloss):
        raise ConfigError(f"{key}: armature ({len(obj.armature)} values) and frictionloss "
                          f"({len(obj.frictionloss)} values) must both give one value per joint")


def load_robot_config(name: str, robots_dir: Path | str = ROBOTS_DIR) -> UrdfArmConfig:
    """The validated ``<robots_dir>/<name>.yaml``; keys are named as ``robots/<name>.<key>``."""
    data = _read_yaml(Path(robots_dir) / f"{name}.yaml")
    config = _build(UrdfArmConfig, data, f"robots/{name}")
    _check_urdf_arm(config, f"robots/{name}")
    return config
