"""Typed, validated configuration read from the YAML files in ``configs/``.

Every tunable number of the project lives in ``configs/*.yaml``; this module describes those files
as frozen dataclasses (:class:`ahrm_stack.schema.Section`) whose fields carry their rules, and turns
the files into them once, at start-up, with pydantic (``ahrm_stack/schema.py``). Anything it does not
recognise is refused with one line that names the dotted key, the rule or the allowed keys/values,
and the file (or "override"), e.g. ``ppo.learning_rate must be > 0, got -1.0 (override)``.

Overrides use dotted keys, e.g. ``task.layout.mode=random`` or ``task.episode.duration=30``; values
are parsed as YAML scalars/lists. ``config.to_dict()`` is the YAML-shaped mapping a run folder's
``config.yaml`` stores; :func:`config_from_dict` reads it back into an equal object.

To add a key: the field in its section below, with its rules and markers and a comment with units,
and its line in the section's YAML file; nothing else. E.g.::

    collect_workers: Annotated[PosInt, le(LIMITS["num_envs"]), legacy(1)]  # processes
    table_margin: Annotated[NonNeg, stricter("higher")]  # m (a key of the safety section)

The markers (``ahrm_stack/schema.py``) hold the per-key rules that are not validation:

* ``legacy(value)`` (or ``legacy_rule(f)``): the value a run folder written before the key existed
  behaved as, a literal (so an old run does not change when a default in ``configs/`` does). A
  run's ``config.yaml`` that lacks the key gets it (:func:`fill_missing`, one generic filler), so
  old runs and checkpoints load, resume and take overrides of the new key. A key without the
  marker is required: an old file without it is refused, naming the key.
* ``stricter(direction)``, required on every key of :class:`SafetyConfig` (a test fails without
  it): ``on``, ``higher``, ``lower`` or ``none`` (no order). Deploy's
  :func:`~ahrm_stack.deploy.merge_safety` reads it: a checkpoint's safety value is used where it
  is stricter than deploy's, ignored (with a note) where it is weaker.

A run folder's ``config.yaml`` is ``{schema_version: SCHEMA_VERSION, **config.to_dict()}``
(:func:`ahrm_stack.run_config.run_config_text`); every reader goes through
:func:`ahrm_stack.run_config.load_run_config`. Renaming or removing a key raises
:data:`SCHEMA_VERSION` with a conversion step in :func:`fill_missing`, and
``python -m ahrm_stack.run_config docs`` rewrites the committed run folders. Rules over several
keys go in the section's ``check``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Sequence

import yaml
from pydantic import AfterValidator, PlainValidator
from pydantic_core import PydanticCustomError

from ahrm_stack.env.layout_rules import Layout, LayoutError, validate_layout
from ahrm_stack.env.realism import RealismConfig, resolve_realism
from ahrm_stack.names import OBJECTIVE_NAMES
from ahrm_stack.schema import _float  # the Float rule, for values inside a custom validator
from ahrm_stack.schema import (MISSING, Bool, ConfigError, Float, FrozenDict, Int, Section, Source, Str, apply_override,
                               count, derived, fail, fill_legacy, ge, gt, le, legacy, legacy_rule, load_file,
                               override_keys, read_yaml, show_path, source_note, stricter, validate, within)


CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
_read_yaml = read_yaml  # the earlier name, still imported by a few modules

# Upper bounds: values past these would run (nearly) forever or exhaust the machine. They are
# limits of this program, not tunables, and sit far above any configuration in use. The fields
# below name them in their rules (``le(LIMITS[...])``).
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
    "noslip_iterations": 1000,  # MuJoCo's noslip passes per physics step
    "osqp_max_iter": 1_000_000,
    "max_obstacle_rows": 100,
    "window": 1_000_000,  # mechanism windows and periods, episodes or steps
}

# Shorthands for the field rules.
Pos = Annotated[Float, gt(0)]  # a number > 0
NonNeg = Annotated[Float, ge(0)]  # a number >= 0
PosInt = Annotated[Int, gt(0)]
NonNegInt = Annotated[Int, ge(0)]
Pair = tuple[Float, Float]
Vec3 = tuple[Float, Float, Float]
Robot = Literal["jaco", "j2s6s200"]  # an arm of ahrm_stack.robot.ARMS
ROBOTS: tuple[str, ...] = typing.get_args(Robot)
Method = Literal["ahrm", "mhrm", "fhrm", "ls"]


def _at(where: str, check: typing.Callable[[Any], Any], value: Any) -> Any:
    """``check(value)``, its error moved below ``where`` (e.g. ``.jaco[2]``)."""
    try:
        return check(value)
    except PydanticCustomError as error:
        fail(f"{where}{error.context['text']}")


def _degrees(value: Any, where: str = "") -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)):
        fail(f"{where}: expected a list, got {value!r}")
    return tuple(_at(f"{where}[{i}]", _float, v) for i, v in enumerate(value))


def _home_deg(value: Any) -> tuple[float, ...] | dict[str, tuple[float, ...]]:
    """One list of degrees (for whichever robot runs) or a mapping robot name -> degrees."""
    if isinstance(value, dict):
        unknown = sorted((k for k in value if k not in ROBOTS), key=str)
        if unknown:
            fail(f".{unknown[0]}: no such robot; choose among {list(ROBOTS)}")
        return FrozenDict({name: _degrees(angles, f".{name}") for name, angles in value.items()})
    return _degrees(value)


def _order(value: tuple[str, str, str]) -> tuple[str, str, str]:
    if sorted(value) != sorted(OBJECTIVE_NAMES):
        fail(f": {list(value)} must be a permutation of {list(OBJECTIVE_NAMES)}")
    return value


def _even(value: int) -> int:
    if value % 2:
        fail(f" must be even (H.264), got {value}")
    return value


def _jitter_square(layout: typing.Mapping[str, Any], root: typing.Mapping[str, Any]) -> Any:
    """Legacy ``task.layout.cube_region``: ``task.cube.position`` +- ``task.cube.jitter`` (where random
    mode drew the cube before the key existed); MISSING when those are malformed (the schema names
    them)."""
    try:
        cube = root["task"]["cube"]
        (x, y), jitter = cube["position"], float(cube["jitter"])
        return [[x - jitter, x + jitter], [y - jitter, y + jitter]]
    except (KeyError, TypeError, ValueError):
        return MISSING


def _bc_coeff(ppo: typing.Mapping[str, Any], root: typing.Mapping[str, Any]) -> Any:
    """Legacy ``ppo.bc_coeff_final``: ``ppo.bc_coeff`` (a constant anchor before the schedule)."""
    return ppo.get("bc_coeff", MISSING)


HomeDeg = Annotated[typing.Union[tuple[float, ...], dict[str, tuple[float, ...]]], PlainValidator(_home_deg)]
Order = Annotated[tuple[Str, Str, Str], AfterValidator(_order)]  # objective names, first = highest
Frozen = dataclasses.dataclass(frozen=True)


# ----------------------------------------------------------------------------------------------
# Schema.  Field comments state units.  Defaults are NOT given here: every value comes from YAML
# (fields marked derived() are computed from others and never read or written).
# ----------------------------------------------------------------------------------------------


@Frozen
class TableConfig(Section):
    half_extent: tuple[Pos, Pos]  # (x, y) half-size of the table top, m
    height: Float  # z of the table top surface, m
    thickness: Pos  # m


@Frozen
class StartIKConfig(Section):
    """The random start's damped-least-squares IK (``ahrm_stack/env/start_pose.py``)."""

    tries: PosInt  # targets drawn before the home posture is kept
    iterations: PosInt  # IK iterations per target
    damping: Pos  # of the least-squares step, (m or rad)^2
    max_step: Pos  # rad, the largest joint change of one iteration
    position_tolerance: Pos  # m, tip from its target
    tilt_tolerance: Pos  # rad, pusher axis from straight down


