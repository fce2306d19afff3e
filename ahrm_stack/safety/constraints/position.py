"""Joint position limits with a margin, for the joints that have finite limits."""

from __future__ import annotations

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.safety.constraints.base import ConstraintDefinitionError


class PositionLimit:
    """``q_min + margin <= q + horizon * u <= q_max - margin`` for every joint with finite limits
    (continuous joints get -inf / +inf).

    This family holds the margined limits (:attr:`lower`, :attr:`upper`, rad) and the horizon; the
    filter turns them into the bounds ``(lower - q) / horizon <= u <= (upper - q) / horizon`` (rad/s)
    at each call, in its own work space (:class:`~ahrm_stack.safety.filter.SafetyFilter`).

    Args:
        robot: the joint limits (rad) are read from here, never restated.
        margin: rad kept from each finite limit. Larger values stop the joints earlier.
        horizon: s over which the command is assumed held. One control period gives the literal
            one-step bound; the braking time max_i v_i / a_i keeps the bound satisfiable under the
            acceleration limits (the joint slows down as it approaches the limit instead of having
            to stop within one period).
    """

    def __init__(self, robot: RobotDescription, margin: float, horizon: float) -> None:
        if not (np.isfinite(margin) and margin >= 0):
            raise ConstraintDefinitionError(f"position margin must be finite and >= 0, got {margin!r}")
        if not (np.isfinite(horizon) and horizon > 0):
            raise ConstraintDefinitionError(f"position horizon must be finite and > 0 s, got {horizon!r}")
        limited = robot.limited
        span = robot.position_upper - robot.position_lower
        too_narrow = limited & ~(span > 2 * margin)
        if np.any(too_narrow):
            i = int(np.flatnonzero(too_narrow)[0])
            raise ConstraintDefinitionError(
                f"position margin {margin} rad leaves no room on {robot.name}.{robot.joint_names[i]} "
                f"(limits [{robot.position_lower[i]}, {robot.position_upper[i]}] rad)")
        self.names = tuple(f"position[{i}]" for i in range(robot.num_joints))
        self.lower = np.where(limited, robot.position_lower + margin, -np.inf)  # rad
        self.upper = np.where(limited, robot.position_upper - margin, np.inf)  # rad
        self.margin = float(margin)  # rad
        self.horizon = float(horizon)  # s
