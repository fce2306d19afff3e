"""What makes a layout of the cube and the obstacles valid (spec §1): every box on the table, no
two footprints closer than ``min_gap``, and a free lane at least ``lane_width`` wide from behind
the cube to a reachable table edge.

All positions are (x, y) centres on the table top, in metres, in the world frame. The rules read a
few values of the task's sections (``task.table``, ``task.cube``, ``task.obstacles``,
``task.layout``), named here by the protocols below, so that the configuration can check its fixed
layout with them (:meth:`ahrm_stack.config.TaskConfig.check`) without an import circle: this module
imports nothing of ``ahrm_stack`` but the schema's :class:`ConfigError`. Sampling and lane choice
are in :mod:`ahrm_stack.env.layout`.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

from ahrm_stack.schema import ConfigError


class TableTop(Protocol):
    """``task.table`` (:class:`~ahrm_stack.config.TableConfig`) as the rules read it."""

    @property
    def half_extent(self) -> tuple[float, float]:
        """(x, y) half-size of the table top, m."""


class CubeSize(Protocol):
    """``task.cube`` (:class:`~ahrm_stack.config.CubeConfig`) as the rules read it."""

    @property
    def size(self) -> float:
        """Edge length, m."""


class ObstacleSize(Protocol):
    """``task.obstacles`` (:class:`~ahrm_stack.config.ObstacleConfig`) as the rules read it."""

    @property
    def size(self) -> tuple[float, float, float]:
        """Full edge lengths (x, y, z), m."""


class LaneRules(Protocol):
    """``task.layout`` (:class:`~ahrm_stack.config.LayoutConfig`) as the rules read it."""

    @property
    def min_gap(self) -> float:
        """Smallest allowed gap between two footprints, m."""

    @property
    def lane_width(self) -> float:
        """Width of the free lane, m."""

    @property
    def approach_room(self) -> float:
        """Free length behind the cube for the pusher, m."""

    @property
    def lane_directions(self) -> tuple[str, ...]:
        """The reachable lane directions, ``"+x"`` and/or ``"-x"``."""


@dataclasses.dataclass(frozen=True)
class Layout:
    cube_xy: np.ndarray  # (2,)
    obstacle_xy: np.ndarray  # (n, 2)


class LayoutError(ConfigError):
    """A layout violates the task's placement rules; the message says which rule and which box."""


def _footprint_gap(center_a: np.ndarray, half_a: np.ndarray, center_b: np.ndarray,
                   half_b: np.ndarray) -> float:
    """Signed gap between two axis-aligned rectangles (negative when they overlap), m."""
    sep = np.abs(center_a - center_b) - (half_a + half_b)
    if np.all(sep < 0):
        return float(sep.max())
    return float(np.linalg.norm(np.maximum(sep, 0.0)))


def free_lanes(layout: Layout, cube_half: float, obstacle_half: np.ndarray, table: TableTop,
               rules: LaneRules) -> list[str]:
    """The directions in ``rules.lane_directions`` whose lane is free of obstacles.

    The lane toward ``+x`` is the strip |y - cube_y| <= lane_width / 2 from ``approach_room``
    behind the cube's face (room for the pusher) to the table edge; likewise for ``-x``.
    """
    half_w = rules.lane_width / 2
    cx, cy = layout.cube_xy
    free = []
    for direction in rules.lane_directions:
        sign = 1.0 if direction == "+x" else -1.0
        x_from, x_to = cx - sign * (cube_half + rules.approach_room), sign * table.half_extent[0]
        lo, hi = min(x_from, x_to), max(x_from, x_to)
        blocked = False
        for ox, oy in layout.obstacle_xy:
            if (ox + obstacle_half[0] > lo and ox - obstacle_half[0] < hi
                    and oy + obstacle_half[1] > cy - half_w and oy - obstacle_half[1] < cy + half_w):
                blocked = True
                break
        if not blocked:
            free.append(direction)
    return free


def validate_layout(layout: Layout, table: TableTop, cube: CubeSize, obstacles: ObstacleSize,
                    rules: LaneRules) -> None:
    """Raise :class:`LayoutError` naming the first rule that ``layout`` breaks."""
    cube_half = np.full(2, cube.size / 2)
    obstacle_half = np.asarray(obstacles.size[:2]) / 2
    table_half = np.asarray(table.half_extent)
    boxes = [("cube", layout.cube_xy, cube_half)] + [
        (f"obstacle {i}", xy, obstacle_half) for i, xy in enumerate(layout.obstacle_xy)]
    for name, xy, half in boxes:
        if np.any(np.abs(xy) + half > table_half):
            raise LayoutError(f"{name} at {np.round(xy, 4).tolist()} is not fully on the table "
                              f"(half-extent {table_half.tolist()})")
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            gap = _footprint_gap(boxes[i][1], boxes[i][2], boxes[j][1], boxes[j][2])
            if gap < rules.min_gap:
                what = "overlaps" if gap < 0 else "is closer than min_gap to"
                raise LayoutError(f"{boxes[j][0]} at {np.round(boxes[j][1], 4).tolist()} {what} "
                                  f"{boxes[i][0]} at {np.round(boxes[i][1], 4).tolist()} "
                                  f"(gap {gap:.4f} m, min_gap {rules.min_gap} m)")
    if not free_lanes(layout, cube.size / 2, obstacle_half, table, rules):
        raise LayoutError(f"no free lane {rules.lane_width} m wide from the cube to a reachable edge "
                          f"({list(rules.lane_directions)}) in layout {layout.obstacle_xy.tolist()}")


__all__ = ["CubeSize", "LaneRules", "Layout", "LayoutError", "ObstacleSize", "TableTop", "free_lanes",
           "validate_layout"]
