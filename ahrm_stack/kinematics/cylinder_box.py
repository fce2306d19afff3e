"""Signed distance between a solid cylinder (the pusher) and an axis-aligned box, exactly.

All lengths are metres, all poses in the world frame (z up).

An upright pusher (axis parallel to z, either sign) uses an exact
closed form (spec §2). Any other pose uses ``_general_distance``, which computes the
same quantity as FCL's signed distance (distance when apart, minus the penetration
depth when overlapping) without calling python-fcl, because python-fcl 0.7 is not
reliable for this pair (measured on random and axis-aligned placements):

* separated: its GJK over-estimates, up to 0.067 m (0.134 m reported for 0.066 m);
* touching or within ~1e-9 m of touching: its EPA returns garbage (-0.062 m for 0) or
  throws a C++ ``std::logic_error`` that python-fcl does not catch: the process aborts;
* shallow overlaps with aligned features: returns ~0 for a 1e-4 m penetration.

Instead (the reference routine, ``_reference_distance``): separated -> alternating
projections, certified to POLISH_TOL by a support-function lower bound; overlapping /
touching -> signed distance = max over unit n of [min_box n.x - max_cylinder n.x],
maximised over the finite set of directions where that maximum can lie (plus a 1-D search
on three great circles). A fast path (``_fast_distance``, see "fast path" below) answers the
usual queries ~10x sooner with bounds certified to the same POLISH_TOL, and hands the rest
to the reference routine. The tests cross-check against python-fcl
(``tests/fcl_reference.py``) only on poses clear of touching.
"""

from __future__ import annotations

import math

import coal
import numpy as np

from ahrm_stack.kinematics.shapes import Bounds, Box, Cylinder

__all__ = [
    "UPRIGHT_TOL",
    "POLISH_TOL",
    "upright_cylinder_box_distance",
    "cylinder_box_distance",
]


UPRIGHT_TOL = 1e-6
"""Max sine of the angle between the pusher axis and z for the closed form.
Closed-form error is then <= half_length * 1e-6 + radius * 5e-13 m."""


POLISH_TOL = 1e-9
"""Certified gap (m) between upper and lower bound of a separated distance."""

_POLISH_MAX_ITERS = 100
_EDGE_SEARCH_AFTER = 10  # alternating-projection iterations before searching along an edge
_EDGE_SEARCH_ITERS = 80  # golden-section steps: shrinks the edge interval by 0.618**80 ~ 2e-17
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
_ARC_SAMPLES = 128  # coarse samples per great circle in _candidate_gap
_ARC_ZOOM_SAMPLES = 25  # samples per zoom step (window shrinks 12x per step)
_ARC_ZOOMS = 3  # final angular resolution ~ 2 pi / 128 / 12**3 ~ 3e-5 rad
_ARC_WINDOWS = 4  # zoom windows per great circle (distinct local maxima to follow)
_DEGENERATE = 1e-12  # |component| below which a direction counts as along/across the axis

# --------------------------------------------------------------------------- distances


def _tilt_sine(cyl: Cylinder) -> float:
    """Sine of the angle between the cylinder axis and the world z axis (either sign)."""
    r = cyl.rotation
    return math.hypot(float(r[0, 2]), float(r[1, 2]))


def _upright_distance(cx: float, cy: float, cz: float, r: float, h: float, b: Bounds) -> float:
    """Exact signed distance, upright cylinder vs AABB ``b`` (m). See spec §2."""
    xlo, ylo, zlo, xhi, yhi, zhi = b
    # Per-axis signed excess of the centre beyond the rectangle (<= 0 inside that slab).
    ex = max(xlo - cx, cx - xhi)
    ey = max(ylo - cy, cy - yhi)
    if ex > 0.0 or ey > 0.0:
        # Centre outside the rectangle: disc-rectangle signed distance = planar distance - r.
        sd_xy = math.hypot(max(ex, 0.0), max(ey, 0.0)) - r
    else:
        # Centre inside: separating shift = r + distance to the nearest edge (= -max(ex, ey)).
        sd_xy = max(ex, ey) - r
    # Signed gap between the z-intervals [cz-h, cz+h] and [zlo, zhi].
    sd_z = max(zlo - (cz + h), (cz - h) - zhi)
    if sd_xy > 0.0 or sd_z > 0.0:
        return math.hypot(max(sd_xy, 0.0), max(sd_z, 0.0))
    # Overlap: the smaller of the horizontal and vertical overlaps, negated (+0.0 turns -0.0 into 0.0).
    return max(sd_xy, sd_z) + 0.0


def upright_cylinder_box_distance(cyl: Cylinder, box: Box) -> float:
    """Exact signed distance (m) between an upright cylinder and an AABB, world frame.

    Positive when apart, 0 when touching, minus the penetration depth when overlapping.
    Raises ValueError unless the axis is parallel to z (either sign) within UPRIGHT_TOL.
    """
    s = _tilt_sine(cyl)
    if s > UPRIGHT_TOL:
        raise ValueError(f"cylinder axis must be parallel to z within {UPRIGHT_TOL}, got tilt sine {s:.3g}")
    cx, cy, cz = cyl.center.tolist()
    return _upright_distance(cx, cy, cz, cyl.radius, cyl.half_length, box.bounds())


def _support_gap(n: tuple[float, float, float], cyl: tuple, b: Bounds) -> float:
    """min over box of n.p minus max over cylinder of n.p, for unit n: a lower bound on the signed distance."""
    nx, ny, nz = n
    (cx, cy, cz), (ax, ay, az), r, h = cyl[0], cyl[1], cyl[2], cyl[3]
    xlo, ylo, zlo, xhi, yhi, zhi = b
    box_min = nx * (xlo if nx > 0 else xhi) + ny * (ylo if ny > 0 else yhi) + nz * (zlo if nz > 0 else zhi)
    na = nx * ax + ny * ay + nz * az
    # |n - (n.a) a| rather than sqrt(1 - na^2): no cancellation when n is along the axis.
    across = math.sqrt((nx - na * ax) ** 2 + (ny - na * ay) ** 2 + (nz - na * az) ** 2)
    cyl_max = nx * cx + ny * cy + nz * cz + h * abs(na) + r * across
    return box_min - cyl_max


