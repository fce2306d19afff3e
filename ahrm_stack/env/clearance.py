"""Clearance of the cube and the pusher from the obstacles: the graded part of the avoid objective.

The spec's f1 sees only a touch. With ``task.rewards.avoid_margin`` > 0 the task also counts a step
as an avoid violation while the cube or the pusher is closer than the margin to any obstacle
(:func:`ahrm_stack.env.rewards.avoid_component`), so that a push which drifts towards an obstacle
is priced before it touches. This module measures that clearance.

All shapes are the simulator's: the cube and the obstacles are boxes (half sizes in m), the pusher a
solid cylinder (radius and half length, m), each placed by a world position (m) and a world-from-body
rotation matrix. Distances are coal's exact convex distances (GJK), signed: negative in
penetration. A pair whose bounding spheres are farther apart than ``reach`` is not asked (its
distance is at least the spheres' gap, returned in its place).
"""

from __future__ import annotations

import math
from typing import Sequence

import coal
import numpy as np

_REQUEST = coal.DistanceRequest()


class Clearance:
    """Smallest distance from the cube and the pusher to the obstacles.

    ``cube_half``: (3,) m; ``obstacle_half``: (n, 3) m; ``pusher_radius``, ``pusher_half_length``:
    m, the cylinder's axis is its local z axis. ``reach`` (m): pairs whose bounding spheres are
    farther apart than this are answered by that gap instead of coal (the caller asks only whether
    the clearance is below its margin, so ``reach`` = the margin loses nothing).
    """

    def __init__(self, cube_half: Sequence[float], obstacle_half: np.ndarray, pusher_radius: float,
                 pusher_half_length: float, reach: float) -> None:
        cube_size = 2.0 * np.asarray(cube_half, dtype=float)
        obstacle_half = np.asarray(obstacle_half, dtype=float).reshape(-1, 3)
        self.reach = float(reach)
        cube = coal.Box(*cube_size)
        pusher = coal.Cylinder(float(pusher_radius), 2.0 * float(pusher_half_length))
        obstacles = [coal.Box(*(2.0 * h)) for h in obstacle_half]
        self._cube_radius = float(np.linalg.norm(cube_size)) / 2.0
        self._pusher_radius = math.hypot(pusher_radius, pusher_half_length)
        self._obstacle_radius = np.linalg.norm(obstacle_half, axis=1)
        self._shapes = (cube, pusher, obstacles)  # ComputeDistance holds raw pointers: keep them alive
        self._cube_compute = [coal.ComputeDistance(cube, o) for o in obstacles]
        self._pusher_compute = [coal.ComputeDistance(pusher, o) for o in obstacles]
        self._a = coal.Transform3s()
        self._b = coal.Transform3s()
        self._result = coal.DistanceResult()

    def _pair(self, compute: coal.ComputeDistance, position_a: np.ndarray, rotation_a: np.ndarray,
              position_b: np.ndarray, rotation_b: np.ndarray) -> float:
        self._a.setTranslation(position_a)
        self._a.setRotation(rotation_a)
        self._b.setTranslation(position_b)
        self._b.setRotation(rotation_b)
        self._result.clear()  # a DistanceResult keeps the smallest distance it has seen
        return float(compute(self._a, self._b, _REQUEST, self._result))

    def distances(self, cube_position: np.ndarray, cube_rotation: np.ndarray,
                  obstacle_positions: np.ndarray, obstacle_rotations: np.ndarray,
                  pusher_center: np.ndarray | None = None,
                  pusher_rotation: np.ndarray | None = None) -> tuple[float, float]:
        """(cube, pusher) clearance: each one's smallest signed distance to any obstacle, m (world).

        ``obstacle_positions``: (n, 3); ``obstacle_rotations``: (n, 3, 3). Without a pusher pose the
        pusher's entry is ``inf``. A pair beyond ``reach`` counts as its bounding spheres' gap.
        """
        cube_best = pusher_best = math.inf
        cube_position = np.asarray(cube_position, dtype=float)
        for i, (position, rotation) in enumerate(zip(obstacle_positions, obstacle_rotations)):
            gap = float(np.linalg.norm(position - cube_position)) - self._cube_radius - self._obstacle_radius[i]
            if gap > self.reach:
                cube_best = min(cube_best, gap)
            else:
                cube_best = min(cube_best, self._pair(self._cube_compute[i], cube_position, cube_rotation,
                                                      position, rotation))
            if pusher_center is None or pusher_rotation is None:
                continue
            gap = (float(np.linalg.norm(position - pusher_center)) - self._pusher_radius
                   - self._obstacle_radius[i])
            if gap > self.reach:
                pusher_best = min(pusher_best, gap)
            else:
                pusher_best = min(pusher_best, self._pair(self._pusher_compute[i], pusher_center,
                                                          pusher_rotation, position, rotation))
        return cube_best, pusher_best
