"""The distance rows: the robot parts (pusher, link capsules) keep a safe distance from the table
and from the obstacles.

For each pair (robot part a, environment object b) closer than the activation distance, FCL gives
the signed distance ``d`` and the witness points ``p_a`` (on the part) and ``p_b``; with
``n = sign(d) (p_a - p_b) / |p_a - p_b|`` (from b towards a) and ``J_a`` the linear Jacobian of the
witness point ``p_a`` on the part, the row is

    d + horizon * n^T J_a u >= d_safe        stored as   -horizon * n^T J_a u <= d - d_safe.

Rows against the table are named ``table:<part>`` (one per part at most); rows against obstacles
``obstacle:<part>/<obstacle>``, of which only the ``max_obstacle_rows`` nearest are kept. Pairs that
cannot be within the activation distance are skipped without an FCL query, by a bound of each
part's bounding sphere against each object's world-aligned bounding box; the sizes are measured
from the FCL objects once, at construction.
"""

from __future__ import annotations

from typing import Mapping

import fcl
import numpy as np

from ahrm_stack.kinematics.scene import CollisionScene
from ahrm_stack.safety.constraints.base import ArmSnapshot, ConstraintDefinitionError, Rows

_REQUEST = fcl.DistanceRequest(enable_signed_distance=True, enable_nearest_points=True)
_PROBE_DISTANCE = 10.0  # m, far outside any part or object: probes measure their extents
_PROBE_RADIUS = 1e-3  # m
_EXTENT_PAD = 1e-3  # m added to each measured extent (FCL's accuracy on the probes is far better)
_DEGENERATE = 1e-9  # m, witness points closer than this give no direction
TABLE = "table"


def local_extent(obj: fcl.CollisionObject) -> np.ndarray:
    """Half extents (m) of ``obj``'s geometry along its local axes about its origin (the larger
    of the + and - side per axis), measured with FCL against a small far-away probe sphere. For
    FCL's primitives (box, capsule, cylinder, sphere) this is their local bounding box."""
    rotation, origin = obj.getRotation(), obj.getTranslation()
    extent = np.zeros(3)
    probe = fcl.CollisionObject(fcl.Sphere(_PROBE_RADIUS))
    for axis in range(3):
        for side in (1.0, -1.0):
            probe.setTransform(fcl.Transform(np.eye(3), origin + side * _PROBE_DISTANCE * rotation[:, axis]))
            d = fcl.distance(obj, probe, _REQUEST, fcl.DistanceResult())
            extent[axis] = max(extent[axis], _PROBE_DISTANCE - _PROBE_RADIUS - d)
    return extent + _EXTENT_PAD