def _project_cylinder(p: tuple[float, float, float], cyl: tuple) -> tuple[float, float, float]:
    """Closest point of the solid cylinder to p (world frame)."""
    (cx, cy, cz), rot, r, h = cyl[0], cyl[4], cyl[2], cyl[3]
    (a, b, c), (d, e, f), (g, hh, i) = rot
    dx, dy, dz = p[0] - cx, p[1] - cy, p[2] - cz
    u, v, w = a * dx + d * dy + g * dz, b * dx + e * dy + hh * dz, c * dx + f * dy + i * dz  # R^T (p - c)
    w = min(max(w, -h), h)
    rho = math.hypot(u, v)
    if rho > r:
        u, v = u * (r / rho), v * (r / rho)
    return (cx + a * u + b * v + c * w, cy + d * u + e * v + f * w, cz + g * u + hh * v + i * w)


def _extreme_point(n: tuple[float, float, float], p: tuple[float, float, float],
                   cyl: tuple) -> tuple[float, float, float]:
    """Point of the cylinder maximising n.x (unit n); where that set is a segment or a disc, its point nearest p."""
    (cx, cy, cz), (ax, ay, az), r, h = cyl[0], cyl[1], cyl[2], cyl[3]
    na = n[0] * ax + n[1] * ay + n[2] * az
    ux, uy, uz = n[0] - na * ax, n[1] - na * ay, n[2] - na * az  # part of n across the axis
    un = math.sqrt(ux * ux + uy * uy + uz * uz)
    if un <= _DEGENERATE:  # n along the axis: the whole cap disc is extreme
        t = h if na > 0.0 else -h
        ox, oy, oz = cx + t * ax, cy + t * ay, cz + t * az
        dx, dy, dz = p[0] - ox, p[1] - oy, p[2] - oz
        da = dx * ax + dy * ay + dz * az
        dx, dy, dz = dx - da * ax, dy - da * ay, dz - da * az
        dn = math.sqrt(dx * dx + dy * dy + dz * dz)
        k = 1.0 if dn <= r else r / dn
        return (ox + k * dx, oy + k * dy, oz + k * dz)
    if abs(na) <= _DEGENERATE:  # n across the axis: a side segment is extreme
        t = min(max((p[0] - cx) * ax + (p[1] - cy) * ay + (p[2] - cz) * az, -h), h)
    else:
        t = h if na > 0.0 else -h
    k = r / un
    return (cx + t * ax + k * ux, cy + t * ay + k * uy, cz + t * az + k * uz)


def _edge_minimiser(q: tuple[float, float, float], axis: int, b: Bounds, cyl: tuple) -> tuple[float, float, float]:
    """Point of the box edge through q (running along ``axis``) nearest the cylinder (golden-section search)."""
    lo, hi = b[axis], b[axis + 3]

    def point(t: float) -> tuple[float, float, float]:
        e = list(q)
        e[axis] = t
        return (e[0], e[1], e[2])

    def f(t: float) -> float:  # distance from the edge point to the cylinder: convex in t
        e = point(t)
        return math.dist(e, _project_cylinder(e, cyl))

    t1, t2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    f1, f2 = f(t1), f(t2)
    for _ in range(_EDGE_SEARCH_ITERS):
        if f1 <= f2:
            hi, t2, f2 = t2, t1, f1
            t1 = hi - _GOLDEN * (hi - lo)
            f1 = f(t1)
        else:
            lo, t1, f1 = t1, t2, f2
            t2 = lo + _GOLDEN * (hi - lo)
            f2 = f(t2)
    return point(t1 if f1 <= f2 else t2)


def _clamp(p: tuple[float, float, float], b: Bounds) -> tuple[float, float, float]:
    """Closest point of the box to p."""
    return (min(max(p[0], b[0]), b[3]), min(max(p[1], b[1]), b[4]), min(max(p[2], b[2]), b[5]))


def _separate(cd: tuple, b: Bounds) -> tuple[float, float]:
    """Bounds (upper, lower) on the signed distance by alternating projections, m.

    Starts from the box point nearest the cylinder centre. Every iterate is a genuine
    (cylinder point p, box point q) pair, so upper = min |p - q| >= max(sd, 0); the support gap
    along p -> q gives lower <= sd. When q lies on one box face the face normal is tried
    directly (exact for face contacts; otherwise q jumps to the face point nearest the
    cylinder's extreme point); when q crawls along a box edge, a 1-D search along the edge
    jumps to its end. Stops when upper - lower <= POLISH_TOL, when a common point is found
    (upper <= POLISH_TOL: the sets touch or overlap), or after _POLISH_MAX_ITERS.
    """
    lo, hi = b[:3], b[3:]
    q = _clamp(cd[0], b)
    upper = math.inf
    lower = -math.inf
    edge_done = False
    for i in range(_POLISH_MAX_ITERS):
        p = _project_cylinder(q, cd)
        q = _clamp(p, b)
        gx, gy, gz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
        g = math.sqrt(gx * gx + gy * gy + gz * gz)
        upper = min(upper, g)
        if g <= POLISH_TOL:  # common point: the sets touch or overlap
            break
        lower = max(lower, _support_gap((gx / g, gy / g, gz / g), cd, b))
        if upper - lower <= POLISH_TOL:
            break
        free = [k for k in range(3) if lo[k] <= p[k] <= hi[k]]
        if len(free) == 2:  # q on a face: try that face's normal
            k = 3 - free[0] - free[1]
            n = [0.0, 0.0, 0.0]
            n[k] = -1.0 if p[k] > hi[k] else 1.0  # from the cylinder towards the box
            s = _extreme_point((n[0], n[1], n[2]), p, cd)
            qs = _clamp(s, b)
            upper = min(upper, math.dist(s, qs))
            lower = max(lower, _support_gap((n[0], n[1], n[2]), cd, b))
            if upper - lower <= POLISH_TOL:
                break
            q = qs  # the face's nearest point lies beyond its boundary: jump there
        elif len(free) == 1 and not edge_done and i >= _EDGE_SEARCH_AFTER:  # crawling along an edge
            edge_done = True
            q = _edge_minimiser(q, free[0], b, cd)
    return upper, lower


def _support_gaps(n: np.ndarray, c: np.ndarray, a: np.ndarray, r: float, h: float, b: Bounds) -> np.ndarray:
    """_support_gap for each unit row of n (k,3)."""
    box_min = (n * np.where(n > 0.0, b[:3], b[3:])).sum(axis=1)
    na = n @ a
    across = np.sqrt(np.maximum(0.0, ((n - na[:, None] * a) ** 2).sum(axis=1)))
    return box_min - (n @ c + h * np.abs(na) + r * across)


