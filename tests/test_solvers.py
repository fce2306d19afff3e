"""The filter's QP backends (ahrm_stack/safety/solvers.py) against closed forms and each other:
box-constrained least distance, rows added and removed between calls of one OSQP workspace, a
Hessian that changes, the size guard, and each failure path."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ahrm_stack.safety import solvers
from ahrm_stack.safety.solvers import INFEASIBLE, DaqpSolver, OsqpSolver

N, ROWS = 4, 3


def _osqp() -> OsqpSolver:
    return OsqpSolver(N, ROWS, eps=1e-10, max_iter=20000)


def _projection(target: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple:
    """min 1/2 |x - target|^2 within a box: H = I, f = -target; the answer is the clip."""
    return np.eye(N), -target, lower, upper, np.zeros((0, N)), np.zeros(0), np.clip(target, lower, upper)


@pytest.mark.parametrize("make", [lambda: DaqpSolver(N, ROWS), _osqp], ids=["daqp", "osqp"])
def test_a_box_projection_is_the_clip(make):
    solver = make()
    rng = np.random.default_rng(0)
    for _ in range(5):
        target = rng.normal(size=N) * 2
        h, f, lo, hi, a, b, want = _projection(target, -np.ones(N), np.ones(N))
        outcome = solver.solve(h, f, lo, hi, a, b)
        assert outcome.status == "optimal"
        np.testing.assert_allclose(outcome.x, want, atol=1e-7)


@pytest.mark.parametrize("make", [lambda: DaqpSolver(N, ROWS), _osqp], ids=["daqp", "osqp"])
def test_rows_of_one_call_do_not_outlive_it(make):
    """Three half-spaces x_i <= 0.1 (i < 3), then one, then none: each answer is the closed-form
    projection of the same target with that call's rows only."""
    solver = make()
    target = np.full(N, 0.5)
    free = np.full(N, 10.0)
    for rows in (3, 1, 0, 2):
        matrix = np.eye(N)[:rows]
        bound = np.full(rows, 0.1)
        outcome = solver.solve(np.eye(N), -target, -free, free, matrix, bound)
        want = target.copy()
        want[:rows] = 0.1
        assert outcome.status == "optimal"
        np.testing.assert_allclose(outcome.x, want, atol=1e-7)


def test_osqp_takes_a_new_hessian_and_keeps_an_unchanged_one():
    solver = _osqp()
    free = np.full(N, 10.0)
    f = -np.ones(N)
    for scale in (1.0, 4.0, 4.0, 0.5):  # x* = H^-1 (-f) = 1 / scale
        h = np.eye(N) * scale
        outcome = solver.solve(h, f, -free, free, np.zeros((0, N)), np.zeros(0))
        np.testing.assert_allclose(outcome.x, np.full(N, 1.0 / scale), atol=1e-7)
    coupled = np.eye(N) + 0.3 * (np.ones((N, N)) - np.eye(N))  # off-diagonal (upper-triangle) entries
    outcome = solver.solve(coupled, f, -free, free, np.zeros((0, N)), np.zeros(0))
    np.testing.assert_allclose(outcome.x, np.linalg.solve(coupled, np.ones(N)), atol=1e-7)


def test_osqp_meets_daqp_on_random_coupled_problems():
    """Random strictly convex problems with active bounds and rows: OSQP (polished, tight eps)
    gives daqp's active-set answer to 1e-6."""
    rng = np.random.default_rng(3)
    daqp_solver, osqp_solver = DaqpSolver(N, ROWS), _osqp()
    for _ in range(30):
        root = rng.normal(size=(N, N))
        h = root @ root.T + 0.5 * np.eye(N)
        f = rng.normal(size=N) * 3
        rows = int(rng.integers(0, ROWS + 1))
        matrix, bound = rng.normal(size=(rows, N)), rng.uniform(0.0, 0.5, rows)
        lower, upper = -rng.uniform(0.2, 1.0, N), rng.uniform(0.2, 1.0, N)
        a = daqp_solver.solve(h, f, lower, upper, matrix, bound)
        b = osqp_solver.solve(h, f, lower, upper, matrix, bound)
        assert a.status == b.status == "optimal"
        np.testing.assert_allclose(b.x, a.x, atol=1e-6)


@pytest.mark.parametrize("make", [lambda: DaqpSolver(N, ROWS), _osqp], ids=["daqp", "osqp"])
def test_infeasible_rows_are_named_and_too_many_rows_refused(make):
    solver = make()
    free = np.full(N, 10.0)
    matrix = np.array([np.eye(N)[0], -np.eye(N)[0]])  # x0 <= -1 and -x0 <= -1: empty
    outcome = solver.solve(np.eye(N), np.zeros(N), -free, free, matrix, np.array([-1.0, -1.0]))
    assert outcome == (None, INFEASIBLE)
    with pytest.raises(ValueError, match=rf"{ROWS + 1} rows exceed the {ROWS}"):
        solver.solve(np.eye(N), np.zeros(N), -free, free, np.zeros((ROWS + 1, N)), np.zeros(ROWS + 1))


def test_a_failed_solve_is_reported_not_raised(monkeypatch):
    free = np.full(N, 10.0)
    problem = (np.eye(N), np.zeros(N), -free, free, np.zeros((0, N)), np.zeros(0))
    osqp_solver = OsqpSolver(N, ROWS, eps=1e-12, max_iter=1)  # one ADMM iteration: not solved
    outcome = osqp_solver.solve(np.eye(N) * 3.0, np.ones(N), *problem[2:])
    assert outcome.x is None and outcome.status.startswith("failed: osqp")
    # a "solved" status with a non-finite entry is a failure too
    fake = SimpleNamespace(x=np.array([0.0, np.nan, 0.0, 0.0]),
                           info=SimpleNamespace(status_val=osqp_solver._accepted[0], status="solved"))
    good = _osqp()
    monkeypatch.setattr(good._solver, "solve", lambda raise_error=False: fake)
    assert good.solve(*problem) == (None, "failed: osqp solved")
    monkeypatch.setattr(solvers.daqp, "solve", lambda *args, **kwargs: (None, None, -3, None))
    assert DaqpSolver(N, ROWS).solve(*problem) == (None, "failed: daqp exitflag -3")


def test_osqp_prints_nothing(capfd):
    solver = _osqp()
    free = np.full(N, 10.0)
    solver.solve(np.eye(N), -np.ones(N), -free, free, np.eye(N)[:1], np.array([0.1]))
    out, err = capfd.readouterr()
    assert out == "" and err == ""
