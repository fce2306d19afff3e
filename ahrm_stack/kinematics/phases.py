"""Phase geometry (spec §2): phase k and boundary distance x of the pusher.

Pure functions over plain numbers; no simulator. All lengths are metres and all
poses are in the world frame (z up). The table top is the plane z = table_height.

Regions (axis-aligned boxes):

* ``B_target``: ``target_half_width`` horizontally around the target centre,
  from the table top up to ``target_height`` above it.
* ``B_obstacles``: the AABB of all obstacles grown horizontally by
  ``obstacle_margin``, from the table top up to ``obstacle_height`` above it.

The pusher E is *in* a region when its signed distance to it is <= 0. Phase 3
(manipulate) if E is in B_target, else 2 (pre-manipulate) if E is in
B_obstacles, else 1 (approach). x is the signed distance to the next phase's
region: B_obstacles in phase 1, B_target in phases 2 and 3.

Distances: the pusher's signed distance to a region is computed exactly by
:mod:`ahrm_stack.kinematics.cylinder_box` (closed form when upright, a certified fast path and
a reference routine when tilted); the value types are in :mod:`ahrm_stack.kinematics.shapes`.

The entry point is :func:`phase_geometry` (phase k, x and the clipped region distances in one
pass): what the task step (and deploy, through it) calls. :func:`phase_and_x`, :func:`region_distances` and
:func:`phase_from_distances` are the definition above written out directly; the tests check
``phase_geometry`` against them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ahrm_stack.kinematics.cylinder_box import (
    _cyl_data,
    _general_distance,
    _point_box_signed_distance,
    _tilt_sine,
    _upright_distance,
)
from ahrm_stack.kinematics.cylinder_box import UPRIGHT_TOL, cylinder_box_distance
from ahrm_stack.kinematics.shapes import Bounds, Box, Cylinder, _as_array, _as_scalar, _require_positive
from ahrm_stack.names import PHASE_NAMES

# Kept importable from here for older call sites (the distances now live in cylinder_box).
from ahrm_stack.kinematics.cylinder_box import POLISH_TOL as POLISH_TOL
from ahrm_stack.kinematics.cylinder_box import _general_cylinder_box_distance as _general_cylinder_box_distance
from ahrm_stack.kinematics.cylinder_box import upright_cylinder_box_distance as upright_cylinder_box_distance
from ahrm_stack.kinematics.shapes import ROTATION_TOL as ROTATION_TOL

__all__ = [
    "Box",
    "Cylinder",
    "RegionParams",
    "PhaseScene",
    "PHASE_NAMES",
    "target_region",
    "obstacle_region",
    "phase_geometry",
    "phase_and_x",
    "region_distances",
    "phase_from_distances",
]


# --------------------------------------------------------------------------- scene


@dataclass(frozen=True)
class RegionParams:
    """Region sizes in metres (the spec defaults live in the config, not here).

    ``target_half_width`` > 0: horizontal half-size of B_target around the target centre.
    ``target_height`` > 0: B_target top above the table top.
    ``obstacle_margin`` >= 0: horizontal growth of the obstacles' bounding box.
    ``obstacle_height`` > 0: B_obstacles top above the table top.
    """

    target_half_width: float
    target_height: float
    obstacle_margin: float
    obstacle_height: float

    def __post_init__(self) -> None:
        for name in ("target_half_width", "target_height", "obstacle_height"):
            object.__setattr__(self, name, _as_scalar(name, getattr(self, name), positive=True))
        object.__setattr__(
            self, "obstacle_margin", _as_scalar("obstacle_margin", self.obstacle_margin, nonnegative=True)
        )


@dataclass(frozen=True, eq=False)
class PhaseScene:
    """Scene for phase computation, world frame, metres.

    ``table_height``: z of the table top; ``target_center`` (3,) (only x, y are used);
    ``obstacle_centers`` / ``obstacle_half_sizes`` (n,3), n >= 1, half sizes > 0.
    The region bounds are computed once here.
    """

    table_height: float
    target_center: np.ndarray
    obstacle_centers: np.ndarray
    obstacle_half_sizes: np.ndarray
    params: RegionParams

    def __post_init__(self) -> None:
        z0 = _as_scalar("table_height", self.table_height)
        object.__setattr__(self, "table_height", z0)
        target = _as_array("target_center", self.target_center, (3,))
        object.__setattr__(self, "target_center", target)
        centers = _as_array("obstacle_centers", self.obstacle_centers, (-1, 3))
        halves = _as_array("obstacle_half_sizes", self.obstacle_half_sizes, (-1, 3))
        if centers.shape[0] == 0:
            raise ValueError("obstacle_centers must hold at least one obstacle, got shape (0, 3)")
        if halves.shape != centers.shape:
            raise ValueError(
                f"obstacle_half_sizes must have the same shape as obstacle_centers {centers.shape}, got {halves.shape}"
            )
        _require_positive("obstacle_half_sizes", halves)
        object.__setattr__(self, "obstacle_centers", centers)
        object.__setattr__(self, "obstacle_half_sizes", halves)
        p = self.params
        if not isinstance(p, RegionParams):
            raise ValueError(f"params must be a RegionParams, got {type(p).__name__}")

        self._set_bounds()

    def _set_bounds(self) -> None:
        z0, p = self.table_height, self.params
        tx, ty, _ = self.target_center.tolist()
        w = p.target_half_width
        object.__setattr__(self, "_target_bounds", (tx - w, ty - w, z0, tx + w, ty + w, z0 + p.target_height))
        m = p.obstacle_margin
        # plain floats: faster than numpy for a few obstacles
        c, hs = self.obstacle_centers.tolist(), self.obstacle_half_sizes.tolist()
        xlo = min([ci[0] - hi[0] for ci, hi in zip(c, hs)])
        ylo = min([ci[1] - hi[1] for ci, hi in zip(c, hs)])
        xhi = max([ci[0] + hi[0] for ci, hi in zip(c, hs)])
        yhi = max([ci[1] + hi[1] for ci, hi in zip(c, hs)])
        object.__setattr__(
            self, "_obstacle_bounds", (xlo - m, ylo - m, z0, xhi + m, yhi + m, z0 + p.obstacle_height)
        )

    @classmethod
    def unchecked(cls, table_height: float, target_center: np.ndarray, obstacle_centers: np.ndarray,
                  obstacle_half_sizes: np.ndarray, params: RegionParams) -> "PhaseScene":
        """The per-control-step constructor, for positions read from the simulator and sizes from a
        validated config: shapes and signs are not checked (~3 us instead of ~16 us); non-finite
        positions still raise ValueError. ``obstacle_half_sizes`` is kept as given (not copied)."""
        target = np.array(target_center, dtype=np.float64)
        centers = np.array(obstacle_centers, dtype=np.float64)
        if not math.isfinite(float(target.sum()) + float(centers.sum())):
            raise ValueError(f"target_center / obstacle_centers must be finite, got {target.tolist()}, "
                             f"{centers.tolist()}")
        scene = object.__new__(cls)
        for name, value in (("table_height", float(table_height)), ("target_center", target),
                            ("obstacle_centers", centers), ("obstacle_half_sizes", obstacle_half_sizes),
                            ("params", params)):
            object.__setattr__(scene, name, value)
        scene._set_bounds()
        return scene


def _box_from_bounds(b: Bounds) -> Box:
    xlo, ylo, zlo, xhi, yhi, zhi = b
    return Box(
        np.array([(xlo + xhi) / 2, (ylo + yhi) / 2, (zlo + zhi) / 2]),
        np.array([(xhi - xlo) / 2, (yhi - ylo) / 2, (zhi - zlo) / 2]),
    )


def target_region(scene: PhaseScene) -> Box:
    """B_target (world frame, m): target centre ± target_half_width in x, y; table top to +target_height in z."""
    return _box_from_bounds(scene._target_bounds)  # type: ignore[attr-defined]


def obstacle_region(scene: PhaseScene) -> Box:
    """B_obstacles (world frame, m): obstacles' AABB grown by obstacle_margin in x, y; table top to +obstacle_height."""
    return _box_from_bounds(scene._obstacle_bounds)  # type: ignore[attr-defined]


