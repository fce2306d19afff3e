"""The safety filter's call paths and what each reports (issue 57, item 7: filter.py's mutation
survivors): the fast and the general path (taken for absurd but finite inputs) give the same
command; the unconstrained optimum is returned without a solver call exactly when it is feasible;
the disabled filter, the blind brake and the pinned box against their closed forms; every
``FilterResult`` field on each path; the tolerance ties of ``active``, ``violated`` and
``modified`` at exactly ``ACTIVE_TOLERANCE`` / ``VIOLATION_TOLERANCE``; the self-collision pairs
as configured; array-likes of any dtype read as float vectors."""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety.filter import (ACTIVE_TOLERANCE, VIOLATION_TOLERANCE, SafetyFilter, SafetyFilterError,
                                      self_collision_pairs)
from ahrm_stack.safety.result import DISABLED, INFEASIBLE, NONFINITE_INPUT, OPTIMAL

ABSURD = 1e301  # finite, beyond SANE: a velocity this size sends the call down the general path


@pytest.fixture(scope="module")
def setting():
    config = load_config([])
    runner = TaskRunner(PushOffTask(config.task), seed=0)
    runner.reset()
    task = runner.task
    kin = task.kinematics
    frames = dict(tip_frame=kin.element_frame_id(task.pusher.tip_site),
                  wrist_frame=kin.element_frame_id(task.arm.wrist_site))
    return config, task, task.make_collision_scene(runner.physics), frames


def _make(setting, *, robot=None, scene="task", dt=0.05, **safety) -> SafetyFilter:
    config, task, task_scene, frames = setting
    return SafetyFilter(robot or task.robot, task.kinematics, dataclasses.replace(config.safety, **safety), dt=dt,
                        table_height=config.task.table.height, **frames,
                        scene=task_scene if scene == "task" else scene)


def _home(setting) -> np.ndarray:
    return np.asarray(setting[0].task.arm.home, dtype=float)


def _spy(monkeypatch, f: SafetyFilter) -> list:
    calls: list = []
    solve = f.solver.solve

    def counted(*args):
        calls.append(1)
        return solve(*args)

    monkeypatch.setattr(f.solver, "solve", counted)
    return calls


def _general(f: SafetyFilter, q, u, *, cartesian=False, **kw):
    """The same call with an absurd measured velocity: the general path (dq enters only u_prev's repair)."""
    call = f.cartesian if cartesian else f
    return call(q, np.full(6, ABSURD), u, **kw)


def _cartesian_closed_form(setting, f: SafetyFilter, q, v_nom) -> np.ndarray:
    """argmin ||J u - v||^2 + lambda ||u||^2 + w ||P_perp J_w u||^2 over all joints, from the caller's
    kinematics (not the filter's snapshot), with v scaled down to the reach sum_i |J_i| v_max,i."""
    kin = setting[1].kinematics
    kin.update(q)
    tip = f._frames[0]
    jac = kin.frame_jacobian(tip)
    linear, angular = jac[:3], jac[3:]
    reach = float(np.linalg.norm(linear, axis=0) @ f.velocity.limit)
    if np.linalg.norm(v_nom) > reach:
        v_nom = v_nom * (reach / np.linalg.norm(v_nom))
    axis = kin.frame_pose(tip)[1][:, 2]
    off_axis = (np.eye(3) - np.outer(axis, axis)) @ angular
    config = f.config
    hessian = linear.T @ linear + config.cartesian_regularization * np.eye(6) \
        + config.cartesian_orientation_weight * off_axis.T @ off_axis
    return np.linalg.solve(hessian, linear.T @ v_nom)


def test_solve_time_is_spent_within_the_call(setting):
    f = _make(setting)
    q = _home(setting)
    for general in (False, True):
        for request in (np.full(6, 0.05), np.full(6, 0.5)):  # the shortcut, then a solver call
            f.reset()
            start = time.perf_counter()
            result = _general(f, q, request) if general else f(q, np.zeros(6), request)
            elapsed = time.perf_counter() - start
            assert 0.0 <= result.solve_time <= elapsed
            assert result.status == OPTIMAL


