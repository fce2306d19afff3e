"""The table rows: control points of the arm stay above the table top."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ahrm_stack.safety.constraints.base import ConstraintDefinitionError, CoordinateRows


class TableLimit(CoordinateRows):
    """``p_z + horizon * (J u)_z >= table_height + margin`` for each control point (the pusher
    tip and the wrist), ``p`` the point's world position (m) and ``J`` its linear Jacobian; stored
    as ``-horizon * J_z u <= p_z - (table_height + margin)``. Rows are named ``table:<point>``.

    Args:
        table_height: z of the table top, m (world frame).
        margins: m kept above the table top, per control point (in the order of the control
            points); larger values keep that point higher.
        horizon: s over which the command is linearised (see ``PositionLimit``).
    """

    def __init__(self, table_height: float, margins: Mapping[str, float], horizon: float) -> None:
        if not np.isfinite(table_height):
            raise ConstraintDefinitionError(f"table height must be finite, got {table_height!r}")
        for point, margin in margins.items():
            if not (np.isfinite(margin) and margin >= 0):
                raise ConstraintDefinitionError(f"table margin of {point} must be finite and >= 0 m, "
                                                f"got {margin!r}")
        self.floors = {p: float(table_height + m) for p, m in margins.items()}  # m
        super().__init__(tuple(margins), [(p, "z", 1, floor, f"table:{p}")
                                          for p, floor in self.floors.items()], horizon)
