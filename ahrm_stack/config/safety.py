"""The safety filter's section (``configs/safety.yaml``): :class:`SafetyConfig`, whose every key
carries a ``stricter`` marker, the per-arm self-collision pairs, and the per-arm joint acceleration
limits with their one resolver (:func:`arm_acceleration_limit`)."""

from __future__ import annotations

import typing
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, PlainValidator
from pydantic_core import PydanticCustomError

from ahrm_stack.config.fields import LIMITS, Frozen, NonNeg, NonNegInt, Pos, PosInt, Vec3
from ahrm_stack.config.robots import arm_names, load_arm, pair_problem
from ahrm_stack.schema import _float  # the Float rule, for values inside a custom validator
from ahrm_stack.schema import Bool, ConfigError, Float, FrozenDict, Section, Str, fail, le, legacy, stricter, within

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

def _pairs_per_arm(value: dict) -> dict:
    """``safety.self_collision_pairs``: registered arm name -> its pairs, each of two arm parts."""
    names = arm_names()
    for robot, pairs in value.items():
        if robot not in names:
            fail(f".{robot}: no arm {robot!r}; registered (configs/robots/): {list(names)}")
        problem = pair_problem(pairs)
        if problem:
            fail(f".{robot}{problem}")
    return FrozenDict(value)


#: Per arm (``task.robot``), the pairs of arm parts that get a self-collision distance row (composed
#: from ``configs/robots/<arm>.yaml``'s ``self_collision_pairs``). Parts are named ``base``,
#: ``link1`` ... ``link6`` (the body each joint turns) and ``pusher``.
SelfCollisionPairs = Annotated[dict[Str, tuple[tuple[Str, Str], ...]], AfterValidator(_pairs_per_arm)]


def _limits(value: Any, where: str) -> tuple[float, ...]:
    """A list of accelerations, each a finite number > 0 (rad/s^2); errors name ``where[i]``."""
    if not isinstance(value, (list, tuple)):
        fail(f"{where}: expected a list of rad/s^2 per joint, got {value!r}")
    out = []
    for i, item in enumerate(value):
        try:
            number = _float(item)
        except PydanticCustomError as error:
            fail(f"{where}[{i}]{error.context['text']}")
        if not number > 0:
            fail(f"{where}[{i}] must be > 0, got {number!r}")
        out.append(number)
    return tuple(out)


def _acceleration_limit(value: Any) -> tuple[float, ...] | FrozenDict:
    """``safety.acceleration_limit``: one list (rad/s^2 per joint of task.robot) or a mapping
    registered arm name -> its list, each list as long as that arm's joints (its registry entry's
    ``home_deg``)."""
    if not isinstance(value, dict):
        return _limits(value, "")
    names = arm_names()
    out = {}
    for robot, limits in value.items():
        if robot not in names:
            fail(f".{robot}: no arm {robot!r}; registered (configs/robots/): {list(names)}")
        out[robot] = _limits(limits, f".{robot}")
        joints = len(load_arm(robot).home_deg)
        if len(out[robot]) != joints:
            fail(f".{robot}: {len(out[robot])} values, arm {robot!r} has {joints} joints: give one per joint")
    return FrozenDict(out)


#: Joint acceleration limits, rad/s^2 per joint: per arm (``task.robot``), a mapping arm name -> one
#: value per joint (composed from ``configs/robots/<arm>.yaml``'s ``acceleration_limit``), or one
#: list that applies to task.robot (the form every run's ``config.yaml`` records, and overrides
#: such as ``safety.acceleration_limit=[1000,1000,1000,1000,1000,1000]``). A loaded
#: :class:`~ahrm_stack.config.Config` holds task.robot's list (:func:`arm_acceleration_limit`).
AccelerationLimits = Annotated[typing.Union[tuple[float, ...], dict[str, tuple[float, ...]]],
                               PlainValidator(_acceleration_limit)]


def arm_acceleration_limit(value: tuple[float, ...] | typing.Mapping[str, tuple[float, ...]], robot: str,
                           joints: int | None = None) -> tuple[float, ...]:
    """The joint acceleration limits (rad/s^2 per joint) of arm ``robot`` in ``value`` (a
    ``safety.acceleration_limit``: a mapping arm name -> values, or one list, which is the arm in
    use's). The one resolver of the key: :class:`~ahrm_stack.config.Config` (for task.robot), the
    safety filter and deploy's Kortex backend read it through here. ``joints``: the arm's joint
    count (``task.arm.home_deg``'s), checked when given. Raises :class:`ConfigError` (one line
    naming the key) for an arm the mapping lacks or a list of another length."""
    if isinstance(value, typing.Mapping):
        if robot not in value:
            raise ConfigError(f"safety.acceleration_limit has no entry for arm {robot!r} (task.robot); "
                              f"entries: {sorted(value)}")
        limit, key, hint = tuple(value[robot]), f"safety.acceleration_limit.{robot}", ""
    else:
        limit, key = tuple(value), "safety.acceleration_limit"
        hint = " (one list applies to task.robot; or give a mapping arm name -> rad/s^2 per joint)"
    if joints is not None and len(limit) != joints:
        raise ConfigError(f"{key} has {len(limit)} values, task.arm.home_deg {joints}: both give one value "
                          f"per joint of task.robot ({robot}){hint}")
    return limit


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
    acceleration_limit: Annotated[AccelerationLimits, stricter("lower")]  # rad/s^2 per joint,
    # |u - u_prev| <= a_max dt: per arm, composed from configs/robots/<arm>.yaml, or one list for
    # task.robot (AccelerationLimits above); a loaded Config holds task.robot's list
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
