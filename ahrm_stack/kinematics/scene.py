"""Collision scene: the pusher, the base and link capsules of the arm, the table, cube, obstacles and
the two phase regions, with signed distances, witness points and normals between them (coal).

Link capsules are derived from the robot description itself: each body's collision geometry, as
MuJoCo compiled it, is enclosed by the tightest capsule along its principal axis
(:func:`fit_capsule`), so no link dimension is written by hand.

Distances come from coal (the hpp-fcl successor that Pinocchio ships), through
:func:`signed_distance`, which never lets a query fail: python-fcl, used here before, aborted the
whole process (an uncaught C++ ``std::logic_error``) on some touching poses, which no ``try``
catches. coal's bindings turn C++ exceptions into Python ones; such an exception, or a non-finite or absurd
answer, gives the conservative bound of :func:`bounding_distance` instead (counted in
:data:`GUARD`). coal sizes are full lengths (``coal.Box(2 hx, 2 hy, 2 hz)``,
``coal.Cylinder(r, 2 h)``, ``coal.Capsule(r, segment length)``); capsules and cylinders lie along
their local z. Units: metres, world frame.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import coal
import mujoco
import numpy as np

from ahrm_stack.kinematics.model import ArmKinematics
from ahrm_stack.kinematics.shapes import Box

_REQUEST = coal.DistanceRequest()
_REQUEST.enable_signed_distance = True  # nearest points are always computed
_REQUEST.gjk_tolerance = 1e-8  # m: separated distances to ~3e-7 m (coal's default, 1e-6, gives 1e-6)
_RIM_POINTS = 256  # points per rim when a cylinder geom is enclosed by a capsule
_UNIT_TOLERANCE = 1e-6  # a normal further than this from unit length is not trusted
_SANE_DISTANCE = 1e3  # m: a larger answer is a failed query (coal reports DBL_MAX when GJK fails)
_POINT = 1e-20  # m^2: a shorter capsule segment is a point
_CROSSING = 1e-12  # m: segments closer than this cross and give no direction
_SIDE_TOLERANCE = 1e-9  # m, a centre this far on the wrong side of its witness point


@dataclasses.dataclass
class GuardCounter:
    """How many queries coal failed (raised, or answered with non-finite or absurd numbers) and were
    answered by the conservative bound instead."""

    failures: int = 0
    last_error: str = ""
    normals: int = 0  # answers whose normal did not separate the shapes and was replaced


GUARD = GuardCounter()


@dataclasses.dataclass(frozen=True)
class Capsule:
    """A capsule fixed to a frame of the arm model: segment ``start``-``end`` (frame coordinates,
    m) swept by a sphere of ``radius`` (m)."""

    frame: str
    start: np.ndarray
    end: np.ndarray
    radius: float

    @property
    def center(self) -> np.ndarray:
        return (self.start + self.end) / 2

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))


def fit_capsule(points: np.ndarray, frame: str) -> Capsule:
    """The capsule along the principal axis of ``points`` (n x 3, frame coordinates, m) that
    encloses every point, with the smallest radius for that axis and the shortest segment for
    that radius."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    axis = vt[0]
    t = (points - centroid) @ axis
    radial = np.linalg.norm((points - centroid) - np.outer(t, axis), axis=1)
    radius = float(radial.max())
    reach = np.sqrt(np.maximum(radius**2 - radial**2, 0.0))
    lo, hi = float(np.min(t + reach)), float(np.max(t - reach))
    if lo > hi:  # a ball-like point set: a sphere at the midpoint
        lo = hi = (lo + hi) / 2
    return Capsule(frame, centroid + lo * axis, centroid + hi * axis, radius)