def test_the_general_path_gives_the_fast_paths_command(setting, monkeypatch):
    f = _make(setting)
    calls = _spy(monkeypatch, f)
    q = _home(setting)
    small = np.array([0.05, -0.04, 0.03, 0.1, -0.1, 0.02])
    fast = f(q, np.zeros(6), small)
    f.reset()
    general = _general(f, q, small)
    assert not calls  # feasible: the unconstrained optimum itself, no solver call
    for result in (fast, general):
        np.testing.assert_array_equal(result.command, small)
        assert (result.modified, result.status, result.fallback, result.violated) == (False, OPTIMAL, False, ())
    for request in (np.full(6, 0.5), -np.full(6, 0.5)):  # beyond the acceleration limit: solved
        f.reset()
        fast = f(q, np.zeros(6), request)
        f.reset()
        general = _general(f, q, request)
        np.testing.assert_allclose(general.command, fast.command, atol=1e-12)
        assert general.modified and fast.modified and general.active == fast.active
    # A request inside the box that drives the pusher towards the table: a coupled row cuts it.
    low = q.copy()
    low[1] += 0.6
    down = np.array([0.0, 0.55, 0.0, 0.0, 0.0, 0.0])
    previous = np.array([0.0, 0.4, 0.0, 0.0, 0.0, 0.0])  # the request is inside the box
    fast = f(low, np.zeros(6), down, u_prev=previous)
    general = _general(f, low, down, u_prev=previous)
    assert fast.modified and "table:pusher" in fast.active
    np.testing.assert_allclose(general.command, fast.command, atol=1e-9)
    assert general.active == fast.active
    # Cartesian mode on both paths (the uncommanded last joint held at zero).
    v = np.array([0.02, -0.01, -0.03])
    f.reset()
    fast = f.cartesian(q, np.zeros(6), v)
    f.reset()
    general = _general(f, q, v, cartesian=True)
    np.testing.assert_allclose(general.command, fast.command, atol=1e-12)
    assert general.command[5] == 0.0 and general.status == OPTIMAL


def test_the_unconstrained_cartesian_optimum_is_returned_without_a_solve(setting, monkeypatch):
    """Every joint commanded and a slow request: the optimum of the Cartesian objective is feasible,
    so it is the command (no solver call) on both paths, and it is the closed form."""
    robot = dataclasses.replace(setting[1].robot, commanded_joints=tuple(range(6)))
    f = _make(setting, robot=robot)
    calls = _spy(monkeypatch, f)
    q = _home(setting)
    v = np.array([0.02, -0.01, -0.03])
    expected = _cartesian_closed_form(setting, f, q, v)
    for general in (False, True):
        f.reset()
        result = _general(f, q, v, cartesian=True) if general else f.cartesian(q, np.zeros(6), v)
        np.testing.assert_allclose(result.command, expected, rtol=1e-9, atol=1e-12)
        assert (result.modified, result.status, result.active) == (False, OPTIMAL, ())
    assert not calls


def test_the_disabled_filter_clips_to_the_velocity_limit_and_reports_it(setting):
    f = _make(setting, enabled=False)
    robot = setting[1].robot
    q = _home(setting)
    inside = np.array([0.1, -0.2, 0.3, -0.4, 0.5, -0.6])
    result = f(q, np.zeros(6), inside)
    np.testing.assert_array_equal(result.command, inside)
    assert (result.modified, result.active, result.status, result.solve_time, result.fallback, result.worst_margin,
            result.violated) == (False, (), DISABLED, 0.0, False, np.inf, ())
    result = f(q, np.zeros(6), 2 * robot.velocity_limit * [1, -1, 1, -1, 1, -1])
    np.testing.assert_array_equal(result.command, robot.velocity_limit * [1, -1, 1, -1, 1, -1])
    assert (result.modified, result.status, result.solve_time, result.fallback) == (True, DISABLED, 0.0, False)
    result = f(q, np.zeros(6), [np.nan, 0.1, 0.1, 0.1, 0.1, 0.1])
    np.testing.assert_array_equal(result.command, np.zeros(6))
    assert (result.modified, result.status, result.solve_time, result.fallback) == (True, NONFINITE_INPUT, 0.0, False)