_CIRCLE_J = np.array([[1], [2], [0]])  # great circle i is spanned by e_j, e_k
_CIRCLE_K = np.array([[2], [0], [1]])
_ARC_T = np.linspace(0.0, 2.0 * math.pi, _ARC_SAMPLES, endpoint=False)
_ARC_COS = np.broadcast_to(np.cos(_ARC_T), (3, _ARC_SAMPLES))
_ARC_SIN = np.broadcast_to(np.sin(_ARC_T), (3, _ARC_SAMPLES))
_ARC_DIRS: np.ndarray = np.zeros((3, _ARC_SAMPLES, 3))  # the same samples as unit vectors, circle by circle
for _i in range(3):
    _ARC_DIRS[_i, :, (_i + 1) % 3] = np.cos(_ARC_T)
    _ARC_DIRS[_i, :, (_i + 2) % 3] = np.sin(_ARC_T)
_ARC_DIRS = _ARC_DIRS.reshape(-1, 3)
# Zoom offsets per round: +-1 coarse step, shrinking by (ZOOM_SAMPLES - 1) / 2 each round.
_ZOOM_OFFSETS = [
    np.linspace(-1.0, 1.0, _ARC_ZOOM_SAMPLES) * (2.0 * math.pi / _ARC_SAMPLES) * (2.0 / (_ARC_ZOOM_SAMPLES - 1)) ** z
    for z in range(_ARC_ZOOMS)
]
_ZOOM_COS = [np.cos(d) for d in _ZOOM_OFFSETS]
_ZOOM_SIN = [np.sin(d) for d in _ZOOM_OFFSETS]


def _vertex_offsets(c: np.ndarray, a: np.ndarray, b: Bounds) -> tuple[np.ndarray, np.ndarray]:
    """The box's eight vertices minus the cylinder's centre ``c`` (8, 3), m, and those offsets
    across the unit axis ``a`` (their part perpendicular to it)."""
    w = np.array([[x, y, z] for x in (b[0], b[3]) for y in (b[1], b[4]) for z in (b[2], b[5])]) - c
    return w, w - np.outer(w @ a, a)


def _candidate_gap(cd: tuple, b: Bounds) -> float:
    """Max of the support gap over the directions where its maximum over the sphere can lie, m.

    The signed distance is the max over unit n of gap(n) = min_box n.x - max_cyl n.x (any n gives
    a lower bound). The gap is smooth except where a component of n is 0 (box features),
    n.a = 0 (cylinder side) or n = +-a (caps); its local maxima lie at: box face normals,
    +-a, +-(e_i x a) (edge vs side), the side's normals through box vertices, rim-to-vertex
    directions, or smooth maxima on the great circles n_i = 0 (box edge vs cap rim), which
    are found by sampling and zooming in (angle-addition, no trig per call).
    """
    c, a, r, h = np.array(cd[0]), np.array(cd[1]), cd[2], cd[3]
    ax, ay, az = cd[1]
    w, side = _vertex_offsets(c, a, b)
    side_u = side / np.maximum(np.sqrt((side * side).sum(axis=1)), _DEGENERATE)[:, None]
    rim = np.vstack([w - h * a, w + h * a]) - r * np.vstack([side_u, side_u])  # nearest rim point -> vertex
    fixed = [
        [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],  # box faces
        [ax, ay, az], [0.0, ay, az], [ax, 0.0, az], [ax, ay, 0.0],  # caps, and a moved onto each circle n_i = 0
        [0.0, -az, ay], [az, 0.0, -ax], [-ay, ax, 0.0],  # e_i x a: box edge vs side
    ]  # fmt: skip
    dirs = np.vstack([fixed, side, rim])
    norm = np.sqrt((dirs * dirs).sum(axis=1))
    keep = norm > _DEGENERATE
    dirs = dirs[keep] / norm[keep, None]
    g = _support_gaps(np.vstack([dirs, -dirs, _ARC_DIRS]), c, a, r, h, b)  # one call for all
    best = float(g.max())
    g = g[-_ARC_DIRS.shape[0] :].reshape(3, _ARC_SAMPLES)  # coarse samples of the great circles
    # Great circles n_i = 0 (circle i spanned by e_j, e_k), where
    #   gap = co (lo_j | hi_j) + si (lo_k | hi_k) - n.c - h |n.a| - r sqrt(1 - (n.a)^2)
    # (the sqrt loses ~1e-8 relative only next to n = +-a, which is a fixed candidate).
    # Branch and bound: gap is Lipschitz in the angle with constant lip, so a sample of value g
    # bounds the gap within half a spacing s of it by g + lip * s / 2. Windows that cannot beat
    # the best value are dropped; the others are zoomed into around their best sample.
    lo, hi = np.asarray(b[:3]), np.asarray(b[3:])
    par = np.stack([lo[_CIRCLE_J], hi[_CIRCLE_J], lo[_CIRCLE_K], hi[_CIRCLE_K],
                    a[_CIRCLE_J], a[_CIRCLE_K], c[_CIRCLE_J], c[_CIRCLE_K]])
    lip = float(np.sqrt(((w * w).sum(axis=1)).max())) + math.hypot(r, h)

    def gaps(co: np.ndarray, si: np.ndarray, p: np.ndarray) -> np.ndarray:
        na = co * p[4] + si * p[5]
        return (
            co * np.where(co > 0.0, p[0], p[1])
            + si * np.where(si > 0.0, p[2], p[3])
            - co * p[6]
            - si * p[7]
            - h * np.abs(na)
            - r * np.sqrt(np.maximum(0.0, 1.0 - na * na))
        )

    spacing = 2.0 * math.pi / _ARC_SAMPLES
    # The _ARC_WINDOWS best sampled local maxima per circle (distinct peaks, not two samples of
    # one) seed the zoom windows.
    peak = (g >= np.roll(g, 1, axis=1)) & (g >= np.roll(g, -1, axis=1))
    order = np.argsort(-np.where(peak, g, -np.inf), axis=1)[:, :_ARC_WINDOWS]
    vals = np.take_along_axis(np.where(peak, g, -np.inf), order, axis=1)
    live = vals + lip * spacing / 2 > best
    circle = np.nonzero(live)[0]
    index = order[live]
    co, si = _ARC_COS[0, index][:, None], _ARC_SIN[0, index][:, None]
    for z in range(_ARC_ZOOMS):
        if circle.size == 0:
            break
        p = par[:, circle]
        co, si = co * _ZOOM_COS[z] - si * _ZOOM_SIN[z], si * _ZOOM_COS[z] + co * _ZOOM_SIN[z]  # angle + offsets
        g = gaps(co, si, p)
        k = g.argmax(axis=1)
        top = g[np.arange(circle.size), k]
        best = max(best, float(top.max()))
        spacing *= 2.0 / (_ARC_ZOOM_SAMPLES - 1)
        keep = top + lip * spacing / 2 > best
        circle, k = circle[keep], k[keep]
        co = co[keep, k][:, None]
        si = si[keep, k][:, None]
    return best