def geom_points(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """Points (n x 3, body frame, m) whose convex hull encloses geom ``geom``: a mesh's vertices,
    a box's corners, or a cylinder's two rims as polygons circumscribing the circles.

    Raises:
        ValueError: another geom type (named).
    """
    kind = model.geom_type[geom]
    size = model.geom_size[geom]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        local = np.asarray(model.mesh_vert[start:start + count], dtype=float)
    elif kind == mujoco.mjtGeom.mjGEOM_BOX:
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size
    elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        angles = np.linspace(0.0, 2 * np.pi, _RIM_POINTS, endpoint=False)
        rim = size[0] / np.cos(np.pi / _RIM_POINTS)  # the polygon's edges touch the circle
        ring = np.stack([rim * np.cos(angles), rim * np.sin(angles), np.zeros_like(angles)], axis=1)
        local = np.concatenate([ring - [0, 0, size[1]], ring + [0, 0, size[1]]])
    else:
        raise ValueError(f"geom {model.geom(geom).name!r} of body {model.body(model.geom_bodyid[geom]).name!r}"
                         f" has type {mujoco.mjtGeom(kind).name}; a link capsule can enclose meshes, "
                         "boxes and cylinders")
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
    return local @ rotation.reshape(3, 3).T + model.geom_pos[geom]


def link_capsules(model: mujoco.MjModel, arm_bodies: Sequence[tuple[int, str]]) -> list[Capsule]:
    """One capsule per arm body, enclosing its colliding geoms (meshes, boxes, cylinders) as
    MuJoCo compiled them; a body without colliding geoms (the j2s6s200's link 6, whose URDF gives
    it only a visual mesh) is enclosed by its visual geoms. Bodies without geoms get none.

    ``arm_bodies``: (MuJoCo body id, arm-model frame name) pairs.
    """
    capsules = []
    for body_id, frame in arm_bodies:
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body_id]
        colliding = [g for g in geoms if model.geom_contype[g] or model.geom_conaffinity[g]]
        chosen = colliding or geoms
        if chosen:
            capsules.append(fit_capsule(np.concatenate([geom_points(model, g) for g in chosen]), frame))
    return capsules


@dataclasses.dataclass(frozen=True)
class Distance:
    """Signed distance (m) between two named objects, the witness points on each (world, m) and
    the unit normal from ``b`` towards ``a`` (moving ``a`` along it increases the distance).
    ``exact`` is False when the conservative bound answered (coal failed)."""

    a: str
    b: str
    distance: float
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    exact: bool = True


def local_extent(geometry: coal.CollisionGeometry) -> np.ndarray:
    """Half extents (m) of a coal box, capsule or cylinder along its local axes about its
    origin: its local bounding box."""
    if isinstance(geometry, coal.Box):
        return np.array(geometry.halfSide, dtype=float)
    if isinstance(geometry, coal.Capsule):
        r = geometry.radius
        return np.array([r, r, geometry.halfLength + r])
    if isinstance(geometry, coal.Cylinder):
        r = geometry.radius
        return np.array([r, r, geometry.halfLength])
    raise TypeError(f"no extent for a {type(geometry).__name__}")


def bounding_radius(geometry: coal.CollisionGeometry) -> float:
    """Radius (m) of the smallest ball about the origin enclosing a coal box, capsule or
    cylinder."""
    if isinstance(geometry, coal.Capsule):
        return float(geometry.halfLength + geometry.radius)
    return float(np.linalg.norm(local_extent(geometry)))