# --------------------------------------------------------------------------- phases


def phase_and_x(scene: PhaseScene, pusher: Cylinder) -> tuple[int, float]:
    """Phase k in {1, 2, 3} and boundary distance x (m) of the pusher (spec §2).

    k = 3 if the pusher is in B_target (signed distance <= 0), x = that distance (<= 0);
    k = 2 if in B_obstacles, x = signed distance to B_target (> 0);
    k = 1 otherwise, x = signed distance to B_obstacles (> 0).
    """
    tb: Bounds = scene._target_bounds  # type: ignore[attr-defined]
    ob: Bounds = scene._obstacle_bounds  # type: ignore[attr-defined]
    if _tilt_sine(pusher) <= UPRIGHT_TOL:
        cx, cy, cz = pusher.center.tolist()
        r, h = pusher.radius, pusher.half_length
        d_target = _upright_distance(cx, cy, cz, r, h, tb)
        if d_target <= 0.0:
            return 3, d_target
        d_obstacles = _upright_distance(cx, cy, cz, r, h, ob)
    else:
        cd = _cyl_data(pusher)
        d_target = _general_distance(cd, tb)
        if d_target <= 0.0:
            return 3, d_target
        d_obstacles = _general_distance(cd, ob)
    if d_obstacles <= 0.0:
        return 2, d_target
    return 1, d_obstacles