def _cyl_data(cyl: Cylinder) -> tuple:
    rot = cyl.rotation.tolist()
    return (tuple(cyl.center.tolist()), (rot[0][2], rot[1][2], rot[2][2]), cyl.radius, cyl.half_length, rot,
            cyl.rotation, cyl.center)


def _general_distance(cd: tuple, b: Bounds) -> float:
    """Signed distance (m), cylinder in any pose (data ``cd``) vs AABB ``b``.

    The fast path (:func:`_fast_distance`: coal's GJK/EPA for the direction, then exact
    polishing and a check) answers almost every query; when its check fails, the reference
    routine :func:`_reference_distance` does.
    """
    d = _fast_distance(cd, b)
    return _reference_distance(cd, b) if d is None else d


def _reference_distance(cd: tuple, b: Bounds) -> float:
    """Signed distance (m), the reference routine (slow, ~0.2 ms when overlapping).

    Separated: alternating projections, certified to POLISH_TOL by a support-gap lower bound.
    Touching, overlapping (a common point was found) or not certified within the iteration
    cap: the maximum support gap over the directions where it can peak (_candidate_gap),
    which is the signed distance (minus the penetration depth when overlapping).
    """
    return _settle(cd, b, *_separate(cd, b))


def _settle(cd: tuple, b: Bounds, upper: float, lower: float) -> float:
    """Signed distance from _separate's bounds, searching the candidate directions if needed."""
    if lower > 0.0 and upper - lower <= POLISH_TOL:
        return upper
    lower = max(lower, _candidate_gap(cd, b))
    return min(lower, 0.0) if upper <= POLISH_TOL else lower


# --------------------------------------------------------------------------- fast path
#
# The reference routine above costs ~0.2 ms when the pusher overlaps a region (the arc search of
# _candidate_gap), which is most control steps. The fast path answers the usual queries in a few
# microseconds with the same accuracy, and returns None (-> reference routine) otherwise. Every
# value it returns is certified by a lower and an upper bound within POLISH_TOL:
#
# * lower: the support gap G(n) = min_box n.x - max_cyl n.x of some unit n (any n gives a lower
#   bound; the signed distance is the max over n). G is smooth except on the great circles
#   n_i = 0 (box features), n.a = 0 (cylinder side) and at n = +-a (caps); candidates are the 14
#   crossings of those circles (box face normals, +-a, +-(e_i x a): closed forms) and the
#   direction coal reports, snapped to / polished on the features within FAST_SNAP of it
#   (Newton's method on a circle, closed forms elsewhere).
# * upper, apart: the distance of a genuine point pair (the box point nearest coal's box witness
#   and its projection on the cylinder): the reference routine's own certificate.
# * upper, overlapping: the signed distance of a segment inside the cylinder (the side's ruling
#   through the extreme point), exact by the segment-box zonotope's 12 facets: a smaller body is
#   never deeper. Tight when the pusher pokes into the box through one face or edge-on along its
#   side (nearly every overlap of the task). Otherwise a fatter inscribed body: a prism over a
#   polygon in the cap disc (box - prism is a zonotope, exact by its facets), with a geometric fan
#   of vertices around the touching point where the optimum is curved (a box edge against the cap
#   rim, a box vertex against the side).
# * directions when coal's is wrong or missing (its EPA failed): a search of the curved optima
#   (Newton on the great circles n_i = 0 from coarse samples; the box vertices against the side).
#   What none of this certifies goes to the reference routine (none of 3,471 random tilted
#   queries in benchmarks/bench_phases.py; 75 before the fan and the search).
#
# coal (the maintained successor of FCL, installed with Pinocchio; unlike python-fcl it does not
# abort near touching) is only a source of directions and witness points: its EPA can stop on a
# wrong face (measured: ~1% of random overlaps, more near axis-aligned poses), so its values are
# never returned. benchmarks/bench_phases.py compares the fast and the reference routine.

_COAL_FAILED = -1e300  # coal's EPA reports -DBL_MAX (with an arbitrary normal) when it fails

FAST_SNAP = 1e-4
"""Features (circles, crossings) within this distance of coal's direction are polished."""

_NEWTON_ITERS = 8
_COAL_REQUEST = coal.DistanceRequest()
_COAL_REQUEST.gjk_tolerance = 1e-10
_COAL_REQUEST.epa_tolerance = 1e-10
_COAL_REQUEST.epa_max_iterations = 256
_COAL_CYLINDERS: dict[tuple[float, float], coal.Cylinder] = {}
_COAL_BOXES: dict[tuple[float, float, float], coal.Box] = {}
# Reused per query (set, not allocated): the fast path is not thread-safe, like the env it serves.
_COAL_CYL_POSE = coal.Transform3s()
_COAL_BOX_POSE = coal.Transform3s()
_COAL_RESULT = coal.DistanceResult()


def _coal_query(cd: tuple, b: Bounds) -> tuple[float, np.ndarray, np.ndarray]:
    """coal's signed distance (m), unit direction cylinder -> box, and its witness point on the box."""
    key = (cd[2], cd[3])
    cyl = _COAL_CYLINDERS.get(key)
    if cyl is None:
        cyl = _COAL_CYLINDERS.setdefault(key, coal.Cylinder(cd[2], 2.0 * cd[3]))
    xlo, ylo, zlo, xhi, yhi, zhi = b
    size = (xhi - xlo, yhi - ylo, zhi - zlo)
    box = _COAL_BOXES.get(size)
    if box is None:
        if len(_COAL_BOXES) > 64:  # obstacle regions change when an obstacle moves
            _COAL_BOXES.clear()
        box = _COAL_BOXES.setdefault(size, coal.Box(*size))
    _COAL_CYL_POSE.setRotation(cd[5])
    _COAL_CYL_POSE.setTranslation(cd[6])
    _COAL_BOX_POSE.setTranslation(np.array([(xlo + xhi) * 0.5, (ylo + yhi) * 0.5, (zlo + zhi) * 0.5]))
    result = _COAL_RESULT
    result.clear()  # it keeps a running minimum otherwise
    d = coal.distance(cyl, _COAL_CYL_POSE, box, _COAL_BOX_POSE, _COAL_REQUEST, result)
    return float(d), result.normal, result.getNearestPoint2()