def bounding_distance(a: coal.CollisionObject, b: coal.CollisionObject
                      ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """A lower bound of the signed distance between ``a`` and ``b`` that needs no library:
    ``a``'s bounding ball against ``b`` when ``b`` is a box (exact for the ball, signed), else
    ball against ball. Returns (distance m, witness on a, witness on b, unit normal from b
    towards a), as :func:`signed_distance`."""
    center = np.asarray(a.getTranslation(), dtype=float)
    radius = bounding_radius(a.collisionGeometry())
    other = b.collisionGeometry()
    origin = np.asarray(b.getTranslation(), dtype=float)
    if isinstance(other, coal.Box):
        rotation = np.asarray(b.getRotation(), dtype=float)
        half = local_extent(other)
        local = rotation.T @ (center - origin)
        clamped = np.clip(local, -half, half)
        gap = local - clamped
        outside = float(np.linalg.norm(gap))
        if outside > 0:
            normal_local, surface, depth = gap / outside, clamped, -outside
        else:  # the centre is inside: out through the nearest face
            slack = half - np.abs(local)
            axis = int(np.argmin(slack))
            normal_local = np.zeros(3)
            normal_local[axis] = 1.0 if local[axis] >= 0 else -1.0
            surface = local.copy()
            surface[axis] = normal_local[axis] * half[axis]
            depth = float(slack[axis])
        normal = rotation @ normal_local
        point_b = origin + rotation @ surface
        distance = -depth - radius
    else:
        offset = center - origin
        length = float(np.linalg.norm(offset))
        normal = offset / length if length > 0 else np.array([0.0, 0.0, 1.0])
        other_radius = bounding_radius(other)
        point_b = origin + other_radius * normal
        distance = length - radius - other_radius
    return float(distance), center - radius * normal, point_b, normal


def signed_distance(a: coal.CollisionObject, b: coal.CollisionObject
                    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Signed distance between two placed coal objects (m; minus the penetration depth when they
    overlap), the witness points on ``a`` and on ``b`` (world, m), the unit normal from ``b``
    towards ``a`` (coal's, valid at contact where the witness points coincide) and whether coal
    answered. This never raises and never returns NaN for finite placements: a coal exception or
    a non-finite answer gives :func:`bounding_distance`, a lower bound, and counts in
    :data:`GUARD`."""
    result = coal.DistanceResult()
    try:
        d = float(coal.distance(a, b, _REQUEST, result))
        ax, ay, az = result.getNearestPoint1().tolist()
        bx, by, bz = result.getNearestPoint2().tolist()
        nx, ny, nz = (-result.normal).tolist()  # coal's normal points from a to b
        # one sum is NaN or huge when any term is (plain floats: this runs for every query)
        if (abs(d) < _SANE_DISTANCE and abs(ax + ay + az + bx + by + bz) < _SANE_DISTANCE
                and abs(nx * nx + ny * ny + nz * nz - 1.0) <= _UNIT_TOLERANCE):
            # A valid normal separates: a's witness is a's lowest point along it, b's is b's
            # highest, so a's centre lies on its far side and b's centre on the near one. At an
            # exact touch on an edge coal can return a normal that fails this; then the normal is
            # taken from b's centre to a's (the distance and the witness points stand).
            cax, cay, caz = a.getTranslation().tolist()
            cbx, cby, cbz = b.getTranslation().tolist()
            if (nx * (cax - ax) + ny * (cay - ay) + nz * (caz - az) < -_SIDE_TOLERANCE
                    or nx * (cbx - bx) + ny * (cby - by) + nz * (cbz - bz) > _SIDE_TOLERANCE):
                GUARD.normals += 1
                offset = np.array([cax - cbx, cay - cby, caz - cbz])
                length = float(np.linalg.norm(offset))
                nx, ny, nz = (offset / length).tolist() if length > 0 else (0.0, 0.0, 1.0)
            return d, np.array([ax, ay, az]), np.array([bx, by, bz]), np.array([nx, ny, nz]), True
        error = f"non-finite, absurd or non-unit answer: d={d!r}, normal={[nx, ny, nz]}"
    except Exception as exc:  # noqa: BLE001 - any failure of the library takes the guarded path
        error = f"{type(exc).__name__}: {exc}"
    GUARD.failures += 1
    GUARD.last_error = error
    return (*bounding_distance(a, b), False)


def placed_signed_distance(compute: coal.ComputeDistance, result: coal.DistanceResult,
                           transform_a: coal.Transform3s, transform_b: coal.Transform3s,
                           center_a: Sequence[float], center_b: Sequence[float]) -> tuple[float, ...] | None:
    """:func:`signed_distance` on its common path, set up once: ``compute`` is
    ``coal.ComputeDistance(geometry_a, geometry_b)``, ``result`` a ``DistanceResult`` reused from
    call to call (cleared here), the shapes placed at ``transform_a`` and ``transform_b`` with
    origins ``center_a`` and ``center_b`` (world, m). Returns the distance (m), the witness points
    on a and on b and the normal from b towards a, as ten plain floats, bit for bit what
    :func:`signed_distance` returns for the same placements; None where :func:`signed_distance`
    would take another path (coal raised, or answered with a non-finite, absurd or non-unit value,
    or a normal that does not separate): then ask :func:`signed_distance` itself, which guards the
    answer and counts it in :data:`GUARD`."""
    result.clear()  # a DistanceResult keeps the smallest distance it has seen
    try:
        d = float(compute(transform_a, transform_b, _REQUEST, result))
    except Exception:  # noqa: BLE001 - signed_distance answers it, guarded
        return None
    ax, ay, az = result.getNearestPoint1().tolist()
    bx, by, bz = result.getNearestPoint2().tolist()
    mx, my, mz = result.normal.tolist()
    nx, ny, nz = -mx, -my, -mz  # coal's normal points from a to b
    cax, cay, caz = center_a
    cbx, cby, cbz = center_b
    if (abs(d) < _SANE_DISTANCE and abs(ax + ay + az + bx + by + bz) < _SANE_DISTANCE
            and abs(nx * nx + ny * ny + nz * nz - 1.0) <= _UNIT_TOLERANCE
            and not nx * (cax - ax) + ny * (cay - ay) + nz * (caz - az) < -_SIDE_TOLERANCE
            and not nx * (cbx - bx) + ny * (cby - by) + nz * (cbz - bz) > _SIDE_TOLERANCE):
        return d, ax, ay, az, bx, by, bz, nx, ny, nz
    return None


def capsule_distance(center_a: Sequence[float], axis_a: Sequence[float], half_a: float, radius_a: float,
                     center_b: Sequence[float], axis_b: Sequence[float], half_b: float, radius_b: float
                     ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance between two capsules in closed form: segments ``center +- half * axis``
    (world, m; ``axis`` a unit vector) swept by ``radius`` (m). Returns the distance (m; minus
    the penetration depth while the segments do not cross), the witness points on a and on b and
    the unit normal from b towards a, as :func:`signed_distance`. The segments' closest points are
    Ericson's (Real-Time Collision Detection, 5.1.9), in plain floats (:func:`capsule_distance_floats`)."""
    d, ax, ay, az, bx, by, bz, nx, ny, nz = capsule_distance_floats(
        center_a, axis_a, half_a, radius_a, center_b, axis_b, half_b, radius_b)
    return d, np.array([ax, ay, az]), np.array([bx, by, bz]), np.array([nx, ny, nz])


def capsule_distance_floats(center_a: Sequence[float], axis_a: Sequence[float], half_a: float,
                            radius_a: float, center_b: Sequence[float], axis_b: Sequence[float],
                            half_b: float, radius_b: float) -> tuple[float, ...]:
    """:func:`capsule_distance` as ten plain floats: the distance (m), the witness point on a, the
    witness point on b and the normal from b towards a (x, y, z each). This runs for the
    self-collision pairs at every filter call."""
    ax, ay, az = axis_a
    bx, by, bz = axis_b
    d1 = (2 * half_a * ax, 2 * half_a * ay, 2 * half_a * az)
    d2 = (2 * half_b * bx, 2 * half_b * by, 2 * half_b * bz)
    p1 = (center_a[0] - half_a * ax, center_a[1] - half_a * ay, center_a[2] - half_a * az)
    p2 = (center_b[0] - half_b * bx, center_b[1] - half_b * by, center_b[2] - half_b * bz)
    r = (p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2])
    a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]
    f = d2[0] * r[0] + d2[1] * r[1] + d2[2] * r[2]
    if a <= _POINT and e <= _POINT:
        s = t = 0.0
    elif a <= _POINT:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = d1[0] * r[0] + d1[1] * r[1] + d1[2] * r[2]
        if e <= _POINT:
            s, t = min(max(-c / a, 0.0), 1.0), 0.0
        else:
            b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > _POINT * a * e else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = min(max(-c / a, 0.0), 1.0), 0.0
            elif t > 1.0:
                s, t = min(max((b - c) / a, 0.0), 1.0), 1.0
    c1 = (p1[0] + s * d1[0], p1[1] + s * d1[1], p1[2] + s * d1[2])
    c2 = (p2[0] + t * d2[0], p2[1] + t * d2[1], p2[2] + t * d2[2])
    gx, gy, gz = c1[0] - c2[0], c1[1] - c2[1], c1[2] - c2[2]
    between = math.sqrt(gx * gx + gy * gy + gz * gz)
    if between > _CROSSING:
        nx, ny, nz = gx / between, gy / between, gz / between
    else:  # the segments cross: push the centres apart (or up)
        gx, gy, gz = (center_a[0] - center_b[0], center_a[1] - center_b[1], center_a[2] - center_b[2])
        length = math.sqrt(gx * gx + gy * gy + gz * gz)
        nx, ny, nz = (gx / length, gy / length, gz / length) if length > _CROSSING else (0.0, 0.0, 1.0)
    return (between - radius_a - radius_b,
            c1[0] - radius_a * nx, c1[1] - radius_a * ny, c1[2] - radius_a * nz,
            c2[0] + radius_b * nx, c2[1] + radius_b * ny, c2[2] + radius_b * nz,
            nx, ny, nz)


def _transform(rotation: np.ndarray, translation: np.ndarray) -> coal.Transform3s:
    return coal.Transform3s(np.ascontiguousarray(rotation, dtype=float),
                            np.ascontiguousarray(translation, dtype=float))


def _capsule_rotation(direction: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is ``direction`` (capsules and cylinders lie along local z)."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _check_pose(name: str, position: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    position = np.asarray(position, dtype=float)
    rotation = np.asarray(rotation, dtype=float)
    if position.shape != (3,) or rotation.shape != (3, 3):
        raise ValueError(f"{name} pose must be a 3-vector and a 3x3 rotation, got shapes "
                         f"{position.shape} and {rotation.shape}")
    if not (np.isfinite(position).all() and np.isfinite(rotation).all()):
        raise ValueError(f"{name} pose is not finite: position {position.tolist()}, "
                         f"rotation {rotation.ravel().tolist()}")
    return position, rotation


class CollisionScene:
    """coal objects for the robot parts (``pusher``, one capsule per link and, with
    ``base_frame``, the base) and the environment (``table``, ``cube``, ``obstacle_i``,
    ``B_target``, ``B_obstacles``).

    Robot parts are placed from :class:`ArmKinematics` (call ``update_robot`` after
    ``kinematics.update(q)``); environment objects from poses (``update_objects``). The base is
    a robot part for self-collision only: it sits on the table and never moves
    (:attr:`moving_parts` leaves it out).
    """

    def __init__(self, kinematics: ArmKinematics, capsules: Sequence[Capsule], pusher_frame: str,
                 pusher_radius: float, pusher_half_length: float, table_half_extent: Sequence[float],
                 table_height: float, table_thickness: float, cube_size: float,
                 obstacle_half_sizes: np.ndarray, base_frame: str | None = None) -> None:
        self.kinematics = kinematics
        self.capsules = list(capsules)
        if base_frame is not None and base_frame not in {c.frame for c in self.capsules}:
            raise ValueError(f"base frame {base_frame!r} has no capsule; capsules: "
                             f"{[c.frame for c in self.capsules]}")
        self.base_frame = base_frame
        self._capsule_frames = [kinematics.frame_id(c.frame) for c in self.capsules]
        self._capsule_local = []
        self.robot: dict[str, coal.CollisionObject] = {}
        for capsule in self.capsules:
            length = capsule.length
            rotation = _capsule_rotation(capsule.end - capsule.start) if length > 0 else np.eye(3)
            self._capsule_local.append((rotation, capsule.center))
            self.robot[capsule.frame] = coal.CollisionObject(coal.Capsule(capsule.radius, length))
        self._pusher_frame = kinematics.frame_id(pusher_frame)
        self.robot["pusher"] = coal.CollisionObject(coal.Cylinder(pusher_radius, 2 * pusher_half_length))
        self.moving_parts = tuple(name for name in self.robot if name != base_frame)
        hx, hy = table_half_extent
        self.table_top = table_height
        self.environment: dict[str, coal.CollisionObject] = {
            "table": coal.CollisionObject(coal.Box(2 * hx, 2 * hy, table_thickness),
                                          _transform(np.eye(3), np.array([0, 0, table_height - table_thickness / 2]))),
            "cube": coal.CollisionObject(coal.Box(cube_size, cube_size, cube_size)),
        }
        for i, half in enumerate(np.asarray(obstacle_half_sizes, dtype=float)):
            self.environment[f"obstacle_{i}"] = coal.CollisionObject(coal.Box(*(2 * half)))
        self._obstacles = [self.environment[n] for n in self.environment if n.startswith("obstacle_")]
        # update_objects' memory: each object's pose as last placed (rows: the cube, then the
        # obstacles; position, then the rotation's 9 entries), NaN before the first placement
        self._movable = [self.environment["cube"], *self._obstacles]
        self._placed = np.full((len(self._movable), 12), np.nan)
        self._poses = np.empty_like(self._placed)

    def update_robot(self) -> None:
        """Place the pusher and the capsules at the kinematics' current configuration."""
        for obj, fid, (rotation, center) in zip(self.robot.values(), self._capsule_frames,
                                                self._capsule_local):
            position, frame_rotation = self.kinematics.frame_pose(fid)
            obj.setTransform(_transform(frame_rotation @ rotation, position + frame_rotation @ center))
        position, rotation = self.kinematics.frame_pose(self._pusher_frame)
        self.robot["pusher"].setTransform(_transform(rotation, position))

    def update_objects(self, cube_position: np.ndarray, cube_rotation: np.ndarray,
                       obstacle_positions: np.ndarray, obstacle_rotations: np.ndarray,
                       regions: dict[str, Box] | None = None) -> None:
        """Place the cube, the obstacles (positions m, rotation matrices) and the phase regions.
        An object whose pose equals, bit for bit, the one this method last gave it keeps its
        transform (it would be set to the same values): in a control loop the obstacles rarely
        move and the cube only in phases 2–3.

        Raises:
            ValueError: a pose that is not finite (or of the wrong shape), or the wrong number of
                obstacles; the message names the object. Nothing is moved then.
        """
        obstacle_positions = np.asarray(obstacle_positions, dtype=float).reshape(-1, 3)
        obstacle_rotations = np.asarray(obstacle_rotations, dtype=float).reshape(-1, 3, 3)
        if len(obstacle_positions) != len(self._obstacles) or len(obstacle_rotations) != len(self._obstacles):
            raise ValueError(f"{len(obstacle_positions)} obstacle positions and {len(obstacle_rotations)} "
                             f"rotations for a scene of {len(self._obstacles)} obstacles")
        poses = self._poses
        if np.shape(cube_position) == (3,) and np.shape(cube_rotation) == (3, 3):
            poses[0, :3], poses[0, 3:] = cube_position, np.reshape(cube_rotation, 9)
            poses[1:, :3], poses[1:, 3:] = obstacle_positions, obstacle_rotations.reshape(-1, 9)
            valid = bool(np.isfinite(poses).all())
        else:
            valid = False
        if not valid:  # the checks below name the object and raise
            _check_pose("cube", cube_position, cube_rotation)
            for i, (p, r) in enumerate(zip(obstacle_positions, obstacle_rotations)):
                _check_pose(f"obstacle_{i}", p, r)
        for name, box in (regions or {}).items():
            _check_pose(name, box.center, np.eye(3))
        changed = (poses.view(np.int64) != self._placed.view(np.int64)).any(axis=1)  # bit for bit
        for i in np.flatnonzero(changed).tolist():
            self._movable[i].setTransform(_transform(poses[i, 3:].reshape(3, 3), poses[i, :3]))
            self._placed[i] = poses[i]
        for name, box in (regions or {}).items():
            self.environment[name] = coal.CollisionObject(coal.Box(*(2 * np.asarray(box.half_size))),
                                                          _transform(np.eye(3), box.center))

    def distance(self, robot_part: str, other: str) -> Distance:
        """Signed distance, witness points and normal between a robot part and an environment
        object or another robot part (:func:`signed_distance`)."""
        obj = self.environment.get(other)
        if obj is None:
            obj = self.robot[other]
        d, point_a, point_b, normal, exact = signed_distance(self.robot[robot_part], obj)
        return Distance(robot_part, other, d, point_a, point_b, normal, exact)

    def distances(self, robot_parts: Sequence[str] | None = None,
                  others: Sequence[str] | None = None) -> list[Distance]:
        """All pairs of ``robot_parts`` (default: the moving parts) x ``others`` (default: table
        and obstacles)."""
        parts = list(self.moving_parts) if robot_parts is None else robot_parts
        if others is None:
            others = ["table"] + [n for n in self.environment if n.startswith("obstacle_")]
        return [self.distance(p, o) for p in parts for o in others]