def test_the_disabled_filter_in_cartesian_mode_is_the_unconstrained_ik(setting):
    """At each call's own q (not the last one's): clip(argmin of the objective, -v_max, v_max), the
    uncommanded joint at zero; a request beyond the reach scaled to it; a non-finite state, zero."""
    robot = setting[1].robot
    f = _make(setting, enabled=False)
    home = _home(setting)
    f.cartesian(home + 0.3, np.zeros(6), np.array([0.0, 0.1, 0.0]))  # the snapshot elsewhere first
    q = home.copy()
    q[1] += 0.4
    commanded = np.isin(np.arange(6), robot.commanded_joints)
    for v in (np.array([0.03, -0.02, -0.05]), np.array([3.0, -4.0, 12.0])):
        result = f.cartesian(q, np.zeros(6), v)
        expected = np.clip(_cartesian_closed_form(setting, f, q, v), -robot.velocity_limit, robot.velocity_limit)
        np.testing.assert_allclose(result.command, expected * commanded, rtol=1e-9, atol=1e-12)
        assert result.command[5] == 0.0
        assert (result.modified, result.status, result.solve_time, result.fallback) == (False, DISABLED, 0.0, False)
    result = f.cartesian(np.full(6, np.nan), np.zeros(6), np.array([0.03, -0.02, -0.05]))
    np.testing.assert_array_equal(result.command, np.zeros(6))
    assert (result.modified, result.status, result.fallback) == (True, NONFINITE_INPUT, False)


def test_a_cartesian_request_is_scaled_to_the_reach_whatever_its_size(setting):
    """A slowed arm (reach well below 1 m/s): a request with every component below 1 m/s, faster
    than the reach but whose largest component is slower than it, is still scaled to the reach."""
    robot = setting[1].robot
    slow = dataclasses.replace(robot, velocity_limit=0.05 * robot.velocity_limit)
    f = _make(setting, robot=slow, enabled=False)
    q = _home(setting)
    kin = setting[1].kinematics
    kin.update(q)
    reach = float(np.linalg.norm(kin.frame_jacobian(f._frames[0])[:3], axis=0) @ f.velocity.limit)
    assert reach < 0.5
    v = np.full(3, 1.5 * reach / np.sqrt(3.0))  # |v| = 1.5 reach; each component reach * 0.87
    result = f.cartesian(q, np.zeros(6), v)
    expected = np.clip(_cartesian_closed_form(setting, f, q, v), -slow.velocity_limit, slow.velocity_limit)
    np.testing.assert_allclose(result.command, expected * np.isin(np.arange(6), robot.commanded_joints),
                               rtol=1e-9, atol=1e-12)


def test_a_zero_cartesian_request_asks_for_nothing_without_warnings(setting):
    f = _make(setting)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = f.cartesian(_home(setting), np.zeros(6), np.zeros(3))
    np.testing.assert_allclose(result.command, np.zeros(6), atol=1e-12)


def test_a_non_finite_state_brakes_at_the_acceleration_limit(setting):
    f = _make(setting)
    velocity, step = f.velocity.limit, np.asarray(f.acceleration.step)
    nan = np.full(6, np.nan)
    previous = np.array([0.3, -0.3, 0.1, 0.3, -0.3, 0.0])
    result = f(nan, np.zeros(6), np.zeros(6), u_prev=previous)
    lower, upper = np.maximum(-velocity, previous - step), np.minimum(velocity, previous + step)
    expected = np.clip(0.0, lower, upper)
    np.testing.assert_array_equal(result.command, expected)
    on_bound = [f"acceleration[{i}]" for i in range(6) if min(expected[i] - lower[i], upper[i] - expected[i]) < 1e-9]
    assert len(on_bound) == 4
    assert result.active == tuple(on_bound)
    assert (result.modified, result.status, result.solve_time, result.fallback, result.violated) == \
        (True, NONFINITE_INPUT, 0.0, True, ())
    assert np.isnan(result.worst_margin)
    # A non-finite previous command is replaced by the measured velocity, or zero where that is not finite.
    measured = np.array([np.nan, 0.25, np.nan, -0.25, np.nan, 0.25])
    result = f(nan, measured, np.zeros(6), u_prev=nan)
    previous = np.nan_to_num(measured, nan=0.0)
    expected = np.clip(0.0, np.maximum(-velocity, previous - step), np.minimum(velocity, previous + step))
    np.testing.assert_array_equal(result.command, expected)
    assert result.status == NONFINITE_INPUT


