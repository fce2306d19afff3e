"""The task's sections (``configs/task.yaml`` and ``configs/scripted.yaml``): the table, arm,
pusher, cube, obstacles, layout, regions, episode, rewards, actions and observations of
:class:`TaskConfig`, and the scripted controller's :class:`ScriptedConfig`. Lengths in m, angles
in degrees where the key says ``_deg`` (else rad), times in s; positions in the world frame."""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, PlainValidator
from pydantic_core import PydanticCustomError

from ahrm_stack.config.fields import LIMITS, Frozen, NonNeg, NonNegInt, Pair, Pos, PosInt, Vec3
from ahrm_stack.config.layout_rules import Layout, LayoutError, validate_layout
from ahrm_stack.config.robots import arm_names, registered_arm
from ahrm_stack.realism import RealismConfig
from ahrm_stack.schema import _float  # the Float rule, for values inside a custom validator
from ahrm_stack.schema import (MISSING, Bool, ConfigError, Float, FrozenDict, Section, Str, count, derived, fail, le,
                               legacy, legacy_rule, within)

Robot = Annotated[Str, AfterValidator(registered_arm)]  # an arm of the registry (configs/robots/<name>.yaml)


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
        names = arm_names()
        unknown = sorted((k for k in value if k not in names), key=str)
        if unknown:
            fail(f".{unknown[0]}: no arm {unknown[0]!r}; registered (configs/robots/): {list(names)}")
        return FrozenDict({name: _degrees(angles, f".{name}") for name, angles in value.items()})
    return _degrees(value)


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


HomeDeg = Annotated[typing.Union[tuple[float, ...], dict[str, tuple[float, ...]]], PlainValidator(_home_deg)]


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
    bearing: Annotated[Literal["any", "behind", "behind_free"], legacy("any")]  # any: uniform |
    # behind: opposite the episode's lane as the planner chooses it | behind_free: opposite a lane
    # drawn uniformly among the free ones (no planner; legacy: before 2026-12-02 every bearing)
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
    integrator: Annotated[Literal["euler", "implicitfast"], legacy("euler")]  # MuJoCo's integrator
    # (legacy: before 2026-12-06 MuJoCo's default, semi-implicit Euler); implicitfast integrates the
    # velocity actuators' damping implicitly, stable at the coarser timestep
    impratio: Annotated[Pos, legacy(1.0)]  # MuJoCo's ratio of frictional to normal constraint
    # impedance (elliptic cones): above 1 the friction is harder, less slip without noslip passes
    # (legacy: before 2026-12-06 MuJoCo's default 1)

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
class StagedRewardConfig(Section):
    """The oracle control's staged dense reward (``task.rewards.learning: staged``; issue 56), after
    ManiSkill3's PushCube: reach a push pose behind the cube for the episode's lane, then push it
    along the lane off the table. Per step, in [-1, 1]: (reach + reached x push) / 2, 1 on success,
    minus 1 on a step that touches an obstacle."""

    tanh_scale: Pos  # 1/m: reach = 1 - tanh(scale x the tip's distance to the push pose), push likewise
    push_offset: Pos  # m: the push pose is this far behind the cube's back face, at the cube's centre
    reached_distance: Pos  # m: the push term counts once the tip is this close to the push pose


@Frozen
class RewardConfig(Section):
    obstacle_speed_threshold: Pos  # m/s; a faster obstacle counts as touched
    progress_eps: Pos  # m; f2 needs progress above the best so far by more than this
    time_reference: Annotated[Literal["previous", "success"], legacy("previous")]  # the episode that
    # sets f3's phase budgets (legacy: before 2026-12-02 the spec's previous episode)
    avoid_margin: Annotated[NonNeg, legacy(0.0)]  # m; f1 = -1 also while the cube or the pusher is
    # this close to an obstacle (legacy: before 2026-12-04 the touch alone)
    learning: Annotated[Literal["mechanism", "staged"], legacy("mechanism")]  # the reward the learner
    # gets: mechanism (the reward mechanism's, spec §4) | staged (the oracle control's staged dense
    # reward, keyed on the planner's lane: a diagnosis of PPO, never a method; the mechanism still
    # runs and logs)
    staged: Annotated[StagedRewardConfig, legacy({"tanh_scale": 5.0, "push_offset": 0.03,
                                                  "reached_distance": 0.03})]
    touch_cost: Annotated[NonNeg, legacy(0.0)]  # the learner's reward units (before ppo.reward_scale):
    # subtracted once per episode, at its first step that touches an obstacle; the episode goes on
    # (issue 56 item 4: the touch priced per episode, as the goal counts it; 0: none; legacy: before
    # 2026-12-08 none)
    touched_success_cost: Annotated[NonNeg, legacy(0.0)]  # the learner's reward units (before
    # ppo.reward_scale): subtracted at the success step of an episode that touched an obstacle before
    # or at it, so that a touched push is priced only when it succeeds (a touch that does not lead to a
    # success costs nothing more; the curriculum still counts the success); 0: none; legacy: before
    # 2026-12-08 none


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
    robot: Robot  # an arm of the registry: configs/robots/<name>.yaml
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