@Frozen
class NearCubeStartConfig(Section):
    """Starts near the cube (the easy end of the start curriculum, ``train.start_curriculum``): the
    pusher tip, pointing down, at a uniform bearing around the cube centre."""

    distance: Pair  # (lo, hi) of the tip's horizontal distance from the cube centre, m
    height: Pair  # (lo, hi) of the tip's height above the table top, m
    bearing: Annotated[Literal["any", "behind"], legacy("any")]  # any: uniform | behind: opposite
    # the episode's lane (legacy: before 2026-12-02 every bearing)
    behind_spread_deg: Annotated[NonNeg, legacy(30.0)]  # deg, half-width of the behind bearings

    def check(self, key: str) -> None:
        for name in ("distance", "height"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ConfigError(f"{key}.{name} must satisfy 0 <= min <= max, got {[lo, hi]}")


@Frozen
class ArmConfig(Section):
    base_position: Vec3  # world position of the arm base, m
    base_yaw_deg: Float  # rotation of the base about world z, degrees
    home_deg: HomeDeg  # initial joint angles, degrees: a mapping robot name -> angles (task.robot
    # picks the entry) or one list for the chosen robot
    joint_jitter: NonNeg  # uniform per-joint jitter of the initial posture, rad
    start: Annotated[Literal["home", "random"], legacy("home")]  # home: the jittered home posture;
    # random: the pusher tip placed by IK at a uniform point of ``start_region``, pointing down
    # (legacy: before 2026-12-01 the home start)
    start_region: Annotated[tuple[Pair, Pair, Pair], legacy([[-0.2, 0.2], [0.0, 0.3], [0.56, 0.76]])]
    # random start: (lo, hi) of the tip's world x, y, z, m
    start_ik: Annotated[StartIKConfig, legacy({"tries": 20, "iterations": 60, "damping": 1.0e-3, "max_step": 0.3,
                                               "position_tolerance": 2.0e-3, "tilt_tolerance": 0.02})]
    near_cube: Annotated[NearCubeStartConfig, legacy({"distance": [0.06, 0.12], "height": [0.02, 0.08],
                                                      "bearing": "any", "behind_spread_deg": 30.0})]
    home: tuple[float, ...] = derived()  # rad: home_deg of task.robot (set by TaskConfig)
    base_yaw: float = derived()  # rad: base_yaw_deg

    def derive(self) -> None:
        object.__setattr__(self, "base_yaw", math.radians(self.base_yaw_deg))
        if not isinstance(self.home_deg, dict):
            object.__setattr__(self, "home", tuple(math.radians(d) for d in self.home_deg))

    def check(self, key: str) -> None:
        for axis, (lo, hi) in zip("xyz", self.start_region):
            if not lo <= hi:
                raise ConfigError(f"{key}.start_region ({axis}): min {lo} must be <= max {hi}")


@Frozen
class PusherConfig(Section):
    radius: Pos  # m
    length: Pos  # full length of the cylinder, m
    mass: Pos  # kg


@Frozen
class CubeConfig(Section):
    size: Pos  # edge length, m
    mass: Pos  # kg
    position: Pair  # nominal (x, y) of the cube centre on the table, m
    jitter: Float  # uniform (x, y) jitter of the cube position, m


@Frozen
class ObstacleConfig(Section):
    size: tuple[Pos, Pos, Pos]  # full edge lengths (x, y, z), m
    mass: Pos  # kg
    fixed_layout: tuple[Pair, ...]  # (x, y) centres of the default layout, m;
    # its length is the number of obstacles in every mode


@Frozen
class LayoutConfig(Section):
    mode: Literal["fixed", "random"]
    cube_region: Annotated[tuple[Pair, Pair], legacy_rule(_jitter_square)]  # random mode: the cube
    # centre uniform in x in [lo, hi] and y in [lo, hi], m (fixed mode: cube.position +- cube.jitter;
    # legacy: before 2026-12-01 random mode drew it there too)
    obstacle_draws_per_cube: Annotated[PosInt, legacy(100)]  # random mode: obstacle draws before the
    # cube is drawn again
    radial_range: Pair  # obstacle distance from the cube centre in random mode, m
    min_gap: Float  # smallest allowed gap between two obstacles / obstacle and cube, m
    lane_width: Pos  # width of the free lane the initializer must keep, m
    approach_room: Pos  # free length behind the cube (opposite the lane) for the pusher, m
    lane_directions: Annotated[tuple[Literal["+x", "-x"], ...], count(1)]  # reachable lane directions
    max_tries: Annotated[PosInt, le(LIMITS["max_tries"])]  # rejection-sampling attempts before giving up
    settle_steps: Annotated[NonNegInt, le(LIMITS["settle_steps"])]  # physics steps run at reset so
    # the free bodies come to rest

    def check(self, key: str) -> None:
        for axis, (lo, hi) in zip("xy", self.cube_region):
            if not lo <= hi:
                raise ConfigError(f"{key}.cube_region ({axis}): min {lo} must be <= max {hi}")
        lo, hi = self.radial_range
        if not 0 < lo <= hi:
            raise ConfigError(f"{key}.radial_range must satisfy 0 < min <= max, got {self.radial_range}")


@Frozen
class RegionConfig(Section):
    target_half_width: Pos  # m
    target_height: Pos  # m above the table top
    obstacle_margin: NonNeg  # m
    obstacle_height: Pos  # m above the table top
    distance_clip: Pos  # m; the reported region distances are exact within +-this, saturated beyond


@Frozen
class EpisodeConfig(Section):
    duration: Pos  # s of simulated time
    control_period: Annotated[Pos, le(LIMITS["control_period"], " s")]  # s
    physics_timestep: Pos  # s
    sleep: Annotated[Bool, legacy(False)]  # MuJoCo's body sleeping in the stepped physics (TaskRunner)
    noslip_iterations: Annotated[NonNegInt, le(LIMITS["noslip_iterations"]), legacy(5)]  # MuJoCo's noslip
    # passes per step (legacy: before 2026-12-03 dm_control's composer arena's 5)

    def check(self, key: str) -> None:
        ratio = self.control_period / self.physics_timestep
        if abs(ratio - round(ratio)) > 1e-9:
            raise ConfigError(f"{key}.control_period ({self.control_period}) must be a whole multiple "
                              f"of {key}.physics_timestep ({self.physics_timestep})")
        if self.physics_timestep > self.control_period:
            raise ConfigError(f"{key}.physics_timestep ({self.physics_timestep} s) must be <= "
                              f"{key}.control_period ({self.control_period} s): substeps is an integer >= 1")
        if ratio > LIMITS["substeps"] + 0.5:
            raise ConfigError(f"{key}.physics_timestep ({self.physics_timestep} s) gives {ratio:.4g} "
                              f"physics steps per control period; at most {LIMITS['substeps']} (>= "
                              f"{self.control_period / LIMITS['substeps']:g} s)")
        if self.duration < self.control_period:
            raise ConfigError(f"{key}.duration ({self.duration} s) must be >= {key}.control_period "
                              f"({self.control_period} s): an episode has at least one step")
        if self.duration / self.control_period > LIMITS["episode_steps"] + 0.5:
            raise ConfigError(f"{key}.duration ({self.duration} s) gives more than "
                              f"{LIMITS['episode_steps']} control steps per episode")


@Frozen
class RewardConfig(Section):
    obstacle_speed_threshold: Pos  # m/s; a faster obstacle counts as touched
    progress_eps: Pos  # m; f2 needs progress above the best so far by more than this
    time_reference: Annotated[Literal["previous", "success"], legacy("previous")]  # the episode that
    # sets f3's phase budgets (legacy: before 2026-12-02 the spec's previous episode)
    avoid_margin: Annotated[NonNeg, legacy(0.0)]  # m; f1 = -1 also while the cube or the pusher is
    # this close to an obstacle (legacy: before 2026-12-04 the touch alone)


@Frozen
class ActionConfig(Section):
    mode: Literal["joint", "cartesian"]
    cartesian_max_speed: Pos  # m/s, scale of a normalised Cartesian action
    smoothing: Annotated[NonNeg, legacy(0.0)]  # in [0, 1): request = smoothing * previous request +
    # (1 - smoothing) * new

    def check(self, key: str) -> None:
        if not self.smoothing < 1:
            raise ConfigError(f"{key}.smoothing must be in [0, 1), got {self.smoothing}")


@Frozen
class ObservationConfig(Section):
    relative: Bool  # append the tip and each obstacle relative to the cube (m, world frame)
    lanes: Bool  # append each reachable lane's clearance (m; see env.layout.lane_clearance)
    lane_clip: Annotated[Pair, legacy([-0.1, 0.3])]  # m, the lane clearance saturates at these
    lane_choice: Annotated[Bool, legacy(False)]  # append the episode's lane, one-hot (see
    # env.layout.choose_lane)
    joint_velocity: Annotated[Literal["measured", "position_difference"], legacy("measured")]  # the joint velocities the policy
    # reads: as measured (the simulator's, or the arm's velocity feedback), or estimated from the
    # measured angles' differences over each control period, smoothed (env.realism.VelocityEstimator)
    velocity_smoothing: Annotated[Float, within(0, 1, "[)"), legacy(0.0)]  # position_difference: estimate =
    # this * previous estimate + (1 - this) * the period's difference quotient (0: none)

    def check(self, key: str) -> None:
        if not self.lane_clip[0] < self.lane_clip[1]:
            raise ConfigError(f"{key}.lane_clip must satisfy min < max, got {list(self.lane_clip)}")


@Frozen
class TaskConfig(Section):
    robot: Robot  # an arm of ahrm_stack.robot.ARMS
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
    observation: Annotated[ObservationConfig, legacy({"relative": False, "lanes": False})]
    realism: Annotated[RealismConfig, legacy("ideal")]  # training's domain randomisation: a real
    # arm's imperfections (configs/realism.yaml names sets of them; a name there, e.g. jaco2 or
    # ideal, or the values; legacy: before 2026-12-04 the ideal simulation)

    @property
    def substeps(self) -> int:
        return int(round(self.episode.control_period / self.episode.physics_timestep))

    @property
    def max_steps(self) -> int:
        return int(round(self.episode.duration / self.episode.control_period))

    def derive(self) -> None:
        home = self.arm.home_deg
        if isinstance(home, dict) and self.robot in home:
            object.__setattr__(self, "arm", dataclasses.replace(
                self.arm, home=tuple(math.radians(d) for d in home[self.robot])))

    def check(self, key: str) -> None:
        if isinstance(self.arm.home_deg, dict) and self.robot not in self.arm.home_deg:
            raise ConfigError(f"{key}.arm.home_deg has no entry for robot {self.robot!r} (task.robot); "
                              f"entries: {sorted(self.arm.home_deg)}")
        import numpy as np

        layout = Layout(np.asarray(self.cube.position, float),
                        np.asarray(self.obstacles.fixed_layout, float).reshape(-1, 2))
        if self.layout.mode == "fixed":  # random mode never uses the fixed layout
            try:
                validate_layout(layout, self.table, self.cube, self.obstacles, self.layout)
            except LayoutError as error:
                raise ConfigError(f"{key}.obstacles.fixed_layout / {key}.cube.position: {error}") from None
        if self.layout.mode == "random":  # the nearest allowed obstacle centre must fit on the table
            room = np.asarray(self.table.half_extent) - np.asarray(self.obstacles.size[:2]) / 2
            corners = np.array([[sx * room[0], sy * room[1]] for sx in (-1, 1) for sy in (-1, 1)])
            middle = np.mean(np.asarray(self.layout.cube_region, float), axis=1)  # the region's centre
            reach = float(np.max(np.linalg.norm(corners - middle, axis=1)))
            if self.layout.radial_range[0] > reach:
                raise ConfigError(f"{key}.layout.radial_range {list(self.layout.radial_range)}: no "
                                  f"obstacle that far from the cube fits on the table (at most "
                                  f"{reach:.3f} m)")


@Frozen
class ScriptedConfig(Section):
    """The mink differential-IK waypoint controller (classical baseline). Positions: pusher tip."""

    travel_speed: Pos  # m/s, top tip speed toward a waypoint (lift, travel, descend)
    push_speed: Pos  # m/s, tip speed along the push direction
    position_gain: Pos  # 1/s, proportional gain toward a waypoint / onto the push line
    tilt_gain: Pos  # 1/s, rate of turning the pusher axis toward straight down
    tilt_speed: Pos  # rad/s, top rate of that turn
    tilt_tolerance: Pos  # rad, largest pusher tilt from vertical at which the push may start
    orientation_cost: Pos  # weight of the pusher-pointing-down task (position task weight 1)
    roll_cost: NonNeg  # weight of holding the pusher's spin about its own axis at zero
    damping: Pos  # Levenberg-Marquardt damping of the IK
    clearance: Pos  # m, tip height of the travel plane above the obstacles' tops
    standoff: NonNeg  # m, gap between the pusher and the cube face where the descent ends
    push_height: Pos  # m, tip height above the table while pushing
    push_overshoot: NonNeg  # m, the push stops this far past the table edge
    steer_gain: NonNeg  # 1/m, tan of the push direction's lean toward the lane line per metre of
    # the cube's offset from that line
    max_heading: NonNeg  # rad, largest lean of the push direction from the lane
    realign_distance: Pos  # m, the push stops advancing while the tip is this far off its line
    waypoint_tolerance: Pos  # m
    descend_radius: Annotated[Pos, legacy(0.03)]  # m, the stateless stage inference (train.expert: stateless) has the tip
    # over the push start within this (above waypoint_tolerance, so a descent is not undone)
    collision_margin: NonNeg  # m, distance the IK keeps between the arm/pusher and the obstacles
    collision_detection: Pos  # m, distance at which that constraint becomes active
    collision_gain: Annotated[Float, within(0, 1, "(]")]  # fraction of the gap beyond the margin
    # one control step may close
    solver: Str  # QP solver name for mink (qpsolvers), e.g. daqp

    def check(self, key: str) -> None:
        if self.collision_detection <= self.collision_margin:
            raise ConfigError(f"{key}.collision_detection ({self.collision_detection}) must exceed "
                              f"{key}.collision_margin ({self.collision_margin})")
        import qpsolvers  # the solver list is only known at run time
        if self.solver not in qpsolvers.available_solvers:
            raise ConfigError(f"{key}.solver: {self.solver!r} is not installed; choose one of "
                              f"{sorted(qpsolvers.available_solvers)}")


#: ``safety.self_collision_pairs`` of a run written before the key existed: configs/safety.yaml's
#: pairs when the key was added (2026-12-01).
SELF_COLLISION_PAIRS_2026_12_01 = {
    "jaco": [["base", "link4"], ["base", "link5"], ["base", "link6"], ["base", "pusher"],
             ["link1", "link4"], ["link1", "link5"], ["link1", "link6"], ["link1", "pusher"],
             ["link2", "link4"], ["link2", "link5"], ["link2", "link6"], ["link2", "pusher"]],
    "j2s6s200": [["base", "link4"], ["base", "link5"], ["base", "link6"], ["base", "pusher"],
                 ["link1", "link4"], ["link1", "link5"], ["link1", "link6"], ["link1", "pusher"],
                 ["link2", "link4"], ["link2", "link5"], ["link2", "link6"], ["link2", "pusher"],
                 ["link3", "link5"], ["link3", "link6"], ["link3", "pusher"]]}

SELF_COLLISION_PART = re.compile(r"^(base|pusher|link[1-9])$")


@Frozen
class SelfCollisionPairs(Section):
    """Per arm (``task.robot``), the pairs of arm parts that get a self-collision distance row.
    Parts are named ``base``, ``link1`` ... ``link6`` (the body each joint turns) and ``pusher``."""

    jaco: tuple[tuple[Str, Str], ...]
    j2s6s200: tuple[tuple[Str, Str], ...]

    def check(self, key: str) -> None:
        for robot in (f.name for f in dataclasses.fields(self)):
            for i, pair in enumerate(getattr(self, robot)):
                where = f"{key}.{robot}[{i}]"
                for name in pair:
                    if not SELF_COLLISION_PART.match(name):
                        raise ConfigError(f"{where}: {name!r} is not an arm part; use base, link1 ... "
                                          "link9 or pusher")
                if pair[0] == pair[1]:
                    raise ConfigError(f"{where}: a part cannot be paired with itself ({list(pair)})")


@Frozen
class SafetyConfig(Section):
    """The QP action filter (spec §5). Joint limits and velocity limits come from the robot
    description; only margins and the extra limits the description lacks live here."""

    enabled: Annotated[Bool, stricter("on")]  # false only for an explicit ablation (logged as such)
    solver: Annotated[Literal["osqp", "daqp"], stricter("none")]
    position_margin: Annotated[NonNeg, stricter("higher")]  # rad, kept from each finite joint limit
    velocity_margin: Annotated[Float, within(0, 1, "[)"), stricter("higher")]  # fraction of each
    # joint's velocity limit left unused: headroom for the velocity controller, whose joints run
    # faster than commanded under gravity (servo error)
    acceleration_limit: Annotated[tuple[Pos, ...], stricter("lower")]  # rad/s^2 per joint,
    # |u - u_prev| <= a_max dt
    braking_horizon: Annotated[Bool, stricter("on")]  # true: position and Cartesian rows look ahead
    # max(dt, max_i v_i/a_i) s (the time to brake from full speed), which keeps them satisfiable
    # under the acceleration limits; false: one control period dt, the literal one-step rows
    table_rows: Annotated[Bool, stricter("on")]  # the tip and wrist stay table_margin above the table top
    table_margin: Annotated[NonNeg, stricter("higher")]  # m, the pusher tip stays this far above the table top
    wrist_table_margin: Annotated[NonNeg, stricter("higher")]  # m, the wrist point (the pusher's
    # attachment, inside the wrist ring) stays this far above the table top: the ring's radius plus
    # a clearance
    workspace_rows: Annotated[Bool, stricter("on")]  # the tip and wrist stay inside the workspace box
    workspace_lower: Annotated[Vec3, stricter("higher")]  # m, world-frame box the tip and wrist stay in
    workspace_upper: Annotated[Vec3, stricter("lower")]  # m
    table_distance_rows: Annotated[Bool, stricter("on")]  # distance rows robot part-table (pusher
    # body, link capsules)
    obstacle_rows: Annotated[Bool, stricter("on")]  # distance rows robot part-obstacle (off in
    # training, on in deployment)
    obstacle_safe_distance: Annotated[NonNeg, stricter("higher")]  # m, d_safe
    obstacle_activation_distance: Annotated[Float, stricter("higher")]  # m, pairs farther than this
    # add no row
    max_obstacle_rows: Annotated[NonNegInt, le(LIMITS["max_obstacle_rows"]), stricter("higher")]  # the
    # nearest pairs within the activation distance get a row
    self_collision_rows: Annotated[Bool, stricter("on"), legacy(True)]  # distance rows between the
    # arm's own parts (the pairs below), with the obstacle rows' safe distance, activation distance
    # and horizon (legacy: runs before 2026-12-01 were read with the rows on, as configs/ had it then)
    self_collision_pairs: Annotated[SelfCollisionPairs, stricter("none"), legacy(SELF_COLLISION_PAIRS_2026_12_01)]
    # no order: deploy's pairs are used (its arm's)
    osqp_eps: Annotated[Pos, stricter("none")]  # OSQP absolute and relative tolerance
    osqp_max_iter: Annotated[PosInt, le(LIMITS["osqp_max_iter"]), stricter("none")]
    cartesian_regularization: Annotated[Pos, stricter("none")]  # lambda of ||u||^2 in cartesian mode, (m/rad)^2
    cartesian_orientation_weight: Annotated[NonNeg, stricter("none")]  # weight of holding the pusher's
    # axis direction, m^2

    def check(self, key: str) -> None:
        if self.obstacle_activation_distance <= self.obstacle_safe_distance:
            raise ConfigError(f"{key}.obstacle_activation_distance ({self.obstacle_activation_distance}) "
                              f"must exceed {key}.obstacle_safe_distance ({self.obstacle_safe_distance})")
        for i, (lo, hi) in enumerate(zip(self.workspace_lower, self.workspace_upper)):
            if not lo < hi:
                raise ConfigError(f"{key}.workspace_lower[{i}] ({lo}) must be < workspace_upper[{i}] ({hi})")


Window = Annotated[PosInt, le(LIMITS["window"])]


@Frozen
class MechanismConfig(Section):
    """Reward mechanisms of spec §4. Orders list objective names: avoid, manipulate, time."""

    method: Method
    fixed_order: Order  # FHRM: one order for every phase
    manual_orders: tuple[Order, Order, Order]  # MHRM, per phase
    initial_orders: tuple[Order, Order, Order]  # AHRM, per phase
    convergence_window: Window  # W episodes
    convergence_tolerance: Pos  # relative to max(1, |mean|)
    constraint_window: Window  # episodes averaged for tau
    constraint_min_steps: Window  # steps in a phase before the constraint is checked
    constraint_margin: NonNeg  # a per-step average below tau - margin ends the episode
    priority_period: Window  # P: visiting episodes between priority determinations
    # magnitude (spec Eqs. 3-5): |mean episode sum of f_i| high to low | violation: the per-step
    # average of f_i low to high (the most often violated objective first)
    priority_rule: Annotated[Literal["magnitude", "violation"], legacy("magnitude")]  # (legacy: before
    # 2026-12-02 the spec's ranking)
    blend_band: Pos  # delta, m
    blend_slope: Pos  # alpha, 1/m


LaneFrame = Literal["none", "mirror", "mirror_no_joints", "cube_side_no_joints"]  # ppo.lane_frame (learning/lane_frame.py)


@Frozen
class PPOConfig(Section):
    """PPO hyper-parameters (spec §6). ``configs/ppo.yaml`` holds the learnability study's choices;
    the paper's Table I values are ``configs/profiles/paper.yaml``."""

    gamma: Annotated[Float, within(0, 1)]
    gae_lambda: Annotated[Float, within(0, 1)]
    frames_per_batch: Annotated[PosInt, le(LIMITS["frames_per_batch"])]
    mini_batch_size: PosInt
    epochs: Annotated[PosInt, le(LIMITS["epochs"])]
    learning_rate: Pos
    clip_epsilon: Pos
    entropy_coeff: NonNeg
    critic_coeff: NonNeg
    max_grad_norm: Pos
    hidden_sizes: Annotated[tuple[Annotated[PosInt, le(LIMITS["hidden_width"])], ...],
                            count(1, LIMITS["hidden_layers"])]  # actor and critic layer widths
    activation: Literal["tanh", "relu", "elu"]
    init_std: Pos  # initial standard deviation of the (pre-tanh) Gaussian policy
    actor_init_scale: Annotated[Float, within(0, 1, "(]"), legacy(1.0)]  # the actor's output layer starts with its
    # initial weights and bias times this (1: the library's init; 0.01: Andrychowicz et al. 2021)
    std_mode: Literal["learned", "fixed", "scheduled"]  # scheduled: init_std -> final_std
    final_std: Pos  # std_mode scheduled: the standard deviation reached after std_schedule_frames
    std_schedule_frames: PosInt  # frames over which the std goes (log-linearly) to final_std
    target_kl: NonNeg  # stop a batch's epochs once the approximate KL exceeds 1.5x this (0: off)
    normalize_advantage: Bool  # scale each mini-batch's advantages to zero mean, unit std
    normalize_observations: Bool
    normalizer_clip: Pos  # normalised observations are clipped to +-this
    normalizer_min_std: Annotated[NonNeg, legacy(0.0)]  # the normaliser's per-feature scale is at least this (observation
    # units; 0: sqrt(var + 1e-8) as it is): a feature that barely varied in training cannot turn a
    # small measurement error into a saturated input (legacy: before 2026-12-04 no floor)
    update_normalizer: Bool  # keep updating its statistics from every batch (false: frozen once set)
    bc_coeff: NonNeg  # weight of a behaviour-cloning term toward the demonstrations (0: off)
    bc_coeff_final: Annotated[NonNeg, legacy_rule(_bc_coeff)]  # the anchor's weight goes linearly
    # from bc_coeff to this ...
    bc_decay_frames: Annotated[NonNegInt, legacy(0)]  # ... over this many frames (0: constant bc_coeff)
    reward_scale: Annotated[Pos, legacy(1.0)]  # rewards are multiplied by this before GAE (the critic
    # learns scaled returns)
    lane_frame: Annotated[LaneFrame, legacy("none")]  # the policy reads the world mirrored
    # x -> -x when the episode's lane is -x (learning/lane_frame.py); no_joints: joint entries zeroed;
    # cube_side_no_joints: mirrored when the cube's observed x is < 0 instead (no planner input)

    def check(self, key: str) -> None:
        if self.frames_per_batch % self.mini_batch_size:
            raise ConfigError(f"{key}.frames_per_batch ({self.frames_per_batch}) must be a multiple of "
                              f"{key}.mini_batch_size ({self.mini_batch_size})")


@Frozen
class TrainConfig(Section):
    episodes: Annotated[PosInt, le(LIMITS["episodes"])]  # training stops after this many episodes
    seed: Annotated[NonNegInt, le(LIMITS["seed"])]
    runs_dir: Str  # run folders are created here (relative to the working directory)
    checkpoint_every: PosInt  # batches between checkpoints
    keep_checkpoints: Annotated[PosInt, le(LIMITS["keep_checkpoints"])]  # most recent kept on disk
    eval_episodes: Annotated[NonNegInt, le(LIMITS["eval_episodes"])]  # deterministic evaluation
    # episodes at the end of training (0: none)
    eval_every: NonNegInt  # also evaluate (eval_episodes) every this many training episodes (0: never)
    threads: Annotated[PosInt, le(LIMITS["threads"], " (train.py also refuses more than this "
                                                     "machine's CPU count)")]  # torch intra-op threads
    update_threads: Annotated[PosInt, le(LIMITS["threads"]), legacy(1)]  # torch threads for GAE and the PPO
    # epochs (the environments wait then); at most the machine's CPU count is used. More than 1 pays
    # only for a run alone on the machine (two runs at once with 2 each ran ~3x slower)
    warm_start: Literal["none", "bc"]  # bc: behaviour cloning from scripted demonstrations first
    demo_episodes: Annotated[PosInt, le(LIMITS["demo_episodes"])]  # scripted-controller episodes
    # recorded for warm start and the BC anchor
    bc_epochs: Annotated[PosInt, le(LIMITS["bc_epochs"])]  # passes over the demonstrations for
    # behaviour cloning and the critic refit
    bc_learning_rate: Pos
    demo_noise: NonNeg  # std of noise on the executed demonstration actions (normalised; labels clean)
    expert: Annotated[Literal["stateful", "stateless"], legacy("stateful")]  # the scripted teacher of the demonstrations and the
    # DAgger labels: stages carried over from step to step, or inferred from each state alone
    num_envs: Annotated[PosInt, le(LIMITS["num_envs"])]  # environments stepped together (in one
    # process, sharing the reward mechanism)
    env_workers: Annotated[PosInt, legacy(1)]  # processes the num_envs environments are split over (1: the trainer's own)
    dagger_rounds: Annotated[NonNegInt, legacy(0)]  # after cloning: rounds of (run the clone, label its states with the
    # scripted controller, refit on all data so far); 0: none
    dagger_episodes: Annotated[PosInt, legacy(30)]  # episodes per round
    dagger_duration: Annotated[Pos, legacy(15.0)]  # s, a round's episode is cut after this much simulated time
    frames: Annotated[NonNegInt, legacy(0)]  # training stops once this many frames are collected (0: ``episodes`` decides)
    eval_every_frames: Annotated[NonNegInt, legacy(0)]  # ... or evaluate every this many frames (0: never); either triggers
    time_limit: Annotated[NonNeg, legacy(0.0)]  # s, training episodes are truncated here (0: task.episode.duration);
    # evaluation keeps task.episode.duration
    touch_end: Annotated[bool, legacy(False)]  # a touch of an obstacle ends a training episode as a terminal failure, its
    # step's reward lowered by touch_penalty(ppo.gamma) (evaluation: touches never end an episode)
    touch_end_after: Annotated[NonNegInt, legacy(0)]  # frames: with touch_end, touches end episodes only from this many
    # frames collected on (0: from the start)
    start_curriculum: Annotated[Literal["none", "near_cube", "scripted_states"], legacy("none")]  # near_cube: start near the
    # cube (task.arm.near_cube), more starts by task.arm.start as the level rises; scripted_states:
    # start from the scripted controller's recorded states, further back as the level rises
    curriculum_states: Annotated[PosInt, legacy(100)]  # scripted_states: scripted episodes recorded (the won ones are used)
    curriculum_window: Annotated[PosInt, legacy(50)]  # training episodes whose success rate decides a rise of the level
    curriculum_threshold: Annotated[Float, within(0, 1), legacy(0.5)]  # success rate over the window that raises it
    curriculum_step: Annotated[Float, within(0, 1, "(]"), legacy(0.25)]  # the level's rise (0 to 1; at 1 the task
    # draws every start)

    def check(self, key: str) -> None:
        if self.num_envs % self.env_workers:
            raise ConfigError(f"{key}.num_envs ({self.num_envs}) must be a multiple of "
                              f"{key}.env_workers ({self.env_workers})")
        if self.env_workers > 1 and self.start_curriculum == "scripted_states":
            raise ConfigError(f"{key}.start_curriculum ({self.start_curriculum}) needs "
                              f"{key}.env_workers: 1 (the recorded states are not sent to worker processes)")
        if not self.runs_dir.strip():
            raise ConfigError(f"{key}.runs_dir must name a folder, got {self.runs_dir!r}")


@Frozen
class Config(Section):
    task: TaskConfig
    scripted: ScriptedConfig
    safety: SafetyConfig
    mechanism: MechanismConfig
    ppo: PPOConfig
    train: TrainConfig

    def check(self, key: str) -> None:
        ppo, train, episode = self.ppo, self.train, self.task.episode
        if ppo.frames_per_batch % train.num_envs:
            raise ConfigError(f"ppo.frames_per_batch ({ppo.frames_per_batch}) must be a multiple of "
                              f"train.num_envs ({train.num_envs})")
        steps = round(episode.duration / episode.control_period)
        uses_demos = train.warm_start == "bc" or ppo.bc_coeff > 0
        if uses_demos and train.demo_episodes * steps > LIMITS["demo_steps"]:
            raise ConfigError(f"train.demo_episodes ({train.demo_episodes}) x {steps} steps per "
                              f"episode (task.episode.duration) exceeds {LIMITS['demo_steps']} "
                              "demonstration steps held in memory")
        if len(self.safety.acceleration_limit) != len(self.task.arm.home):
            raise ConfigError(f"safety.acceleration_limit has {len(self.safety.acceleration_limit)} "
                              f"values, task.arm.home_deg {len(self.task.arm.home)}: both give one "
                              f"value per joint of task.robot ({self.task.robot})")
        if ppo.lane_frame != "none":
            task = self.task
            if ppo.lane_frame.startswith("mirror") and not task.observation.lane_choice:
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs task.observation.lane_choice: "
                                  "true (the episode's lane decides whether the policy's frame is mirrored)")
            if task.action.mode != "cartesian":
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs task.action.mode: cartesian (a "
                                  f"joint-velocity action has no mirror image), got {task.action.mode}")
            if set(task.layout.lane_directions) != {"+x", "-x"}:
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs both lanes, +x and -x, in "
                                  f"task.layout.lane_directions, got {list(task.layout.lane_directions)}")
        if self.task.regions.distance_clip < self.mechanism.blend_band:
            raise ConfigError(f"task.regions.distance_clip ({self.task.regions.distance_clip} m) must "
                              f"be >= mechanism.blend_band ({self.mechanism.blend_band} m)")


