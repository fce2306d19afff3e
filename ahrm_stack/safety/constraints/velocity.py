"""Joint velocity limits."""

from __future__ import annotations

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.safety.constraints.base import ConstraintDefinitionError, JointBounds


class VelocityLimit:
    """``|u| <= (1 - margin) v_max`` per joint, with ``v_max`` (rad/s) read from the robot
    description (the velocity actuators' control range).

    Args:
        robot: the velocity limits.
        margin: fraction of each limit left unused, in [0, 1): headroom for the velocity
            controller, whose joints can run faster than commanded (servo error under gravity).
    """

    def __init__(self, robot: RobotDescription, margin: float = 0.0) -> None:
        limit = np.asarray(robot.velocity_limit, dtype=float)
        if limit.shape != (robot.num_joints,) or not np.all(np.isfinite(limit) & (limit > 0)):
            raise ConstraintDefinitionError(
                f"{robot.name}: velocity limits must be {robot.num_joints} finite values > 0 rad/s, "
                f"got {robot.velocity_limit!r}")
        if not (np.isfinite(margin) and 0 <= margin < 1):
            raise ConstraintDefinitionError(f"velocity margin must be a fraction in [0, 1), got {margin!r}")
        self.names = tuple(f"velocity[{i}]" for i in range(robot.num_joints))
        self.limit = limit * (1.0 - margin)  # rad/s, what the filter may command
        self._bounds = JointBounds(-self.limit, self.limit.copy())

    def bounds(self) -> JointBounds:
        """Bounds on u, rad/s."""
        return self._bounds