def _arc_newton(i: int, n0: tuple[float, float, float], cd: tuple, b: Bounds) -> tuple[float, float, float] | None:
    """Maximiser of the smooth support gap on the great circle n_i = 0 near n0 (Newton on the angle).

    On the circle (spanned by e_j, e_k) with the signs of n0: G = W.n - r sqrt(1 - (alpha.n)^2),
    W = (box vertex - cap centre) in (j, k), alpha = (a_j, a_k). None when G is not concave there.
    """
    j, k = (i + 1) % 3, (i + 2) % 3
    (cx, cy, cz), a, r, h = cd[0], cd[1], cd[2], cd[3]
    c = (cx, cy, cz)
    sa = h if n0[0] * a[0] + n0[1] * a[1] + n0[2] * a[2] > 0.0 else -h
    wj = (b[j] if n0[j] > 0.0 else b[j + 3]) - c[j] - sa * a[j]
    wk = (b[k] if n0[k] > 0.0 else b[k + 3]) - c[k] - sa * a[k]
    aj, ak = a[j], a[k]
    norm = math.hypot(n0[j], n0[k])
    co, si = n0[j] / norm, n0[k] / norm
    for _ in range(_NEWTON_ITERS):
        p = aj * co + ak * si
        dp = -aj * si + ak * co
        s2 = 1.0 - p * p
        if s2 <= 1e-12:
            return None
        s = math.sqrt(s2)
        g1 = -wj * si + wk * co + r * p * dp / s
        g2 = -(wj * co + wk * si) + r * ((dp * dp - p * p) / s + p * p * dp * dp / (s2 * s))
        if not g2 < 0.0:
            return None
        step = g1 / g2
        if abs(step) > 0.1:
            return None
        cs, ss = math.cos(step), math.sin(step)  # theta -= step
        co, si = co * cs + si * ss, si * cs - co * ss
        if abs(step) < 1e-13:
            break
    n = [0.0, 0.0, 0.0]
    n[j], n[k] = co, si
    return (n[0], n[1], n[2])


def _unit(x: float, y: float, z: float) -> tuple[float, float, float] | None:
    norm = math.sqrt(x * x + y * y + z * z)
    return None if norm <= _DEGENERATE else (x / norm, y / norm, z / norm)


def _polished_gap(n0: tuple[float, float, float], cd: tuple, b: Bounds) -> tuple[float, tuple[float, float, float]]:
    """The best support gap (a lower bound on the signed distance, m) and its direction, over n0 and the
    features near it."""
    ax, ay, az = cd[1]
    (cx, cy, cz), r, h = cd[0], cd[2], cd[3]
    nx, ny, nz = n0
    na = nx * ax + ny * ay + nz * az
    best, arg = _support_gap(n0, cd, b), n0
    near = [i for i in range(3) if abs(n0[i]) < FAST_SNAP]
    candidates: list[tuple[float, float, float] | None] = []
    if 1.0 - abs(na) < FAST_SNAP:  # a cap
        candidates.append((ax, ay, az) if na > 0.0 else (-ax, -ay, -az))
    if len(near) >= 2:  # a box face
        k = 3 - near[0] - near[1]
        e = [0.0, 0.0, 0.0]
        e[k] = 1.0 if n0[k] > 0.0 else -1.0
        candidates.append((e[0], e[1], e[2]))
    side = abs(na) < FAST_SNAP
    for i in near:
        if side:  # crossing of n_i = 0 and n.a = 0: +-(e_i x a)
            ex, ey, ez = [(0.0, -az, ay), (az, 0.0, -ax), (-ay, ax, 0.0)][i]
            sign = 1.0 if ex * nx + ey * ny + ez * nz > 0.0 else -1.0
            candidates.append(_unit(sign * ex, sign * ey, sign * ez))
        candidates.append(_arc_newton(i, n0, cd, b))  # box edge vs cap rim
    # Box vertex (by the signs of n0) against the cylinder.
    vx = (b[0] if nx > 0.0 else b[3]) - cx
    vy = (b[1] if ny > 0.0 else b[4]) - cy
    vz = (b[2] if nz > 0.0 else b[5]) - cz
    if side:  # the side: n along the vertex offset across the axis
        wa = vx * ax + vy * ay + vz * az
        candidates.append(_unit(vx - wa * ax, vy - wa * ay, vz - wa * az))
    else:  # inside a cell: from the nearest rim point to the vertex (apart only)
        t = h if na > 0.0 else -h
        wx, wy, wz = vx - t * ax, vy - t * ay, vz - t * az
        wa = wx * ax + wy * ay + wz * az
        ux, uy, uz = wx - wa * ax, wy - wa * ay, wz - wa * az
        un = math.sqrt(ux * ux + uy * uy + uz * uz)
        if un > r:
            k = r / un
            candidates.append(_unit(wx - k * ux, wy - k * uy, wz - k * uz))
    for n in candidates:
        if n is not None:
            g = _support_gap(n, cd, b)
            if g > best:
                best, arg = g, n
    return best, arg


