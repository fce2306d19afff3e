"""The joint-space and coordinate constraint families against their closed forms, in milliseconds.

Each family's bounds or rows are written out by hand for a small made-up arm (three joints, one of
them continuous) and compared with what the family builds, on both sides of every boundary its
constructor checks. These are the fast tests of ``tools/mutate.py --suite`` for
``ahrm_stack/safety/constraints/`` (the property tests of ``tests/test_safety.py`` take minutes).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrm_stack.robot import RobotDescription
from ahrm_stack.safety.constraints import (AccelerationLimit, ConstraintDefinitionError, ControlPoints,
                                           CoordinateRows, JointBounds, PositionLimit, TableLimit, VelocityLimit,
                                           WorkspaceLimit)

LOWER = np.array([-2.0, 0.5, -np.inf])  # rad; joint 2 is continuous
UPPER = np.array([1.0, 3.5, np.inf])  # rad
V_MAX = np.array([0.8, 1.2, 2.0])  # rad/s


def arm(lower: np.ndarray = LOWER, upper: np.ndarray = UPPER, velocity: np.ndarray = V_MAX) -> RobotDescription:
    """A made-up three-joint arm: only the joint-space facts the families read."""
    return RobotDescription(name="toy", joint_names=("a", "b", "c"), position_lower=np.asarray(lower, float),
                            position_upper=np.asarray(upper, float), velocity_limit=np.asarray(velocity, float),
                            commanded_joints=(0, 1, 2), link_bodies=("l1", "l2", "l3"), base_body="base",
                            attachment_site="flange")


# ------------------------------------------------------------------------------------ position


def test_position_limits_move_in_by_the_margin_on_each_side_and_continuous_joints_are_free():
    family = PositionLimit(arm(), margin=0.25, horizon=0.5)
    np.testing.assert_array_equal(family.lower, [-1.75, 0.75, -np.inf])  # q_min + margin
    np.testing.assert_array_equal(family.upper, [0.75, 3.25, np.inf])  # q_max - margin
    assert family.names == ("position[0]", "position[1]", "position[2]")
    assert (family.margin, family.horizon) == (0.25, 0.5)


def test_a_margin_of_zero_keeps_the_limits_and_the_horizon_is_kept_as_given():
    family = PositionLimit(arm(), margin=0.0, horizon=2e-3)
    np.testing.assert_array_equal(family.lower[:2], LOWER[:2])
    np.testing.assert_array_equal(family.upper[:2], UPPER[:2])
    assert family.horizon == 2e-3


@pytest.mark.parametrize("margin", [-1e-12, -0.1, math.nan, math.inf])
def test_a_negative_or_non_finite_margin_is_refused(margin):
    with pytest.raises(ConstraintDefinitionError, match=r"^position margin must be finite and >= 0"):
        PositionLimit(arm(), margin=margin, horizon=0.1)


@pytest.mark.parametrize("horizon", [0.0, -0.1, math.nan, math.inf])
def test_a_horizon_not_finite_and_positive_is_refused(horizon):
    with pytest.raises(ConstraintDefinitionError, match=r"^position horizon must be finite and > 0 s"):
        PositionLimit(arm(), margin=0.1, horizon=horizon)


def test_a_margin_of_half_the_span_leaves_no_room_and_just_below_it_does():
    # joint 0 spans 3 rad, joint 1 spans 3 rad as well: 1.5 rad from each side meets in the middle
    with pytest.raises(ConstraintDefinitionError, match=r"margin 1\.5 rad leaves no room on toy\.a "):
        PositionLimit(arm(), margin=1.5, horizon=0.1)
    family = PositionLimit(arm(), margin=1.5 - 1e-9, horizon=0.1)
    assert np.all(family.lower[:2] < family.upper[:2])


def test_the_first_joint_without_room_is_named():
    narrow = np.array([-2.0, 0.5, -np.inf]), np.array([1.0, 0.7, np.inf])  # joint 1 spans 0.2 rad
    with pytest.raises(ConstraintDefinitionError, match=r"on toy\.b \(limits \[0\.5, 0\.7\] rad\)"):
        PositionLimit(arm(*narrow), margin=0.1, horizon=0.1)
    PositionLimit(arm(*narrow), margin=0.099, horizon=0.1)  # a continuous joint never lacks room


# ------------------------------------------------------------------------------------ velocity


def test_velocity_bounds_are_the_limits_less_the_margin_symmetric():
    family = VelocityLimit(arm(), margin=0.25)
    np.testing.assert_array_equal(family.limit, 0.75 * V_MAX)
    bounds = family.bounds()
    assert isinstance(bounds, JointBounds)
    np.testing.assert_array_equal(bounds.lower, -0.75 * V_MAX)
    np.testing.assert_array_equal(bounds.upper, 0.75 * V_MAX)
    assert family.names == ("velocity[0]", "velocity[1]", "velocity[2]")
    np.testing.assert_array_equal(VelocityLimit(arm()).limit, V_MAX)  # no margin by default


@pytest.mark.parametrize("margin", [0.0, 0.999])
def test_a_velocity_margin_in_zero_to_one_is_accepted(margin):
    np.testing.assert_allclose(VelocityLimit(arm(), margin).limit, (1 - margin) * V_MAX)


@pytest.mark.parametrize("margin", [1.0, -1e-12, math.nan])
def test_a_velocity_margin_outside_zero_to_one_is_refused(margin):
    with pytest.raises(ConstraintDefinitionError, match=r"^velocity margin must be a fraction in \[0, 1\)"):
        VelocityLimit(arm(), margin)


@pytest.mark.parametrize("limits", [[0.8, 1.2], [0.8, 0.0, 2.0], [0.8, -1.0, 2.0], [0.8, np.inf, 2.0],
                                    [0.8, np.nan, 2.0]])
def test_velocity_limits_must_be_one_finite_positive_value_per_joint(limits):
    with pytest.raises(ConstraintDefinitionError, match=r"^toy: velocity limits must be 3 finite values > 0"):
        VelocityLimit(arm(velocity=np.array(limits)))


# ------------------------------------------------------------------------------------ acceleration


@pytest.mark.parametrize("previous", [[0.0, 0.0, 0.0], [0.5, -0.7, 0.1], [-0.9, 0.9, -2.0]])
def test_acceleration_bounds_are_the_previous_command_plus_and_minus_one_step(previous):
    family = AccelerationLimit([2.0, 4.0, 10.0], dt=0.05, num_joints=3)
    np.testing.assert_allclose(family.step, [0.1, 0.2, 0.5], rtol=0, atol=1e-15)  # a_max * dt, rad/s
    previous = np.array(previous)
    bounds = family.bounds(previous)
    np.testing.assert_array_equal(bounds.lower, previous - family.step)
    np.testing.assert_array_equal(bounds.upper, previous + family.step)
    assert family.names == ("acceleration[0]", "acceleration[1]", "acceleration[2]")
    np.testing.assert_array_equal(family.limit, [2.0, 4.0, 10.0])


def test_acceleration_limits_must_fit_the_arm_and_be_finite_and_positive():
    with pytest.raises(ConstraintDefinitionError, match=r"^acceleration_limit has 2 values, the arm has 3 joints"):
        AccelerationLimit([1.0, 1.0], dt=0.05, num_joints=3)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ConstraintDefinitionError, match=r"^acceleration_limit must be finite and > 0"):
            AccelerationLimit([1.0, bad, 1.0], dt=0.05, num_joints=3)
    for bad in (0.0, -0.05, math.inf, math.nan):
        with pytest.raises(ConstraintDefinitionError, match=r"^control period must be finite and > 0 s"):
            AccelerationLimit([1.0, 1.0, 1.0], dt=bad, num_joints=3)


# ------------------------------------------------------------------------------------ coordinate rows

POINTS = ("tip", "wrist")


def points() -> ControlPoints:
    """Two control points with made-up positions (m) and linear Jacobians (m per rad/s)."""
    rng = np.random.default_rng(7)
    return ControlPoints(POINTS, np.array([0.1, -0.2, 0.35, 0.3, 0.05, 0.6]), rng.normal(size=(6, 3)))


def test_table_rows_keep_each_point_its_margin_above_the_table_over_the_horizon():
    at = points()
    family = TableLimit(0.3, {"tip": 0.01, "wrist": 0.04}, horizon=0.2)
    assert family.floors == pytest.approx({"tip": 0.31, "wrist": 0.34})
    rows = family.rows(at)
    assert rows.names == ("table:tip", "table:wrist")
    # z + T (J u)_z >= floor  <=>  -T J_z u <= z - floor
    np.testing.assert_allclose(rows.matrix, -0.2 * at.jacobians[[2, 5]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rows.bound, [0.35 - 0.31, 0.6 - 0.34], rtol=0, atol=1e-15)
    matrix, bound = np.empty((2, 3)), np.empty(2)
    family.write(at.jacobians, at.positions, matrix, bound)
    np.testing.assert_array_equal(matrix, rows.matrix)
    np.testing.assert_array_equal(bound, rows.bound)


def test_table_limits_refuse_a_non_finite_height_or_a_negative_margin():
    TableLimit(0.0, {"tip": 0.0}, horizon=0.1)  # zero margin and a table at z = 0 are fine
    with pytest.raises(ConstraintDefinitionError, match=r"^table height must be finite"):
        TableLimit(math.nan, {"tip": 0.01}, horizon=0.1)
    for bad in (-1e-9, math.nan, math.inf):
        with pytest.raises(ConstraintDefinitionError, match=r"^table margin of wrist must be finite and >= 0 m"):
            TableLimit(0.3, {"tip": 0.01, "wrist": bad}, horizon=0.1)


def test_workspace_rows_keep_each_point_inside_the_box_over_the_horizon():
    at = points()
    lower, upper = np.array([-0.5, -0.4, 0.2]), np.array([0.6, 0.3, 0.9])
    family = WorkspaceLimit(lower, upper, horizon=0.1, points=POINTS)
    rows = family.rows(at)
    expected_names, expected_matrix, expected_bound = [], [], []
    for k, point in enumerate(POINTS):
        for a, axis in enumerate("xyz"):
            position, jacobian = at.positions[3 * k + a], at.jacobians[3 * k + a]
            expected_names += [f"workspace:{point}:{axis}_upper", f"workspace:{point}:{axis}_lower"]
            expected_matrix += [0.1 * jacobian, -0.1 * jacobian]  # p + T J u <= upper; p + T J u >= lower
            expected_bound += [upper[a] - position, position - lower[a]]
    assert rows.names == tuple(expected_names)
    np.testing.assert_allclose(rows.matrix, expected_matrix, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rows.bound, expected_bound, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(family.lower, lower)
    np.testing.assert_array_equal(family.upper, upper)


@pytest.mark.parametrize("lower, upper, message", [
    ([0.0, 0.0], [1.0, 1.0, 1.0], "workspace corners must be 3-vectors"),
    ([0.0, 0.0, 0.0], [1.0, 1.0], "workspace corners must be 3-vectors"),
    ([0.0, 0.5, 0.0], [1.0, 0.5, 1.0], "workspace needs finite lower < upper"),  # an empty y range
    ([0.0, 0.0, 0.0], [1.0, 1.0, math.inf], "workspace needs finite lower < upper"),
    ([-math.inf, 0.0, 0.0], [1.0, 1.0, 1.0], "workspace needs finite lower < upper"),  # ordered, not finite
    ([math.nan, 0.0, 0.0], [1.0, 1.0, 1.0], "workspace needs finite lower < upper"),
])
def test_workspace_corners_must_be_finite_ordered_three_vectors(lower, upper, message):
    with pytest.raises(ConstraintDefinitionError, match=f"^{message}"):
        WorkspaceLimit(lower, upper, horizon=0.1, points=POINTS)


def test_coordinate_rows_refuse_bad_rows_and_stack_only_alike_families():
    with pytest.raises(ConstraintDefinitionError, match=r"^horizon must be finite and > 0 s"):
        CoordinateRows(POINTS, [], 0.0)
    for bad in [("elbow", "z", 1, 0.0, "r"), ("tip", "w", 1, 0.0, "r"), ("tip", "z", 0, 0.0, "r")]:
        with pytest.raises(ConstraintDefinitionError, match=r"^bad coordinate row"):
            CoordinateRows(POINTS, [bad], 0.1)
    with pytest.raises(ConstraintDefinitionError, match=r"^limit of row .* must be finite"):
        CoordinateRows(POINTS, [("tip", "z", 1, math.inf, "r")], 0.1)
    table = TableLimit(0.3, {"tip": 0.01, "wrist": 0.04}, horizon=0.2)
    box = WorkspaceLimit([-1, -1, 0], [1, 1, 2], horizon=0.2, points=POINTS)
    stacked = CoordinateRows.stacked([table, box]).rows(points())
    table_rows, box_rows = table.rows(points()), box.rows(points())
    assert stacked.names == table_rows.names + box_rows.names
    np.testing.assert_array_equal(stacked.matrix, np.vstack([table_rows.matrix, box_rows.matrix]))
    np.testing.assert_array_equal(stacked.bound, np.concatenate([table_rows.bound, box_rows.bound]))
    with pytest.raises(ConstraintDefinitionError, match=r"^stacked coordinate rows need the same"):
        CoordinateRows.stacked([table, WorkspaceLimit([-1, -1, 0], [1, 1, 2], horizon=0.1, points=POINTS)])
    with pytest.raises(ValueError, match=r"^rows expect control points"):
        table.rows(ControlPoints(("wrist", "tip"), points().positions, points().jacobians))