class DistanceLimit:
    """Distance rows between every robot part of ``scene`` and its ``table`` and ``obstacle_i``.

    The robot parts are placed here, from the filter's own kinematics snapshot: each part gets a
    frame of its own, fixed where the scene placed it relative to the frame carrying it; the
    caller keeps the environment objects current (``scene.update_objects``).

    Args:
        scene: the FCL scene; its robot parts must be placed (``scene.update_robot``) at the
            configuration of ``snapshot`` when this is built.
        snapshot: kinematics updated at the configuration the scene's robot parts are placed at
            (the parts' frames are attached to its model).
        part_frames: frame id rigidly carrying each robot part of the scene.
        safe_distance: d_safe, m.
        activation_distance: m; pairs farther apart add no row. Must exceed ``safe_distance``.
        max_obstacle_rows: at most this many obstacle rows (the nearest pairs).
        horizon: s over which the command is linearised (see ``PositionLimit``).
    """

    def __init__(self, scene: CollisionScene, snapshot: ArmSnapshot, part_frames: Mapping[str, int],
                 safe_distance: float, activation_distance: float, max_obstacle_rows: int,
                 horizon: float) -> None:
        if not (np.isfinite(safe_distance) and safe_distance >= 0):
            raise ConstraintDefinitionError(f"safe distance must be finite and >= 0 m, got {safe_distance!r}")
        if not (np.isfinite(activation_distance) and activation_distance > safe_distance):
            raise ConstraintDefinitionError(
                f"activation distance ({activation_distance!r} m) must exceed the safe distance "
                f"({safe_distance!r} m)")
        if max_obstacle_rows < 0:
            raise ConstraintDefinitionError(f"max_obstacle_rows must be >= 0, got {max_obstacle_rows!r}")
        if not (np.isfinite(horizon) and horizon > 0):
            raise ConstraintDefinitionError(f"distance horizon must be finite and > 0 s, got {horizon!r}")
        missing = sorted(set(scene.robot) - set(part_frames))
        if missing:
            raise ConstraintDefinitionError(f"no frame given for robot part(s) {missing} of the scene")
        if TABLE not in scene.environment:
            raise ConstraintDefinitionError("the collision scene has no 'table'")
        self.scene = scene
        self.safe_distance = float(safe_distance)
        self.activation_distance = float(activation_distance)
        self.max_obstacle_rows = int(max_obstacle_rows)
        self.horizon = float(horizon)
        self.part_names = tuple(scene.robot)
        self._parts = [scene.robot[name] for name in self.part_names]
        # A frame at each part's origin, fixed to the frame carrying it, as the scene placed it.
        self._part_frames = [snapshot.attach_frame(f"safety/{name}", int(part_frames[name]),
                                                   obj.getTranslation(), obj.getRotation())
                             for name, obj in zip(self.part_names, self._parts)]
        # Column 0 is the table, then the obstacles.
        self.object_names = (TABLE,) + tuple(n for n in scene.environment if n.startswith("obstacle_"))
        self._objects = [scene.environment[name] for name in self.object_names]
        self._part_radius = np.array([np.linalg.norm(local_extent(o)) for o in self._parts])
        # For the bounding test: the table's world-aligned box as it lies (the scene never moves
        # it); each obstacle's local box, turned with it at every call.
        table = self._objects[0]
        self._table_origin = table.getTranslation()
        self._table_half = np.abs(table.getRotation()) @ local_extent(table)
        self._obstacle_extent = np.array([local_extent(o) for o in self._objects[1:]]).reshape(-1, 3)
        self._names = [[f"table:{a}"] + [f"obstacle:{a}/{b}" for b in self.object_names[1:]]
                       for a in self.part_names]
        self.last_queries = 0  # FCL queries made by the last call (after the bounding test)

    def max_rows(self, table: bool, obstacles: bool) -> int:
        return (len(self._parts) if table else 0) + (self.max_obstacle_rows if obstacles else 0)

    def rows(self, snapshot: ArmSnapshot, table: bool = True, obstacles: bool = True) -> Rows:
        """Rows against the table and/or the obstacles at the configuration ``snapshot`` was
        updated at."""
        nv = snapshot.model.nv
        self.last_queries = 0
        obstacles = obstacles and self.max_obstacle_rows > 0 and len(self._objects) > 1
        if not (table or obstacles):
            return Rows.empty(nv)
        first = 0 if table else 1
        # Bounding test: each part's sphere against each object's world-aligned box.
        centers = snapshot.positions(self._part_frames)
        if obstacles:
            others = self._objects[1:]
            rotations = np.abs(np.array([o.getRotation() for o in others]))
            origins = np.array(([self._table_origin] if table else []) + [o.getTranslation() for o in others])
            half = np.einsum("kij,kj->ki", rotations, self._obstacle_extent)
            half = np.concatenate(([self._table_half], half)) if table else half
        else:
            origins, half = self._table_origin[None], self._table_half[None]
        gap = np.maximum(np.abs(centers[:, None, :] - origins) - half, 0.0)
        near = np.sqrt(np.einsum("ijk,ijk->ij", gap, gap)) - self._part_radius[:, None] \
            <= self.activation_distance
        parts, objects = np.nonzero(near)
        self.last_queries = len(parts)
        if not len(parts):
            return Rows.empty(nv)
        # Exact signed distances and witness points of the candidates.
        placed = set()
        found = []
        for i, j in zip(parts.tolist(), (objects + first).tolist()):
            part = self._parts[i]
            if i not in placed:
                part.setTransform(fcl.Transform(snapshot.placement(self._part_frames[i])[1], centers[i]))
                placed.add(i)
            result = fcl.DistanceResult()
            d = fcl.distance(part, self._objects[j], _REQUEST, result)
            if d <= self.activation_distance:
                found.append((j > 0, d, i, j, result.nearest_points))
        if not found:
            return Rows.empty(nv)
        table_rows = [f for f in found if not f[0]]
        obstacle_rows = sorted((f for f in found if f[0]), key=lambda f: f[1])[:self.max_obstacle_rows]
        found = table_rows + obstacle_rows
        # The rows, all at once: n = sign(d) (p_part - p_object)/|.|, row = -T n^T J_witness.
        distance = np.array([f[1] for f in found])
        on_part = np.array([f[4][0] for f in found])
        direction = on_part - np.array([f[4][1] for f in found])
        length = np.sqrt(np.einsum("ij,ij->i", direction, direction))
        if length.min() < _DEGENERATE:  # touching: push away from the object's origin instead
            for k in np.flatnonzero(length < _DEGENERATE):
                direction[k] = on_part[k] - self._objects[found[k][3]].getTranslation()
            length = np.maximum(np.sqrt(np.einsum("ij,ij->i", direction, direction)), _DEGENERATE)
        normal = direction * (np.where(distance < 0, -1.0, 1.0) / length)[:, None]
        frames = [self._part_frames[f[2]] for f in found]
        matrix = -self.horizon * snapshot.point_rows(frames, on_part, normal)
        names = tuple(self._names[f[2]][f[3]] for f in found)
        return Rows(matrix, distance - self.safe_distance, names)
