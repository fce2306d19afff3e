"""Lane agreement: did the cube leave by the lane the scripted controller's planner chose?

For any policy (a trained one, with or without the planner's ``lane_choice`` in its observation,
or the scripted controller itself), per episode:

* the **planned** lane: :func:`~ahrm_stack.env.layout.choose_lane` on the first state of the
  episode (the settled layout and the pusher tip after the reset), exactly the plan the scripted
  controller follows and the ``lane_choice`` observation shows
  (:meth:`~ahrm_stack.env.task.PushOffTask.plan_lane`);
* the **taken** lane: the sign of the cube's x displacement (m, world frame) from the episode's
  start to its end, ``+x`` or ``-x`` (the task's lanes run along x); ``None`` when the cube moved
  less than half its size in x (it was not pushed along a lane);
* whether an obstacle was touched in the episode.

:class:`LaneTable` counts them: agreement among the pushed episodes, and touching after a wrong
lane against after the planned one.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np


@dataclasses.dataclass(frozen=True)
class LaneOutcome:
    """One episode's lanes: ``planned`` (``+x`` / ``-x``), ``taken`` (``None``: not pushed along
    a lane) and ``touched`` (any obstacle touched in the episode)."""

    planned: str
    taken: str | None
    touched: bool

    @property
    def agrees(self) -> bool | None:
        """Whether the cube left by the planned lane (``None`` when it was not pushed)."""
        return None if self.taken is None else self.taken == self.planned

    def row(self) -> dict[str, object]:
        """The episode's columns of ``evaluation.csv``."""
        return {"planned_lane": self.planned, "cube_lane": self.taken or "",
                "lane_agrees": "" if self.agrees is None else self.agrees}


def taken_lane(start_xy: Sequence[float], end_xy: Sequence[float], min_shift: float) -> str | None:
    """The lane the cube went along: ``+x`` / ``-x`` by the sign of its x displacement from
    ``start_xy`` to ``end_xy`` (m, world frame), ``None`` when that displacement is below
    ``min_shift`` (m)."""
    shift = float(end_xy[0]) - float(start_xy[0])
    if not np.isfinite(shift):
        raise ValueError(f"cube positions must be finite, got {start_xy} -> {end_xy}")
    if abs(shift) < min_shift:
        return None
    return "+x" if shift > 0 else "-x"


@dataclasses.dataclass(frozen=True)
class LaneTable:
    """Counts over episodes: ``episodes``; ``pushed`` (a lane taken); ``agreeing`` (the planned
    lane); ``touched_agreeing`` and ``touched_disagreeing`` (episodes that touched an obstacle
    among the agreeing and the disagreeing ones)."""

    episodes: int
    pushed: int
    agreeing: int
    touched_agreeing: int
    touched_disagreeing: int

    @property
    def disagreeing(self) -> int:
        return self.pushed - self.agreeing

    @property
    def agreement(self) -> float:
        """Share of the pushed episodes that left by the planned lane (nan when none was pushed)."""
        return self.agreeing / self.pushed if self.pushed else float("nan")

    @classmethod
    def from_outcomes(cls, outcomes: Sequence[LaneOutcome]) -> "LaneTable":
        pushed = [o for o in outcomes if o.agrees is not None]
        return cls(len(outcomes), len(pushed), sum(bool(o.agrees) for o in pushed),
                   sum(o.touched for o in pushed if o.agrees), sum(o.touched for o in pushed if not o.agrees))

    def as_dict(self) -> dict[str, float | int]:
        return {**dataclasses.asdict(self), "disagreeing": self.disagreeing, "agreement": self.agreement}

    def __str__(self) -> str:
        return (f"lane agreement {self.agreeing}/{self.pushed} pushed episodes ({self.agreement:.1%}) | "
                f"touching after the planned lane {self.touched_agreeing}/{self.agreeing}, after a wrong "
                f"lane {self.touched_disagreeing}/{self.disagreeing}")


__all__ = ["LaneOutcome", "LaneTable", "taken_lane"]