# ----------------------------------------------------------------------------------------------
# Loading and overrides.
# ----------------------------------------------------------------------------------------------

SECTIONS = {"task": "task.yaml", "scripted": "scripted.yaml", "safety": "safety.yaml",
            "mechanism": "mechanism.yaml", "ppo": "ppo.yaml", "train": "train.yaml"}


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


def profile_overrides(name: str, config_dir: Path | str = CONFIG_DIR, _seen: tuple[str, ...] = ()) -> list[str]:
    """The overrides of profile ``name`` (``configs/profiles/<name>.yaml``), as ``key=value``. A
    top-level ``profile: BASE`` in the file puts BASE's overrides first (the file's own win)."""
    folder = Path(config_dir) / PROFILE_DIR
    path = folder / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []
        raise ConfigError(f"profile={name}: no file {path}; known profiles: {known}")
    if name in _seen:
        raise ConfigError(f"profile={name}: its 'profile' key comes back to itself ({' -> '.join([*_seen, name])})")
    data = read_yaml(path)
    base = data.pop("profile", None)
    if base is None:
        return _flatten(data)
    if not isinstance(base, str):
        raise ConfigError(f"profile: must name a profile in {show_path(path)}, got {base!r}")
    return profile_overrides(base, config_dir, (*_seen, name)) + _flatten(data)