def _crossing_gap(cd: tuple, b: Bounds, sides: bool = True) -> tuple[float, tuple[float, float, float]]:
    """Best support gap (m) and its direction over the 14 crossings of the circles: +-e_i (box
    faces), +-a (caps) and, with ``sides``, +-(e_i x a) (box edge vs side). Closed forms, no search."""
    (cx, cy, cz), (ax, ay, az), r, h = cd[0], cd[1], cd[2], cd[3]
    xlo, ylo, zlo, xhi, yhi, zhi = b
    ex = h * abs(ax) + r * math.sqrt(max(0.0, 1.0 - ax * ax))  # cylinder half extent along x
    ey = h * abs(ay) + r * math.sqrt(max(0.0, 1.0 - ay * ay))
    ez = h * abs(az) + r * math.sqrt(max(0.0, 1.0 - az * az))
    ac = ax * cx + ay * cy + az * cz
    amin = ax * (xlo if ax > 0.0 else xhi) + ay * (ylo if ay > 0.0 else yhi) + az * (zlo if az > 0.0 else zhi)
    amax = ax * (xhi if ax > 0.0 else xlo) + ay * (yhi if ay > 0.0 else ylo) + az * (zhi if az > 0.0 else zlo)
    values = (xlo - cx - ex, cx - ex - xhi, ylo - cy - ey, cy - ey - yhi, zlo - cz - ez, cz - ez - zhi,
              amin - ac - h, ac - h - amax)
    dirs = ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0),
            (0.0, 0.0, -1.0), (ax, ay, az), (-ax, -ay, -az))
    k = max(range(8), key=values.__getitem__)
    best, arg = values[k], dirs[k]
    if not sides:
        return best, arg
    for e in ((0.0, -az, ay), (az, 0.0, -ax), (-ay, ax, 0.0)):
        n = _unit(*e)
        if n is not None:
            for m in (n, (-n[0], -n[1], -n[2])):
                g = _support_gap(m, cd, b)
                if g > best:
                    best, arg = g, m
    return best, arg


def _segment_overlap(p0: tuple[float, float, float], p1: tuple[float, float, float], b: Bounds) -> float:
    """Max over the facet normals of (box - segment p0 p1) of min_box n.x - max_seg n.x, m.

    The Minkowski difference of the box and the segment is a zonotope whose 12 facet normals are
    +-e_i and +-(e_i x s), s = p1 - p0. When this is <= 0 the two overlap and it is their signed
    distance exactly (minus the depth: the distance from the origin to the nearest facet);
    when > 0 they are apart (a separating facet direction)."""
    xlo, ylo, zlo, xhi, yhi, zhi = b
    best = max(xlo - max(p0[0], p1[0]), min(p0[0], p1[0]) - xhi,
               ylo - max(p0[1], p1[1]), min(p0[1], p1[1]) - yhi,
               zlo - max(p0[2], p1[2]), min(p0[2], p1[2]) - zhi)
    sx, sy, sz = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    for e in ((0.0, -sz, sy), (sz, 0.0, -sx), (-sy, sx, 0.0)):
        n = _unit(*e)
        if n is None:
            continue
        nx, ny, nz = n  # n.s = 0: the segment's extent along n is the single value n.p0
        ns = nx * p0[0] + ny * p0[1] + nz * p0[2]
        lo_n = nx * (xlo if nx > 0 else xhi) + ny * (ylo if ny > 0 else yhi) + nz * (zlo if nz > 0 else zhi)
        hi_n = nx * (xhi if nx > 0 else xlo) + ny * (yhi if ny > 0 else ylo) + nz * (zhi if nz > 0 else zlo)
        best = max(best, lo_n - ns, ns - hi_n)
    return best


def _overlap_certified(lower: float, n: tuple[float, float, float], cd: tuple, b: Bounds) -> bool:
    """Whether ``lower`` = G(n), a lower bound on the signed distance, is within POLISH_TOL of it.

    Upper bound: the cylinder contains the ruling S of its side through its extreme point p in
    direction n (p and p -+ 2h a), and a smaller body's signed distance is not smaller:
    sd(box, cylinder) <= sd(box, S), exact for a segment (:func:`_segment_overlap`) when <= 0.
    The bounds meet when the pusher pokes into the box through one face (its usual overlap);
    a box edge against the cap rim (an optimum on a great circle) does not certify this way.
    """
    p = _extreme_point(n, cd[0], cd)
    (cx, cy, cz), (ax, ay, az), h = cd[0], cd[1], cd[3]
    t = (p[0] - cx) * ax + (p[1] - cy) * ay + (p[2] - cz) * az  # -h, h, or between on the side
    lo, hi = -h - t, h - t  # the ruling's ends, along the axis from p
    upper = _segment_overlap((p[0] + lo * ax, p[1] + lo * ay, p[2] + lo * az),
                             (p[0] + hi * ax, p[1] + hi * ay, p[2] + hi * az), b)
    return upper <= 0.0 and upper - lower <= POLISH_TOL


_CHORD = 1e-4  # rad: half the chord around n's extreme point (the rim bulges r * 5e-9 beyond it)
_PRISM_ROUNDS = 4  # polygon refinements of the prism certificate
_FAN_RATIO_MIN, _FAN_RATIO_MAX = 1.5, 8.0  # bounds on the fan's angle ratio (at most 24 vertices a side)


def _fan(t: float, lower: float, r: float) -> list[float]:
    """Angles (rad, mod pi) of extra polygon vertices around the disc angle ``t``: t +- _CHORD q^k up
    to pi/2, a geometric fan.

    Why it certifies a curved optimum (a box edge against the cap rim, a box vertex against the
    side): the inscribed ball of radius rho = -lower about the origin touches box - cylinder at the
    optimum, where that body curves with radius r (the rim's) about one direction and the ball with
    rho < r. At rim angle delta from the touching point the surface has fallen ~r delta^2 / 2 below
    the tangent plane, the ball ~r delta^2 (r / rho) / 2, so a chord between delta and q delta (sag
    ~r (q - 1)^2 delta^2 / 8) stays outside the ball when (q - 1)^2 < 4 (r / rho - 1); with a factor 4
    to spare, q = 1 + sqrt(r / rho - 1), kept within [_FAN_RATIO_MIN, _FAN_RATIO_MAX]; the refinement
    rounds of :func:`_prism_certified` mend what this estimate misses."""
    rho = -lower
    q = 1.0 + math.sqrt(r / rho - 1.0) if 0.0 < rho < r else (_FAN_RATIO_MAX if rho <= 0.0 else 0.0)
    q = min(max(q, _FAN_RATIO_MIN), _FAN_RATIO_MAX)
    out: list[float] = []
    d = _CHORD * q
    while d < math.pi / 2:
        out += ((t - d) % math.pi, (t + d) % math.pi)
        d *= q
    return out


