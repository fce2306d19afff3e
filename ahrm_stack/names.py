"""The task's vocabulary, defined once: the three objectives and the three phases.

Objectives are indexed from 0 in the order of :data:`OBJECTIVE_NAMES` (the reward components
f1-f3, the mechanisms' orders, the logs' columns). Phases are numbered from 1 (the task's
``phase``, spec §2): phase k is ``PHASE_NAMES[k - 1]``.
"""

from __future__ import annotations

OBJECTIVE_NAMES: tuple[str, str, str] = ("avoid", "manipulate", "time")
"""Objective i is ``OBJECTIVE_NAMES[i]``: avoid the obstacles, manipulate the cube, minimise time."""
NUM_OBJECTIVES = len(OBJECTIVE_NAMES)

PHASE_NAMES: tuple[str, str, str] = ("approach", "pre-manipulate", "manipulate")
"""Phase k (1-based) is ``PHASE_NAMES[k - 1]``."""
NUM_PHASES = len(PHASE_NAMES)

__all__ = ["NUM_OBJECTIVES", "NUM_PHASES", "OBJECTIVE_NAMES", "PHASE_NAMES"]