def apply_overrides(data: dict, overrides: Sequence[str], config_dir: Path | str = CONFIG_DIR) -> None:
    """Apply ``key=value`` overrides in order; ``profile=NAME`` applies that profile's overrides at
    its place in the list (so later overrides win over it)."""
    _resolve_realism(data)
    for override in overrides:
        if override.strip().startswith("profile="):
            name = override.split("=", 1)[1].strip()
            for item in profile_overrides(name, config_dir):
                try:
                    apply_override(data, item)
                except ConfigError as error:
                    path = show_path(Path(config_dir) / PROFILE_DIR / f"{name}.yaml")
                    raise ConfigError(f"{error} ({path})") from None
        else:
            apply_override(data, override)
        _resolve_realism(data)


def _resolve_realism(data: dict) -> None:
    """``task.realism`` given as a profile name (``configs/realism.yaml``) becomes its values, in
    place (so that the values are what a run folder records, and overrides of single values apply)."""
    task = data.get("task")
    if isinstance(task, dict) and isinstance(task.get("realism"), str):
        task["realism"] = resolve_realism(task["realism"], "task.realism")


def load_raw(config_dir: Path | str = CONFIG_DIR) -> dict:
    config_dir = Path(config_dir)
    return {section: read_yaml(config_dir / name) for section, name in SECTIONS.items()}


