"""The workspace rows: control points of the arm stay inside a world-frame box."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ahrm_stack.safety.constraints.base import ConstraintDefinitionError, CoordinateRows


class WorkspaceLimit(CoordinateRows):
    """``lower <= p + horizon * J u <= upper`` (world frame, m) for each control point.

    Rows, per point and axis k: ``horizon * J_k u <= upper_k - p_k`` (named
    ``workspace:<point>:<k>_upper``) and ``-horizon * J_k u <= p_k - lower_k`` (``..._lower``).

    Args:
        lower, upper: box corners, m, world frame; ``lower < upper`` on every axis.
        horizon: s over which the command is linearised (see ``PositionLimit``).
        points: the control points' names.
    """

    def __init__(self, lower: Sequence[float], upper: Sequence[float], horizon: float,
                 points: Sequence[str]) -> None:
        lower = np.asarray(lower, dtype=float)
        upper = np.asarray(upper, dtype=float)
        if lower.shape != (3,) or upper.shape != (3,):
            raise ConstraintDefinitionError(f"workspace corners must be 3-vectors, got {lower}, {upper}")
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(lower < upper)):
            raise ConstraintDefinitionError(f"workspace needs finite lower < upper, got {lower}, {upper}")
        self.lower, self.upper = lower, upper
        bounds = []
        for p in points:
            for k, axis in enumerate("xyz"):
                bounds.append((p, axis, -1, float(upper[k]), f"workspace:{p}:{axis}_upper"))
                bounds.append((p, axis, 1, float(lower[k]), f"workspace:{p}:{axis}_lower"))
        super().__init__(points, bounds, horizon)