class _RegionDistance:
    """The pusher's signed distance to one region, computed exactly only when needed.

    Cheap bounds first: with c the cylinder's centre and R = sqrt(r^2 + h^2) the radius of its
    bounding ball, sd(c) - R <= d <= sd(c) (the ball contains the cylinder, the cylinder contains
    c). ``exact()`` runs the closed form (upright) or the general path (tilted) once, on demand.
    """

    def __init__(self, pusher: Cylinder, cd: tuple | None, bounds: Bounds) -> None:
        """``cd``: the general path's cylinder data (tilted), or None (upright: closed form)."""
        self.pusher, self.cd, self.bounds = pusher, cd, bounds
        self.upper = _point_box_signed_distance(tuple(pusher.center.tolist()), bounds)
        self.lower = self.upper - math.hypot(pusher.radius, pusher.half_length)
        self._exact: float | None = None

    def exact(self) -> float:
        if self._exact is None:
            if self.cd is None:
                cx, cy, cz = self.pusher.center.tolist()
                self._exact = _upright_distance(cx, cy, cz, self.pusher.radius,
                                                self.pusher.half_length, self.bounds)
            else:
                self._exact = _general_distance(self.cd, self.bounds)
        return self._exact

    def inside(self) -> bool:
        """d <= 0, decided by the bounds where they suffice."""
        if self.upper <= 0.0:
            return True
        if self.lower > 0.0:
            return False
        return self.exact() <= 0.0

    def clipped(self, clip: float) -> float:
        """d clipped to [-clip, clip]: exact inside that band, saturated (by the bounds) beyond."""
        if self.lower >= clip:
            return clip
        if self.upper <= -clip:
            return -clip
        return min(max(self.exact(), -clip), clip)


def phase_geometry(scene: PhaseScene, pusher: Cylinder, clip: float) -> tuple[int, float, np.ndarray]:
    """Phase k, boundary distance x (m, exact) and the signed distances to (B_obstacles, B_target)
    clipped to [-clip, clip] (m; exact inside the band), in one pass.

    Equal to :func:`phase_and_x` for (k, x); at most one exact distance query is run when the
    pusher is away from the other region's boundary (the bounding-ball bounds decide the rest),
    which is what keeps the per-step cost low. The clipped distances are what a reward blend
    across the boundaries needs (its weight saturates beyond the blend band <= clip).
    """
    cd = None if _tilt_sine(pusher) <= UPRIGHT_TOL else _cyl_data(pusher)
    target = _RegionDistance(pusher, cd, scene._target_bounds)  # type: ignore[attr-defined]
    obstacles = _RegionDistance(pusher, cd, scene._obstacle_bounds)  # type: ignore[attr-defined]
    if target.inside():
        phase, x = 3, target.exact()
    elif obstacles.inside():
        phase, x = 2, target.exact()
    else:
        phase, x = 1, obstacles.exact()
    return phase, x, np.array([obstacles.clipped(clip), target.clipped(clip)])


def region_distances(scene: PhaseScene, pusher: Cylinder) -> np.ndarray:
    """Exact signed distances (m) of the pusher to (B_obstacles, B_target), as a (2,) array."""
    return np.array([cylinder_box_distance(pusher, obstacle_region(scene)),
                     cylinder_box_distance(pusher, target_region(scene))])


def phase_from_distances(d_obstacles: float, d_target: float) -> tuple[int, float]:
    """Phase k and boundary distance x (m) from the signed distances to the two regions (spec §2)."""
    if d_target <= 0.0:
        return 3, float(d_target)
    if d_obstacles <= 0.0:
        return 2, float(d_target)
    return 1, float(d_obstacles)