def config_source(config_dir: Path | str = CONFIG_DIR, overrides: Sequence[str] = (),
                  path: Path | str | None = None) -> Source:
    """Where a key's value came from, for messages: "override" for a key that ``overrides`` set
    (a profile's keys count as the profile's file), else ``path`` (a run's config.yaml) or the
    section's file under ``config_dir``."""
    changed, profiles = [], []
    for item in overrides:
        if item.strip().startswith("profile="):
            profiles.append(item.split("=", 1)[1].strip())
        else:
            changed += override_keys([item])

    def at(key: str, keys: list[str]) -> bool:  # key is one of keys or lies below one
        return any(key == k or key.startswith((f"{k}.", f"{k}[")) for k in keys)

    def note(key: str) -> str | None:
        if at(key, changed):
            return "override"
        for name in profiles:
            try:
                keys = override_keys(profile_overrides(name, config_dir))
            except ConfigError:
                continue
            if at(key, keys):
                return show_path(Path(config_dir) / PROFILE_DIR / f"{name}.yaml")
        section = key.split(".")[0].split("[")[0]
        if path is not None:
            where = show_path(path)
        elif section in SECTIONS:
            where = show_path(Path(config_dir) / SECTIONS[section])
        else:
            return None
        # a rule over several keys of a section (key: the section) that an override took part in
        return f"{where} with overrides" if any(at(k, [key]) for k in changed) else where
    return note


