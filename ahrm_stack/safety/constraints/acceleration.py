"""Acceleration (rate) limits against the previous command."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ahrm_stack.safety.constraints.base import ConstraintDefinitionError, JointBounds


class AccelerationLimit:
    """``|u - u_prev| <= a_max * dt`` per joint.

    Args:
        limit: a_max per joint, rad/s^2 (from ``SafetyConfig.acceleration_limit``).
        dt: the control period, s: the command may change by at most ``a_max * dt`` rad/s per step.
        num_joints: the arm's joint count, to catch a config written for another arm.
    """

    def __init__(self, limit: Sequence[float], dt: float, num_joints: int) -> None:
        limit = np.asarray(limit, dtype=float)
        if limit.shape != (num_joints,):
            raise ConstraintDefinitionError(
                f"acceleration_limit has {limit.size} values, the arm has {num_joints} joints")
        if not np.all(np.isfinite(limit) & (limit > 0)):
            raise ConstraintDefinitionError(f"acceleration_limit must be finite and > 0 rad/s^2, "
                                            f"got {limit.tolist()}")
        if not (np.isfinite(dt) and dt > 0):
            raise ConstraintDefinitionError(f"control period must be finite and > 0 s, got {dt!r}")
        self.names = tuple(f"acceleration[{i}]" for i in range(num_joints))
        self.limit = limit
        self.step = limit * dt  # rad/s per control period

    def bounds(self, previous: np.ndarray) -> JointBounds:
        """Bounds on u (rad/s) given the previous command ``previous`` (rad/s, finite)."""
        return JointBounds(previous - self.step, previous + self.step)