def test_a_command_exactly_active_tolerance_from_its_bound_sits_on_it(setting):
    """dt = 1 s and a_max = 2e-7 rad/s^2, so the acceleration box around u_prev = +-1e-7 has a bound
    at exactly -+1e-7: zero is ACTIVE_TOLERANCE from it, and counts as at it, on every path."""
    f = _make(setting, scene=None, dt=1.0, acceleration_limit=[2 * ACTIVE_TOLERANCE] * 6, braking_horizon=False,
              table_distance_rows=False, self_collision_rows=False)
    previous = ACTIVE_TOLERANCE * np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
    q = _home(setting)
    names = tuple(f"acceleration[{i}]" for i in range(6))
    fast = f(q, np.zeros(6), np.zeros(6), u_prev=previous)
    general = _general(f, q, np.zeros(6), u_prev=previous)
    blind = f(np.full(6, np.nan), np.zeros(6), np.zeros(6), u_prev=previous)
    for result in (fast, general, blind):
        np.testing.assert_array_equal(result.command, np.zeros(6))
        assert result.active == names


def test_a_command_exactly_active_tolerance_from_the_request_is_not_modified(setting):
    """FilterResult.modified: the command differs from u_nom by more than 1e-7 rad/s. The
    acceleration box [-1e-7, 1e-7] (dt = 1 s) cuts a request of 2e-7 to 1e-7: exactly the
    tolerance, so not modified; 3e-7 is."""
    f = _make(setting, scene=None, dt=1.0, acceleration_limit=[ACTIVE_TOLERANCE] * 6, braking_horizon=False,
              table_distance_rows=False, self_collision_rows=False)
    q = _home(setting)
    for general in (False, True):
        for request, modified in ((2 * ACTIVE_TOLERANCE, False), (3 * ACTIVE_TOLERANCE, True)):
            f.reset()
            result = _general(f, q, np.full(6, request)) if general else f(q, np.zeros(6), np.full(6, request))
            np.testing.assert_array_equal(result.command, np.full(6, ACTIVE_TOLERANCE))
            assert result.modified is modified


@pytest.mark.parametrize("general", [False, True])
def test_rows_at_the_tolerances_are_active_and_violated_by_the_documented_rule(setting, monkeypatch, general):
    """Rows 0 u <= b (their margins are b whatever the command): a margin of exactly
    ACTIVE_TOLERANCE is active; a row short by exactly VIOLATION_TOLERANCE is not violated (only
    one short by more is), and an active row beside a violated one is not violated."""
    f = _make(setting, scene=None, table_distance_rows=False, self_collision_rows=False)  # 14 rows of space
    q = _home(setting)
    names = ("row:a", "row:b", "row:c")
    cases = (([ACTIVE_TOLERANCE, 2 * ACTIVE_TOLERANCE, 0.5], ("row:a",), (), OPTIMAL),
             ([-VIOLATION_TOLERANCE, 0.0, 0.5], ("row:a", "row:b"), (), INFEASIBLE),
             ([-1.0, 0.0, 0.5], ("row:a", "row:b"), ("row:a",), INFEASIBLE),
             ([-1.0, -VIOLATION_TOLERANCE, 0.5], ("row:a", "row:b"), ("row:a",), INFEASIBLE))
    for bound, active, violated, status in cases:
        rows = (np.zeros((3, 6)), np.array(bound), names)
        monkeypatch.setattr(f, "_rows", lambda with_obstacles, rows=rows: rows)
        f.reset()
        result = _general(f, q, np.zeros(6)) if general else f(q, np.zeros(6), np.zeros(6))
        assert (result.active, result.violated, result.worst_margin, result.status) == \
            (active, violated, bound[0], status)


def test_a_joint_past_its_bound_is_pinned_and_one_at_the_reachable_edge_is_not(setting):
    """dt = T = 1 s, a_max = 0.25: joint 2 lies 1 rad below its lower position bound (its box
    would start at +1 rad/s, past the reachable +0.25): pinned at +0.25 and reported violated.
    Joint 1 sits 0.25 rad below its upper bound with u_prev = 0.5: its position bound is exactly
    the acceleration bound 0.25, a box of one point, met: neither pinned nor violated."""
    f = _make(setting, scene=None, dt=1.0, acceleration_limit=[0.25] * 6, braking_horizon=False,
              table_distance_rows=False, self_collision_rows=False, table_rows=False, workspace_rows=False)
    q = _home(setting)
    q[1] = f.position.upper[1] - 0.25
    q[2] = f.position.lower[2] - 1.0
    previous = np.array([0.0, 0.5, 0.0, 0.0, 0.0, 0.0])
    result = f(q, np.zeros(6), np.zeros(6), u_prev=previous)
    np.testing.assert_array_equal(result.command, [0.0, 0.25, 0.25, 0.0, 0.0, 0.0])
    assert result.violated == ("position[2]",)
    assert (result.status, result.fallback, result.modified) == (INFEASIBLE, True, True)
    assert "position[1]" in result.active and "acceleration[1]" in result.active


