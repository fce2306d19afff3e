"""The QP backends of the filter, behind one call:

    minimize 1/2 x^T H x + f^T x   subject to   lower <= x <= upper,   A x <= b

with ``x`` of fixed size n and at most ``max_rows`` rows.

* :class:`DaqpSolver` — the daqp active-set solver, called directly (its Python entry point is
  about three times faster than going through ``qpsolvers.solve_qp``).
* :class:`OsqpSolver` — one persistent, warm-started ``osqp.OSQP`` object set up once with the
  maximal row set; each call only updates ``q``, ``l``, ``u``, ``Ax`` (and ``Px`` when the Hessian
  changed), so the sparsity pattern never changes. Rows beyond the call's get zero coefficients and
  infinite bounds.

Both return an :class:`Outcome`; neither raises on a failed solve.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import daqp
import numpy as np
import osqp
import scipy.sparse as sp

DAQP_EXIT_INFEASIBLE = -1
INFEASIBLE = "infeasible"


class Outcome(NamedTuple):
    x: np.ndarray | None  # the solution, None when the solve failed
    status: str  # "optimal", "infeasible" or "failed: <the solver's words>"


class QPSolver(Protocol):
    name: str

    def solve(self, hessian: np.ndarray, linear: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              matrix: np.ndarray, bound: np.ndarray) -> Outcome: ...


class DaqpSolver:
    """daqp on each call (no state: a 6-variable problem is set up in about a microsecond).

    Args:
        num_variables, max_rows: the largest problem this will see.
        primal_tol: daqp's primal feasibility tolerance (bounds that end up active are met
            exactly; the filter clips the rest).
    """

    name = "daqp"

    def __init__(self, num_variables: int, max_rows: int, primal_tol: float = 1e-9) -> None:
        self.num_variables, self.max_rows = num_variables, max_rows
        self._sense = np.zeros(num_variables + max_rows, dtype=np.int32)
        self._upper = np.zeros(num_variables + max_rows)
        self._lower = np.full(num_variables + max_rows, -np.inf)  # rows: one-sided
        self._primal_tol = float(primal_tol)

    def solve(self, hessian, linear, lower, upper, matrix, bound) -> Outcome:
        n, m = self.num_variables, len(bound)
        if m > self.max_rows:
            raise ValueError(f"{m} rows exceed the {self.max_rows} this solver was sized for")
        upper_all, lower_all = self._upper[:n + m], self._lower[:n + m]
        upper_all[:n], upper_all[n:] = upper, bound
        lower_all[:n] = lower
        x, _, exitflag, _ = daqp.solve(hessian, linear, matrix, upper_all, lower_all,
                                       self._sense[:n + m], primal_tol=self._primal_tol)
        if exitflag >= 1:
            return Outcome(x, "optimal")
        if exitflag == DAQP_EXIT_INFEASIBLE:
            return Outcome(None, INFEASIBLE)
        return Outcome(None, f"failed: daqp exitflag {exitflag}")


class OsqpSolver:
    """A persistent OSQP workspace for problems of ``num_variables`` variables and up to
    ``max_rows`` rows.

    Args:
        eps: absolute and relative tolerance (tight values with polishing give active-set accuracy;
            the filter projects onto the hard bounds whatever this is).
        max_iter: ADMM iteration cap; reaching it counts as a failure.
    """

    name = "osqp"

    def __init__(self, num_variables: int, max_rows: int, eps: float, max_iter: int) -> None:
        n, m = num_variables, max_rows
        self.num_variables, self.max_rows = n, m
        upper_rows, upper_cols = np.triu_indices(n)
        order = np.lexsort((upper_rows, upper_cols))  # CSC: column-major
        self._p_rows, self._p_cols = upper_rows[order], upper_cols[order]
        self._hessian = np.eye(n)
        pattern_p = sp.csc_matrix((self._hessian[self._p_rows, self._p_cols], self._p_rows,
                                   np.r_[0, np.cumsum(np.arange(1, n + 1))]), shape=(n, n))
        # A = [I_n; rows]: column j holds its identity entry, then the m row entries, all stored.
        indices = np.concatenate([np.r_[j, n + np.arange(m)] for j in range(n)])
        indptr = np.arange(0, n * (m + 1) + 1, m + 1)
        self._a_values = np.zeros((n, m + 1))  # row j: the stored values of column j
        self._a_values[:, 0] = 1.0
        pattern_a = sp.csc_matrix((self._a_values.ravel(), indices, indptr), shape=(n + m, n))
        self._solver = osqp.OSQP()
        self._solver.setup(pattern_p, np.zeros(n), pattern_a, np.full(n + m, -np.inf),
                           np.full(n + m, np.inf), eps_abs=eps, eps_rel=eps, max_iter=max_iter,
                           polishing=True, warm_starting=True, verbose=False)
        status = osqp.SolverStatus
        self._accepted = (int(status.OSQP_SOLVED), int(status.OSQP_SOLVED_INACCURATE))
        self._infeasible = (int(status.OSQP_PRIMAL_INFEASIBLE),
                            int(status.OSQP_PRIMAL_INFEASIBLE_INACCURATE))
        self._lower = np.full(n + m, -np.inf)
        self._upper = np.full(n + m, np.inf)

    def solve(self, hessian, linear, lower, upper, matrix, bound) -> Outcome:
        n, m = self.num_variables, len(bound)
        if m > self.max_rows:
            raise ValueError(f"{m} rows exceed the {self.max_rows} this OSQP workspace was set up for")
        values = self._a_values
        values[:, 1:m + 1] = matrix.T
        values[:, m + 1:] = 0.0
        self._lower[:n] = lower
        self._upper[:n] = upper
        self._upper[n:n + m] = bound
        self._upper[n + m:] = np.inf
        update = {"q": linear, "l": self._lower, "u": self._upper, "Ax": values.ravel()}
        if not np.array_equal(hessian, self._hessian):
            self._hessian = np.array(hessian, dtype=float)
            update["Px"] = self._hessian[self._p_rows, self._p_cols]
        self._solver.update(**update)
        result = self._solver.solve(raise_error=False)
        status = result.info.status_val
        if status in self._accepted and np.all(np.isfinite(result.x)):
            return Outcome(np.array(result.x, dtype=float), "optimal")
        if status in self._infeasible:
            return Outcome(None, INFEASIBLE)
        return Outcome(None, f"failed: osqp {result.info.status}")
