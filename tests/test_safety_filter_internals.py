"""The safety filter's last resort and its Cartesian objective, held to outside references
(issue 57, item 7: filter.py's mutation survivors): the minimum-violation command of an
infeasible row set against SciPy's SLSQP on the same problem, and the Cartesian request's scaling
to the arm's reach against the Jacobian's column norms computed here."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import minimize

from ahrm_stack.config import load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety.filter import VIOLATION_WEIGHT, SafetyFilter
from ahrm_stack.safety.solvers import Outcome


def _filter(safety=None) -> SafetyFilter:
    config = load_config([])
    runner = TaskRunner(PushOffTask(config.task), seed=0)
    runner.reset()
    task = runner.task
    kin = task.kinematics
    return SafetyFilter(task.robot, kin, safety or config.safety, dt=0.05,
                        table_height=config.task.table.height,
                        tip_frame=kin.element_frame_id(task.pusher.tip_site),
                        wrist_frame=kin.element_frame_id(task.arm.wrist_site),
                        scene=task.make_collision_scene(runner.physics))


@pytest.fixture(scope="module")
def safety_filter() -> SafetyFilter:
    return _filter()


def _reference(lower, upper, matrix, bound) -> np.ndarray:
    """min 1/2 |u|^2 + rho s + 1/2 s^2, A u - s <= b, s >= 0, lower <= u <= upper, by SLSQP."""
    n = len(lower)

    def cost(x):  # divided by rho (the same minimiser, a better scaled problem for SLSQP)
        return (0.5 * x @ x) / VIOLATION_WEIGHT + x[-1]

    def grad(x):
        g = x / VIOLATION_WEIGHT
        g[-1] += 1.0
        return g

    rows = {"type": "ineq", "fun": lambda x: bound - (matrix @ x[:n] - x[-1]),
            "jac": lambda x: -np.hstack((matrix, -np.ones((len(bound), 1))))}
    start = np.r_[np.clip(0.0, lower, upper), max(0.0, float(np.max(matrix @ np.clip(0.0, lower, upper) - bound)))]
    found = minimize(cost, start, jac=grad, constraints=[rows], method="SLSQP",
                     bounds=list(zip(lower, upper)) + [(0.0, None)], options={"ftol": 1e-12, "maxiter": 500})
    assert found.success, found.message
    return found.x[:n]


def test_a_feasible_brake_is_the_box_clip_of_zero(safety_filter):
    lower, upper = np.array([-1.0, 0.2, -3, -1, -1, -1]), np.array([1.0, 1.0, -0.5, 1, 1, 1])
    matrix, bound = np.eye(6)[:2], np.array([5.0, 5.0])
    np.testing.assert_array_equal(safety_filter._safest(lower, upper, matrix, bound), [0, 0.2, -0.5, 0, 0, 0])
    no_rows = safety_filter._safest(lower, upper, np.zeros((0, 6)), np.zeros(0))
    np.testing.assert_array_equal(no_rows, [0, 0.2, -0.5, 0, 0, 0])


@pytest.mark.parametrize("seed", range(8))
def test_the_least_violating_command_is_scipys(safety_filter, seed):
    """Rows that zero violates (and that may contradict each other): the filter's fallback QP (DAQP)
    gives SLSQP's minimiser of worst violation first, then distance from zero, within the box."""
    rng = np.random.default_rng(seed)
    lower, upper = -rng.uniform(0.2, 1.0, 6), rng.uniform(0.2, 1.0, 6)
    matrix = rng.normal(size=(4, 6))
    bound = -rng.uniform(0.5, 3.0, 4)  # A 0 = 0 > b: zero violates every row
    if seed % 2:
        matrix[1] = -matrix[0]  # a row and its opposite, both below zero: no command meets both
    mine = safety_filter._safest(lower, upper, matrix, bound)
    theirs = _reference(lower, upper, matrix, bound)
    assert np.all(mine >= lower - 1e-12) and np.all(mine <= upper + 1e-12)
    np.testing.assert_allclose(mine, theirs, atol=2e-4)
    worst = lambda u: float(np.max(matrix @ u - bound))  # noqa: E731
    assert worst(mine) <= worst(theirs) + 1e-6


def test_a_cartesian_request_beyond_the_arms_reach_is_scaled_along_its_direction():
    """The reach is sum_i |J_i| v_max,i (the tip's fastest speed any command could give); a
    request faster than that becomes the reach along its direction, a slower one stays, and zero
    asks for nothing. With no orientation weight the Hessian is J^T J plus the regularisation."""
    config = load_config([])
    plain = _filter(dataclasses.replace(config.safety, cartesian_orientation_weight=0.0))
    regularised = _filter(dataclasses.replace(config.safety, cartesian_orientation_weight=0.0,
                                              cartesian_regularization=0.25))
    q = np.array([0.3, 2.9, 1.3, -2.0, 1.4, 0.0])
    jacobian = None
    for f in (plain, regularised):
        f._snapshot.update(q)
        jacobian = f._snapshot.jacobian(f._frames[0])[:3]
    reach = float(np.sum(np.linalg.norm(jacobian, axis=0) * plain.velocity.limit))
    direction = np.array([0.6, -0.8, 0.0])
    for speed in (10 * reach, 2.0 * reach):
        hessian, linear = plain._cartesian_objective(speed * direction)
        np.testing.assert_allclose(linear, -(jacobian.T @ (reach * direction)), rtol=1e-9, atol=1e-12)
    slow = 0.25 * reach * np.array([0.0, 0.0, -1.0])
    hessian, linear = plain._cartesian_objective(slow)
    np.testing.assert_allclose(linear, -(jacobian.T @ slow), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(hessian, jacobian.T @ jacobian + 1e-3 * np.eye(6), rtol=1e-12, atol=1e-15)
    _, linear = plain._cartesian_objective(np.zeros(3))
    np.testing.assert_array_equal(linear, np.zeros(6))
    more, _ = regularised._cartesian_objective(slow)
    np.testing.assert_allclose(more - hessian, (0.25 - 1e-3) * np.eye(6), atol=1e-12)


def test_a_brake_that_meets_some_rows_but_not_all_is_not_kept(safety_filter):
    """Zero meets the first row and violates the second: the fallback QP runs (SLSQP's answer)."""
    lower, upper = -np.full(6, 0.8), np.full(6, 0.8)
    matrix = np.array([[1.0, 0.5, 0, 0, 0, 0], [0, -1.0, 0.3, 0, 0, 0]])
    bound = np.array([1.0, -0.2])
    mine = safety_filter._safest(lower, upper, matrix, bound)
    np.testing.assert_allclose(mine, _reference(lower, upper, matrix, bound), atol=2e-4)
    assert np.all(matrix @ mine <= bound + 1e-9)


def test_the_brake_is_returned_when_the_fallback_solve_fails(safety_filter, monkeypatch):
    monkeypatch.setattr(safety_filter._fallback_solver, "solve", lambda *args: Outcome(None, "solver_failed"))
    lower, upper = np.array([0.1, -1, -1, -1, -1, -1]), np.ones(6)
    brake = safety_filter._safest(lower, upper, np.eye(6)[:1], np.array([-5.0]))
    np.testing.assert_array_equal(brake, [0.1, 0, 0, 0, 0, 0])