def test_the_position_bound_is_the_distance_over_the_horizon(setting):
    """(q_max - margin - q) / T with T the braking horizon, on both paths."""
    f = _make(setting, table_distance_rows=False, self_collision_rows=False)
    q = _home(setting)
    q[2] = f.position.upper[2] - 0.004
    request = np.array([0.0, 0.0, 0.15, 0.0, 0.0, 0.0])
    for general in (False, True):
        f.reset()
        result = _general(f, q, request) if general else f(q, np.zeros(6), request)
        assert result.command[2] == pytest.approx(0.004 / f.horizon, rel=1e-9)
        assert "position[2]" in result.active


def test_the_table_distance_rows_are_built_on_their_own(setting):
    """table_distance_rows alone (no self-collision rows, no obstacles this call): the same table
    rows as with the self-collision rows beside them."""
    low = _home(setting)
    low[1] += 0.4  # the pusher near the table
    alone = _make(setting, table_rows=False, workspace_rows=False, self_collision_rows=False)
    both = _make(setting, table_rows=False, workspace_rows=False, self_collision_rows=True)
    alone(low, np.zeros(6), np.zeros(6))
    both(low, np.zeros(6), np.zeros(6))
    table = tuple(n for n in both.last_rows if n.startswith("table:"))
    assert table and alone.last_rows == table


def test_obstacle_rows_without_a_scene_are_refused_on_every_path(setting):
    for enabled in (True, False):
        f = _make(setting, scene=None, enabled=enabled, table_distance_rows=False, self_collision_rows=False)
        for dq in (np.zeros(6), np.full(6, ABSURD)):
            with pytest.raises(SafetyFilterError, match="obstacle rows requested but the filter has no collision"):
                f(_home(setting), dq, np.zeros(6), obstacles=True)


def test_the_self_collision_pairs_are_the_configured_ones(setting):
    config, task, scene, _ = setting
    robot = task.robot
    body = {"base": robot.base_body, "pusher": "pusher"}
    body.update({f"link{i + 1}": b for i, b in enumerate(robot.link_bodies)})
    listed = config.safety.self_collision_pairs[robot.name]
    expected = tuple((body[a], body[b]) for a, b in listed)
    assert self_collision_pairs(robot, config.safety, scene) == expected
    assert _make(setting).distances.self_pairs == expected
    off = dataclasses.replace(config.safety, self_collision_rows=False)
    assert self_collision_pairs(robot, off, scene) == ()
    none = dataclasses.replace(config.safety, self_collision_pairs={})
    with pytest.raises(SafetyFilterError, match=f"has no entry for robot '{robot.name}'"):
        self_collision_pairs(robot, none, scene)
    unknown = dataclasses.replace(config.safety, self_collision_pairs={robot.name: (("base", "link9"),)})
    with pytest.raises(SafetyFilterError, match=r"\[0\]: 'link9' is not a part of the"):
        self_collision_pairs(robot, unknown, scene)


def test_array_likes_of_any_dtype_read_as_float_vectors(setting):
    f = _make(setting)
    q = _home(setting)
    reference = f(q, np.zeros(6), np.zeros(6)).command
    for cast in (list, lambda x: np.asarray(x, dtype=np.int64), lambda x: np.asarray(x, dtype=np.float32)):
        f.reset()
        result = f(q.tolist(), cast(np.zeros(6)), cast(np.zeros(6)))
        assert result.command.dtype == np.float64
        np.testing.assert_array_equal(result.command, reference)
    f.reset()
    ints = f(q, [0, 0, 0, 0, 0, 0], np.array([1, 0, 0, 0, 0, 0]))
    assert ints.command.dtype == np.float64 and ints.command[0] == pytest.approx(f.acceleration.step[0])