def _prism_certified(lower: float, n: tuple[float, float, float], cd: tuple, b: Bounds, fan: bool = False) -> bool:
    """Like :func:`_overlap_certified`, with a fatter inner body: a prism over a polygon inscribed in
    the cap disc (times the axis segment). Its vertices: the disc's extreme points along n and along
    the three world axes (so its extents along n and the six box face normals equal the
    cylinder's), two at +-_CHORD around n's (an optimum of a box edge against the cap rim, where n
    is not a crossing, is then matched to ~r * _CHORD^2), with ``fan`` a geometric fan of vertices
    around n's (:func:`_fan`; for an n that is no crossing: the curved optima), then, for up to
    _PRISM_ROUNDS rounds, the extreme point along the prism's own worst facet normal (a
    cutting-plane refinement where the polygon was too coarse). A centrally symmetric polygon is a
    zonogon, so box - prism is a zonotope; its facet normals are the cross products g_i x g_j of its
    generators, and along each the signed distance is (|n.d| - sum_k |n.g_k|) / |n| (vectorised)."""
    (cx, cy, cz), (ax, ay, az), r, h, rot = cd[0], cd[1], cd[2], cd[3], cd[4]
    ex, ey = (rot[0][0], rot[1][0], rot[2][0]), (rot[0][1], rot[1][1], rot[2][1])  # disc plane basis

    def angle(w) -> float | None:  # of the disc's extreme point along w (mod pi: a diameter)
        u = w[0] * ex[0] + w[1] * ex[1] + w[2] * ex[2]
        v = w[0] * ey[0] + w[1] * ey[1] + w[2] * ey[2]
        return math.atan2(v, u) if u * u + v * v > 1e-18 else None

    angles = {t % math.pi for t in map(angle, ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))
              if t is not None}
    t = angle(n)
    if t is not None:
        angles.update((t % math.pi, (t - _CHORD) % math.pi, (t + _CHORD) % math.pi))
        if fan:
            angles.update(_fan(t, lower, r))
    if not angles:
        return False
    # Facet normals of box - prism, g_i x g_j over its generators (the box's half sizes along e_i,
    # h a, the polygon's half edges c_k, all in the disc plane), up to scale and duplicates: e_k
    # (box x box), e_i x a (box x axis), a (chord x chord), and per chord e_i x c_k and a x c_k:
    # 7 + 4 m normals for m chords, not (m + 4)(m + 3) / 2.
    fixed = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
                      [0.0, -az, ay], [az, 0.0, -ax], [-ay, ax, 0.0], [ax, ay, az]])
    maps = np.array([*_CROSS_E_T, [[0.0, az, -ay], [-az, 0.0, ax], [ay, -ax, 0.0]]])  # c @ maps[i]: e_i x c, a x c
    w0 = np.array([[(b[0] + b[3]) / 2 - cx, h * ax, (b[3] - b[0]) / 2, 0.0, 0.0],
                   [(b[1] + b[4]) / 2 - cy, h * ay, 0.0, (b[4] - b[1]) / 2, 0.0],
                   [(b[2] + b[5]) / 2 - cz, h * az, 0.0, 0.0, (b[5] - b[2]) / 2]])  # columns: d, the generators
    basis = np.array([ex, ey])  # (2, 3)
    for _ in range(_PRISM_ROUNDS):
        chords = _half_edges(sorted(angles), r, ex, ey, basis)
        normals = np.concatenate([fixed, (chords @ maps).reshape(-1, 3)])
        proj = np.abs(normals @ np.hstack([w0, chords.T]))  # |n.d|, then |n.g_k| for every generator
        norm = np.sqrt(np.einsum("ij,ij->i", normals, normals))
        value = (2.0 * proj[:, 0] - proj.sum(axis=1)) / np.maximum(norm, 1e-300)  # (|n.d| - sum |n.g_k|) / |n|
        value[norm <= 1e-15] = -np.inf
        k = int(value.argmax())
        upper = float(value[k])
        if upper > 0.0:
            return False
        if upper - lower <= POLISH_TOL:
            return True
        nk = normals[k]
        sign = 1.0 if float(nk @ w0[:, 0]) >= 0.0 else -1.0  # the facet side that attains the max
        worst = tuple((nk * (sign / norm[k])).tolist())  # refine the polygon where it is too coarse
        if _support_gap(worst, cd, b) > lower + POLISH_TOL:
            return False  # a better direction than n: lower is not the signed distance
        t = angle(worst)
        if t is None or t % math.pi in angles:
            return False
        angles.add(t % math.pi)
    return False


def _half_edges(angles: list[float], r: float, ex: tuple, ey: tuple, basis: np.ndarray) -> np.ndarray:
    """Half edges (m, 3) of the polygon with vertices r (cos t ex + sin t ey) at the sorted ``angles``
    in [0, pi) and their opposites (a centrally symmetric polygon: m generators). In plain Python
    for a few vertices (~4 us sooner than numpy's calls), vectorised for a fan."""
    if len(angles) > 12:
        ts = np.array(angles)
        verts = r * (np.stack([np.cos(ts), np.sin(ts)], axis=1) @ basis)  # (m, 3) on the disc's half circle
        return 0.5 * np.diff(np.vstack([verts, -verts[:1]]), axis=0)
    verts = [(r * (math.cos(t) * ex[0] + math.sin(t) * ey[0]), r * (math.cos(t) * ex[1] + math.sin(t) * ey[1]),
              r * (math.cos(t) * ex[2] + math.sin(t) * ey[2])) for t in angles]
    verts.append((-verts[0][0], -verts[0][1], -verts[0][2]))
    return np.array([((q[0] - p[0]) / 2, (q[1] - p[1]) / 2, (q[2] - p[2]) / 2) for p, q in zip(verts, verts[1:])])


