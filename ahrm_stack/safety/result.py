"""What one filter call reports, and the per-episode aggregate the environment and the deploy loop
keep."""

from __future__ import annotations

import collections
import dataclasses
import math

import numpy as np

#: ``FilterResult.status`` values.
OPTIMAL = "optimal"  # the QP was solved; the command is its solution, verified and projected
INFEASIBLE = "infeasible"  # no command meets every constraint: the safest one was returned
SOLVER_FAILED = "solver_failed"  # the solver failed or returned garbage: the safest command
NONFINITE_INPUT = "nonfinite_input"  # NaN/inf in q, dq, u_prev or the request: see FilterResult
DISABLED = "disabled"  # the filter is switched off (ablation): velocity clip only


@dataclasses.dataclass(slots=True)
class FilterResult:
    """The outcome of one filter call.

    Attributes:
        command: joint velocities to send, rad/s (finite; within every hard bound).
        modified: the command differs from the request (joint mode: from ``u_nom`` by more than
            1e-7 rad/s; Cartesian mode: a constraint was active or a fallback was taken).
        active: constraints at their bound, e.g. ``"velocity[2]"``, ``"acceleration[0]"``,
            ``"position[1]"``, ``"table:tip"``, ``"workspace:wrist:z_upper"``,
            ``"obstacle:b_3/obstacle_1"``.
        status: one of ``optimal``, ``infeasible``, ``solver_failed``, ``nonfinite_input``,
            ``disabled``.
        solve_time: s spent in the QP solver(s) during this call.
        fallback: the command is not the solution of the requested QP (infeasible, solver
            failure, or non-finite input): it brakes towards zero within the limits.
        worst_margin: smallest predicted clearance over the coupled rows, m (``p + T J u`` minus
            its bound; negative = violated); +inf when no coupled row was built, NaN when the state
            was not finite.
        violated: constraints the command does not meet because no command could (a joint past
            its position bound further than one period's deceleration allows, coupled rows in the
            fallback). Velocity and acceleration bounds are never in this list.
    """

    command: np.ndarray
    modified: bool
    active: tuple[str, ...]
    status: str
    solve_time: float
    fallback: bool
    worst_margin: float
    violated: tuple[str, ...] = ()


class InterventionStats:
    """Running aggregate of filter results over an episode (or any window): call :meth:`add`
    once per control step and :meth:`reset` at episode start."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.steps = 0
        self.interventions = 0  # steps whose command was modified
        self.fallbacks = 0
        self.nonfinite = 0
        self.worst_margin = math.inf  # m, over the steps with a finite state
        self.max_solve_time = 0.0  # s
        self.total_solve_time = 0.0  # s
        self.active_counts: collections.Counter[str] = collections.Counter()
        self.violated_counts: collections.Counter[str] = collections.Counter()

    def add(self, result: FilterResult) -> None:
        self.steps += 1
        self.interventions += bool(result.modified)
        self.fallbacks += bool(result.fallback)
        self.nonfinite += result.status == NONFINITE_INPUT
        if not math.isnan(result.worst_margin):
            self.worst_margin = min(self.worst_margin, result.worst_margin)
        self.max_solve_time = max(self.max_solve_time, result.solve_time)
        self.total_solve_time += result.solve_time
        self.active_counts.update(result.active)
        self.violated_counts.update(result.violated)

    @property
    def intervention_rate(self) -> float:
        return self.interventions / self.steps if self.steps else 0.0

    def summary(self) -> dict[str, float]:
        """Flat numbers for a logger."""
        return {
            "safety/steps": float(self.steps),
            "safety/interventions": float(self.interventions),
            "safety/intervention_rate": self.intervention_rate,
            "safety/fallbacks": float(self.fallbacks),
            "safety/nonfinite": float(self.nonfinite),
            "safety/worst_margin": self.worst_margin,
            "safety/max_solve_time": self.max_solve_time,
            "safety/mean_solve_time": self.total_solve_time / self.steps if self.steps else 0.0,
        }