def load_config(overrides: Sequence[str] = (), config_dir: Path | str = CONFIG_DIR) -> Config:
    """Read ``configs/*.yaml``, apply ``overrides`` (``profile=NAME`` among them) and validate."""
    data = load_raw(config_dir)
    apply_overrides(data, overrides, config_dir)
    return config_from_dict(data, source=config_source(config_dir, overrides))


#: The version of the run-folder layout of ``config.yaml`` that this code writes (the file's
#: top-level ``schema_version``; a file without one is version 0, written before it was recorded).
#: Adding a key does not change it (a file that lacks the key takes the field's legacy marker);
#: renaming or removing one does, with a step in :func:`fill_missing` that converts older files.
SCHEMA_VERSION = 1


def fill_missing(data: Any) -> Any:
    """A run folder's parsed ``config.yaml`` brought to this schema: its ``schema_version`` checked
    and dropped, every missing key with a :func:`~ahrm_stack.schema.legacy` marker filled with the
    value that run had before the key existed (so it keeps its behaviour, and overrides of the new
    keys apply to it), and a ``task.realism`` profile name resolved. ``data`` itself is not changed;
    anything but a dict is returned as it is, for the schema to name. Raises :class:`ConfigError`
    for a ``schema_version`` this code does not know."""
    if not isinstance(data, dict):
        return data
    if "schema_version" in data:
        version = data["schema_version"]
        if isinstance(version, bool) or not isinstance(version, int) or not 0 <= version <= SCHEMA_VERSION:
            raise ConfigError(f"schema_version: {version!r} is not a version this code reads (0 to "
                              f"{SCHEMA_VERSION}; a newer ahrm_stack wrote it?)")
        data = {key: value for key, value in data.items() if key != "schema_version"}
    data = fill_legacy(Config, data)
    task = data.get("task")
    if isinstance(task, dict) and isinstance(task.get("realism"), str):
        data = {**data, "task": {**task, "realism": resolve_realism(task["realism"], "task.realism")}}
    return data