_CROSS_E_T = [[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],  # c @ this = e_x x c
              [[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],  # e_y x c
              [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]]  # e_z x c


def _crossing_overlap(cd: tuple, b: Bounds) -> tuple[float | None, float, tuple[float, float, float]]:
    """(certified signed distance or None, best crossing gap, its direction) for an overlap: the
    box faces first (the usual answer, cheapest), then all 14 crossings, each certified by the
    ruling (the prism, dearer, is left to the caller: :func:`_fast_distance` tries it on the better
    of this direction and coal's)."""
    lower, n = _crossing_gap(cd, b, sides=False)
    if lower > 0.0:  # a positive support gap: apart (the side crossings cannot change that)
        return None, lower, n
    if _overlap_certified(lower, n, cd, b):
        return lower, lower, n
    lower, n = _crossing_gap(cd, b)
    if lower <= 0.0 and _overlap_certified(lower, n, cd, b):
        return lower, lower, n
    return None, lower, n


def _fast_distance(cd: tuple, b: Bounds) -> float | None:
    """Signed distance (m) by certified shortcuts; None when none applies (then the reference runs).

    Overlapping: the best crossing direction (a box face normal, usually) or, when better, the
    direction coal's EPA reports, polished, certified by :func:`_overlap_certified` or
    :func:`_prism_certified`; when neither certifies, the best direction of
    :func:`_searched_gap` (the curved optima), or the crossing's, with the prism's fan.
    Apart: coal's witness gives a genuine point pair (an upper bound) and its direction the support
    gap (a lower bound); certified when they agree to POLISH_TOL, the reference routine's
    criterion. coal's values themselves are never returned (its EPA can stop on a wrong face).
    """
    inside = _point_box_signed_distance(cd[0], b) <= 0.0  # the centre is in the box: overlapping
    value, lower, n = _crossing_overlap(cd, b)  # the best crossing (usually a box face): no coal needed
    if value is not None:
        return value
    if inside and lower <= 0.0 and _prism_certified(lower, n, cd, b):  # the usual deep overlap
        return lower
    d, normal, witness = _coal_query(cd, b)
    nx, ny, nz = normal.tolist()
    n0 = _unit(nx, ny, nz)
    if n0 is None or not math.isfinite(d) or d <= _COAL_FAILED:  # coal failed: its direction is noise;
        d, n0 = -math.inf, None  # an overlap may still be found by the search
    if d > 0.0 and not inside and n0 is not None:
        lower = _support_gap(n0, cd, b)
        q = _clamp(tuple(witness.tolist()), b)
        p = _project_cylinder(q, cd)
        upper = math.dist(p, q)  # a genuine pair of points: >= the distance
        if upper - lower > POLISH_TOL:
            lower = max(lower, _polished_gap(n0, cd, b)[0])
            if upper - lower > POLISH_TOL:
                q = _clamp(p, b)  # one more alternation
                upper = min(upper, math.dist(_project_cylinder(q, cd), q))
                if upper - lower > POLISH_TOL:
                    return None
        return upper if upper > POLISH_TOL else min(lower, 0.0)
    if not inside and lower <= 0.0 and _prism_certified(lower, n, cd, b):  # the best crossing, by the prism
        return lower
    g, m = _polished_gap(n0, cd, b) if n0 is not None else (-math.inf, n)  # coal's direction, polished
    if g > lower + POLISH_TOL:  # better than every crossing, which then cannot be the optimum: certify g
        if g <= 0.0 and (_overlap_certified(g, m, cd, b) or _prism_certified(g, m, cd, b, fan=True)):
            return g
    if max(g, lower) > 0.0:  # a positive support gap: apart after all (coal said otherwise)
        return None
    # coal's EPA failed or stopped on a wrong face, or the crossing did not certify: search the
    # curved optima (box edge vs cap rim, box vertex vs side) and certify the best of everything.
    s, k = _searched_gap(cd, b)
    if s > max(g, lower) + POLISH_TOL:
        best, arg = s, k
    elif lower >= g - POLISH_TOL:  # the crossing after all: with the fan now (a vertex against the side)
        best, arg = lower, n
    else:
        return None  # coal's direction is the best, and its fan prism did not certify it
    if best <= 0.0 and (_overlap_certified(best, arg, cd, b) or _prism_certified(best, arg, cd, b, fan=True)):
        return best
    return None


def _searched_gap(cd: tuple, b: Bounds) -> tuple[float, tuple[float, float, float]]:
    """Best support gap (m) and its direction over the curved optima of an overlap: on each great
    circle n_i = 0 (a box edge against a cap rim) Newton's method from the best of its coarse samples
    (those of :func:`_candidate_gap`), and the eight box vertices against the side (n across the
    axis, along the vertex's offset). A lower bound, like every support gap; the caller certifies it."""
    c, a, r, h = np.array(cd[0]), np.array(cd[1]), cd[2], cd[3]
    g = _support_gaps(_ARC_DIRS, c, a, r, h, b).reshape(3, _ARC_SAMPLES)
    best, arg = -math.inf, (0.0, 0.0, 1.0)
    for i, j in enumerate(g.argmax(axis=1).tolist()):
        seed = tuple(_ARC_DIRS[i * _ARC_SAMPLES + j].tolist())
        for n in (seed, _arc_newton(i, seed, cd, b)):
            if n is not None:
                v = _support_gap(n, cd, b)
                if v > best:
                    best, arg = v, n
    side = _vertex_offsets(c, a, b)[1]
    norm = np.sqrt((side * side).sum(axis=1))
    side = side[norm > _DEGENERATE] / norm[norm > _DEGENERATE, None]
    if len(side):
        gaps = _support_gaps(side, c, a, r, h, b)
        k = int(gaps.argmax())
        if gaps[k] > best:
            best, arg = float(gaps[k]), tuple(side[k].tolist())
    return best, arg


def _point_box_signed_distance(p: tuple[float, float, float], b: Bounds) -> float:
    """Signed distance (m) of point ``p`` to the AABB ``b``: negative inside (minus the distance
    to the nearest face)."""
    dx = max(b[0] - p[0], 0.0, p[0] - b[3])
    dy = max(b[1] - p[1], 0.0, p[1] - b[4])
    dz = max(b[2] - p[2], 0.0, p[2] - b[5])
    if dx or dy or dz:
        return math.sqrt(dx * dx + dy * dy + dz * dz)
    return -min(p[0] - b[0], b[3] - p[0], p[1] - b[1], b[4] - p[1], p[2] - b[2], b[5] - p[2])


def _general_cylinder_box_distance(cyl: Cylinder, box: Box) -> float:
    """The non-upright path of cylinder_box_distance, for any pose (exposed for tests)."""
    return _general_distance(_cyl_data(cyl), box.bounds())


def cylinder_box_distance(cyl: Cylinder, box: Box) -> float:
    """Signed distance (m) between a cylinder in any pose and an AABB, world frame.

    Positive when apart, 0 when touching, minus the penetration depth when overlapping.
    Closed form when upright (within UPRIGHT_TOL), else _general_distance (see the module notes
    on why python-fcl is not used for the value).
    """
    if _tilt_sine(cyl) <= UPRIGHT_TOL:
        cx, cy, cz = cyl.center.tolist()
        return _upright_distance(cx, cy, cz, cyl.radius, cyl.half_length, box.bounds())
    return _general_cylinder_box_distance(cyl, box)
