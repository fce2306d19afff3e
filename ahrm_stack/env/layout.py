"""Layouts of the cube and the obstacles on the table: seeded sampling, lane clearance and the
choice of lane.

All positions are (x, y) centres on the table top, in metres, in the world frame. What makes a
layout valid (every box on the table, no two footprints closer than ``min_gap``, a free lane at
least ``lane_width`` wide from behind the cube to a reachable table edge; spec §1) is
:mod:`ahrm_stack.config.layout_rules`, whose names are re-exported here.
"""

from __future__ import annotations

import math

import numpy as np

from ahrm_stack.config import CubeConfig, LayoutConfig, ObstacleConfig, TableConfig
from ahrm_stack.config.layout_rules import Layout, LayoutError, free_lanes, validate_layout


def lane_clearance(cube_xy: np.ndarray, obstacle_xy: np.ndarray, cube_half: float,
                   obstacle_half: np.ndarray, table: TableConfig, rules: LayoutConfig,
                   clip: tuple[float, float]) -> np.ndarray:
    """Clearance (m) of each lane of ``rules.lane_directions``: the smallest signed gap between an
    obstacle footprint and the strip the cube sweeps — its width, from ``approach_room`` behind
    its back face to the table edge — clipped to ``clip`` (m; ``task.observation.lane_clip``;
    negative: blocked).

    Positions (x, y) in m, world frame. An observation feature: the same geometry as
    :func:`free_lanes`, measured instead of thresholded."""
    # Per element on Python floats, the same IEEE operations as the vectorised form (a few lanes
    # and obstacles: cheaper than NumPy's per-call overhead; the observation computes it per step).
    cx, cy = float(cube_xy[0]), float(cube_xy[1])
    obstacles = np.asarray(obstacle_xy, dtype=float).reshape(-1, 2).tolist()
    halves = np.broadcast_to(np.asarray(obstacle_half, dtype=float), (len(obstacles), 2)).tolist()
    low, high = clip
    out = np.empty(len(rules.lane_directions))
    for i, direction in enumerate(rules.lane_directions):
        sign = 1.0 if direction == "+x" else -1.0
        near, edge = cx - sign * (cube_half + rules.approach_room), sign * table.half_extent[0]
        lo, hi = (near, edge) if near <= edge else (edge, near)
        center, half = (lo + hi) / 2, (hi - lo) / 2
        gap = math.inf if obstacles else high
        for (ox, oy), (hx, hy) in zip(obstacles, halves):
            sx, sy = abs(ox - center) - (half + hx), abs(oy - cy) - (cube_half + hy)
            if sx < 0 and sy < 0:  # overlapping: the negative penetration
                g = sx if sx >= sy else sy
            else:
                mx, my = (sx if sx > 0.0 else 0.0), (sy if sy > 0.0 else 0.0)
                g = math.sqrt(mx * mx + my * my)
            gap = g if g < gap else gap
        out[i] = min(max(gap, low), high)
    return out


def choose_lane(layout: Layout, tip_xy: np.ndarray, cube_half: float, obstacle_half: np.ndarray,
                table: TableConfig, rules: LayoutConfig) -> int:
    """The lane to push the cube along: its index in ``rules.lane_directions``.

    Of the free lanes (:func:`free_lanes`; all lanes when none is), the one whose strip leaves
    the most room to the obstacles (:func:`lane_clearance`, unclipped); ties to 1 mm go to the
    lane whose push starts on the tip's side of the cube (nearer the tip). Positions (x, y) in m,
    world frame. The scripted controller plans its episode with it, and the observation's
    ``lane_choice`` feature is it, so that a learner sees the decision its teacher made."""
    free = free_lanes(layout, cube_half, obstacle_half, table, rules)
    room = lane_clearance(layout.cube_xy, layout.obstacle_xy, cube_half, obstacle_half, table, rules,
                          (-np.inf, np.inf))
    best: tuple[tuple[float, float], int] | None = None
    for i, direction in enumerate(rules.lane_directions):
        if free and direction not in free:
            continue
        sign = 1.0 if direction == "+x" else -1.0
        start = layout.cube_xy - np.array([sign * (cube_half + rules.approach_room), 0.0])
        key = (round(float(room[i]), 3), -float(np.linalg.norm(start - tip_xy)))
        if best is None or key > best[0]:
            best = (key, i)
    assert best is not None  # lane_directions is never empty (config check)
    return best[1]


class LayoutSampler:
    """Seeded per-episode layouts: the fixed layout with cube jitter (``mode: fixed``), or the cube
    uniform in ``rules.cube_region`` with random obstacle positions around it (``mode: random``).

    ``sample(rng)`` always returns a layout that passes :func:`validate_layout`. The fixed layout is
    checked at construction only when it is used (``mode: fixed``): a random-mode task with a moved
    cube does not need the unused fixed layout to fit around it.
    """

    def __init__(self, table: TableConfig, cube: CubeConfig, obstacles: ObstacleConfig,
                 rules: LayoutConfig) -> None:
        self.table, self.cube, self.obstacles, self.rules = table, cube, obstacles, rules
        self.num_obstacles = len(obstacles.fixed_layout)
        fixed = Layout(np.asarray(cube.position, float), np.asarray(obstacles.fixed_layout, float).reshape(-1, 2))
        if rules.mode == "fixed":
            validate_layout(fixed, table, cube, obstacles, rules)  # fail at start-up, not mid-training
        else:
            self._check_cube_region()
        self.fixed = fixed

    def _check_cube_region(self) -> None:
        """The cube region's corners must hold the whole cube on the table (else LayoutError)."""
        half = self.cube.size / 2
        for axis, (lo, hi) in enumerate(self.rules.cube_region):
            edge = self.table.half_extent[axis]
            if lo - half < -edge or hi + half > edge:
                raise LayoutError(f"task.layout.cube_region {'xy'[axis]} range [{lo}, {hi}] puts the cube "
                                  f"(half-size {half} m) off the table (half-extent {edge} m)")

    def sample(self, rng: np.random.RandomState) -> Layout:
        if self.rules.mode == "fixed":
            cube_xy = np.asarray(self.cube.position, float) + rng.uniform(-1, 1, 2) * self.cube.jitter
            layout = Layout(cube_xy, self.fixed.obstacle_xy.copy())
            validate_layout(layout, self.table, self.cube, self.obstacles, self.rules)
            return layout
        lo, hi = self.rules.radial_range
        (x_lo, x_hi), (y_lo, y_hi) = self.rules.cube_region
        for attempt in range(self.rules.max_tries):
            if attempt % self.rules.obstacle_draws_per_cube == 0:  # a near-uniform cube
                cube_xy = np.array([rng.uniform(x_lo, x_hi), rng.uniform(y_lo, y_hi)])
            radius = rng.uniform(lo, hi, self.num_obstacles)
            angle = rng.uniform(0, 2 * np.pi, self.num_obstacles)
            xy = cube_xy + np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
            layout = Layout(cube_xy, xy)
            try:
                validate_layout(layout, self.table, self.cube, self.obstacles, self.rules)
            except LayoutError:
                continue
            return layout
        raise LayoutError(f"no valid random layout in {self.rules.max_tries} tries; widen "
                          "layout.radial_range or reduce the number of obstacles")


__all__ = ["Layout", "LayoutError", "LayoutSampler", "choose_lane", "free_lanes", "lane_clearance",
           "validate_layout"]