def config_from_dict(data: dict, runnable: bool = True, source: Source | None = None) -> Config:
    """Validate a parsed configuration (the sections of ``configs/`` or a run folder's
    ``config.yaml``: its ``schema_version`` read, keys added since it was written filled by
    :func:`fill_missing`) into a :class:`Config`.

    ``runnable``: also refuse combinations that cannot run (deploy reads a checkpoint's config,
    whose safety settings it replaces, with False). ``source`` (see :func:`config_source`) names
    the file in messages. ``config_from_dict(config.to_dict()) == config``.
    """
    try:
        data = fill_missing(data)
    except ConfigError as error:
        raise ConfigError(f"{error}{source_note(source, 'schema_version')}") from None
    config = validate(Config, data, "", source)
    if runnable and config.task.action.smoothing > 0 and (
            config.train.warm_start != "none" or config.ppo.bc_coeff > 0 or config.train.dagger_rounds > 0):
        raise ConfigError(f"task.action.smoothing: {config.task.action.smoothing} needs train.warm_start: "
                          "none, ppo.bc_coeff: 0 and train.dagger_rounds: 0 (the scripted "
                          "demonstrations' labels are unsmoothed actions)")
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


@Frozen
class VideoConfig(Section):
    """Offscreen evaluation videos (``configs/video.yaml``)."""

    camera: Str  # a named camera of the arena
    width: Annotated[PosInt, AfterValidator(_even)]  # px, even
    height: Annotated[PosInt, AfterValidator(_even)]  # px, even
    frame_every: PosInt  # control steps per frame
    shadows: Bool  # shadows cost most of the rendering time in software OpenGL
    quality: Annotated[Int, within(0, 10)]  # imageio-ffmpeg quality 0..10
    gl_backends: Annotated[tuple[Literal["egl", "osmesa", "glfw"], ...], count(1)]  # MUJOCO_GL values
    # tried in order when MUJOCO_GL is unset


