"""Constraint families of the safety filter, one per module: each builds its bounds or rows from
the current state; the filter stacks them and solves."""

from ahrm_stack.safety.constraints.acceleration import AccelerationLimit
from ahrm_stack.safety.constraints.base import (ArmSnapshot, ConstraintDefinitionError, ControlPoints,
                                                CoordinateRows, JointBounds, Rows)
from ahrm_stack.safety.constraints.distance import DistanceLimit
from ahrm_stack.safety.constraints.position import PositionLimit
from ahrm_stack.safety.constraints.table import TableLimit
from ahrm_stack.safety.constraints.velocity import VelocityLimit
from ahrm_stack.safety.constraints.workspace import WorkspaceLimit

__all__ = ["AccelerationLimit", "ArmSnapshot", "ConstraintDefinitionError", "ControlPoints", "CoordinateRows",
           "DistanceLimit", "JointBounds", "PositionLimit", "Rows", "TableLimit",
           "VelocityLimit", "WorkspaceLimit"]