@Frozen
class PaperRow(Section):
    """One method's row of the paper's Table II."""

    successes: NonNegInt
    episodes: PosInt
    touched: NonNegInt  # episodes touching an obstacle
    time: Pair  # mean, std time to success, s
    travel: Pair  # mean, std cube travel, m


@Frozen
class ExperimentConfig(Section):
    """The four-method grid, its budgets and its report (``configs/experiment.yaml``)."""

    methods: Annotated[tuple[Method, ...], count(1)]  # mechanism.method values, distinct
    seeds: PosInt  # training seeds 0 .. seeds-1
    episodes: PosInt  # training episodes per run (when frames is 0)
    frames: NonNegInt  # training frames per run, the same for every method (0: episodes decides)
    eval_episodes: PosInt  # deterministic evaluation episodes per run
    scripted_episodes: NonNegInt  # evaluation episodes of the scripted controller (0: no row)
    eval_layout: Str  # a name in configs/layouts.yaml
    split: Literal["validation", "test"]  # the final evaluation's seeds (configs/seeds.yaml); test is sealed
    video_episode: Annotated[Int, ge(-1)]  # evaluation episode rendered per method (-1: no videos)
    cpus_per_run: Pos  # Ray num_cpus of one run
    ray_temp_dir: Str
    ray_object_store_mb: PosInt
    success_threshold: Annotated[Float, within(0, 1, "(]")]  # fraction of successes for "episodes
    # to reach it"
    success_window: PosInt  # trailing training episodes of that fraction
    curve_window: PosInt  # trailing window of the learning curves, episodes
    suite: Bool  # also evaluate every run (and its clone, and the scripted controller) on the suite
    bootstrap_samples: PosInt  # resamples of the bootstrap intervals on differences between methods
    paper_table2: dict[Str, PaperRow]

    def check(self, key: str) -> None:
        if len(set(self.methods)) != len(self.methods):
            raise ConfigError(f"{key}.methods: {list(self.methods)} must be distinct values of "
                              f"{list(typing.get_args(Method))}")
        if self.video_episode >= self.eval_episodes:
            raise ConfigError(f"{key}.video_episode ({self.video_episode}) must be < eval_episodes "
                              f"({self.eval_episodes})")


def load_extra(cls: type, name: str, overrides: Sequence[str] = (),
               config_dir: Path | str = CONFIG_DIR) -> Any:
    """Load ``configs/<name>.yaml`` into ``cls`` (VideoConfig, ExperimentConfig) with ``key=value``
    overrides (keys relative to the file), validated; keys are named ``<name>.<key>``."""
    return load_file(cls, Path(config_dir) / f"{name}.yaml", name, overrides)


# ----------------------------------------------------------------------------------------------
# Arms built from a URDF: ``configs/robots/<name>.yaml``.
# ----------------------------------------------------------------------------------------------

ROBOTS_DIR = CONFIG_DIR / "robots"


@Frozen
class UrdfArmConfig(Section):
    """How to build a simulated arm from a URDF of the ``example-robot-data`` package. Joint
    limits, velocity limits, efforts, inertias and meshes come from the URDF; this file holds only
    the simulation parameters a URDF does not carry, and which links to use."""

    urdf: Str  # path under example-robot-data's share folder, e.g. robots/.../kinova.urdf
    root_link: Str  # the link placed at the arm's base frame
    flange_link: Str  # the last link kept: the hand mounts here and the pusher replaces it
    end_effector_link: Str  # a link below the flange: the pusher points from the flange toward it
    hand_meshes: tuple[Str, ...]  # mesh file names of the hand on the flange link (not built)
    velocity_gain: Pos  # kv of the velocity actuators, N m s/rad
    min_velocity_margin: Annotated[Float, within(0, 1, "[)")]  # lower bound on safety.velocity_margin
    # for this arm (fraction of each velocity limit): the filter keeps max(safety.velocity_margin,
    # this) as servo headroom
    joint_damping: NonNeg  # N m s/rad, every actuated joint
    armature: tuple[NonNeg, ...]  # kg m^2, per actuated joint (rotor inertia)
    frictionloss: tuple[NonNeg, ...]  # N m, per actuated joint

    def check(self, key: str) -> None:
        if len(self.armature) != len(self.frictionloss):
            raise ConfigError(f"{key}: armature ({len(self.armature)} values) and frictionloss "
                              f"({len(self.frictionloss)} values) must both give one value per joint")


def load_robot_config(name: str, robots_dir: Path | str = ROBOTS_DIR) -> UrdfArmConfig:
    """The validated ``<robots_dir>/<name>.yaml``; keys are named as ``robots/<name>.<key>``."""
    return load_file(UrdfArmConfig, Path(robots_dir) / f"{name}.yaml", f"robots/{name}")
