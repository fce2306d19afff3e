"""The distance rows as they were computed before the fast path (2026-12-01): the reference the
tests and ``benchmarks/bench_distance_rows.py`` hold :class:`ahrm_stack.safety.constraints.DistanceLimit`
to. One coal query per candidate pair through ``signed_distance`` (a fresh ``DistanceResult``, the
scene's collision objects placed), the rows assembled pair by pair. Nothing in ``ahrm_stack``
imports this module.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import coal
import numpy as np
import pinocchio as pin

from ahrm_stack.kinematics.scene import (CollisionScene, bounding_radius, capsule_distance, local_extent,
                                         signed_distance)
from ahrm_stack.safety.constraints.base import ArmSnapshot, ConstraintDefinitionError, Rows
from ahrm_stack.safety.constraints.distance import TABLE

_TABLE, _OBSTACLE, _SELF = 0, 1, 2  # kinds of row, in the order they are stacked
_LEVI_CIVITA = np.zeros((3, 3, 3))
_LEVI_CIVITA[0, 1, 2] = _LEVI_CIVITA[1, 2, 0] = _LEVI_CIVITA[2, 0, 1] = 1.0
_LEVI_CIVITA[0, 2, 1] = _LEVI_CIVITA[2, 1, 0] = _LEVI_CIVITA[1, 0, 2] = -1.0


def point_rows(snapshot: ArmSnapshot, frames: Sequence[int], points: np.ndarray,
               directions: np.ndarray) -> np.ndarray:
    """``ArmSnapshot.point_rows`` as it was: ``directions[k]^T J_k`` with J_k the linear Jacobian of
    the world point ``points[k]`` rigidly attached to ``frames[k]``."""
    placed = {f: (snapshot.position(f), snapshot.jacobian(f)) for f in set(frames)}
    origins = np.array([placed[f][0] for f in frames])
    jacobians = np.array([placed[f][1] for f in frames])  # k x 6 x nv
    moments = np.einsum("ijk,nj,nk->ni", _LEVI_CIVITA, points - origins, directions)  # r x n
    return np.einsum("ki,kij->kj", np.concatenate((directions, moments), axis=1), jacobians)


def placements(snapshot: ArmSnapshot, frames: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """``ArmSnapshot.placements`` as it was: world positions (k x 3, m) and rotation matrices of
    several frames."""
    model, data = snapshot.model, snapshot.data
    placed = [pin.updateFramePlacement(model, data, f) for f in frames]
    local = np.array([p.translation for p in placed])
    rotations = np.array([p.rotation for p in placed])
    if snapshot._identity_base:
        return local + snapshot.base_translation, rotations
    return (local @ snapshot.base_rotation.T + snapshot.base_translation,
            np.einsum("ij,kjl->kil", snapshot.base_rotation, rotations))


class ReferenceDistanceLimit:
    """Distance rows between the robot parts of ``scene`` and its ``table`` and ``obstacle_i``,
    and between the given pairs of robot parts.

    The robot parts are placed here, from the filter's own kinematics snapshot: each part gets a
    frame of its own, fixed where the scene placed it relative to the frame carrying it; the
    caller keeps the environment objects current (``scene.update_objects``).

    Args:
        scene: the collision scene; its robot parts must be placed (``scene.update_robot``) at
            the configuration of ``snapshot`` when this is built.
        snapshot: kinematics updated at the configuration the scene's robot parts are placed at
            (the parts' frames are attached to its model).
        part_frames: frame id rigidly carrying each robot part of the scene.
        safe_distance: d_safe, m (every row).
        activation_distance: m; pairs farther apart add no row. Must exceed ``safe_distance``.
        max_obstacle_rows: at most this many obstacle rows (the nearest pairs).
        horizon: s over which the command is linearised (see ``PositionLimit``).
        self_pairs: pairs of robot part names (scene names) that keep ``safe_distance`` from each
            other.
    """

    def __init__(self, scene: CollisionScene, snapshot: ArmSnapshot, part_frames: Mapping[str, int],
                 safe_distance: float, activation_distance: float, max_obstacle_rows: int,
                 horizon: float, self_pairs: Sequence[tuple[str, str]] = ()) -> None:
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
        index = {name: i for i, name in enumerate(self.part_names)}
        self._moving = np.array([index[name] for name in scene.moving_parts], dtype=int)
        pairs = []
        for pair in self_pairs:
            a, b = pair
            for name in (a, b):
                if name not in index:
                    raise ConstraintDefinitionError(f"self-collision pair {list(pair)}: {name!r} is not a "
                                                    f"robot part of the scene {list(self.part_names)}")
            if a == b or (index[a], index[b]) in pairs or (index[b], index[a]) in pairs:
                raise ConstraintDefinitionError(f"self-collision pair {list(pair)} repeats a part or a pair")
            pairs.append((index[a], index[b]))
        self.self_pairs = tuple((self.part_names[i], self.part_names[j]) for i, j in pairs)
        self._pair_a = np.array([p[0] for p in pairs], dtype=int)
        self._pair_b = np.array([p[1] for p in pairs], dtype=int)
        # A frame at each part's origin, fixed to the frame carrying it, as the scene placed it.
        self._part_frames = [snapshot.attach_frame(f"reference/{name}", int(part_frames[name]),
                                                   obj.getTranslation(), obj.getRotation())
                             for name, obj in zip(self.part_names, self._parts)]
        # Column 0 is the table, then the obstacles.
        self.object_names = (TABLE,) + tuple(n for n in scene.environment if n.startswith("obstacle_"))
        self._objects = [scene.environment[name] for name in self.object_names]
        self._part_radius = np.array([bounding_radius(o.collisionGeometry()) for o in self._parts])
        # For the bounding test: the table's world-aligned box as it lies (the scene never moves
        # it); each obstacle's local box, turned with it at every call.
        table = self._objects[0]
        self._table_origin = np.array(table.getTranslation())
        self._table_half = np.abs(np.array(table.getRotation())) @ local_extent(table.collisionGeometry())
        self._obstacle_extent = np.array([local_extent(o.collisionGeometry())
                                          for o in self._objects[1:]]).reshape(-1, 3)
        self._names = [[f"table:{a}"] + [f"obstacle:{a}/{b}" for b in self.object_names[1:]]
                       for a in self.part_names]
        self._self_names = [f"self:{a}/{b}" for a, b in self.self_pairs]
        # Two capsules are measured in closed form (no library call): each part's half length
        # and radius, and whether it is a capsule (the pusher is a cylinder).
        self._capsule = [isinstance(o.collisionGeometry(), coal.Capsule) for o in self._parts]
        self._half_radius = [(float(o.collisionGeometry().halfLength), float(o.collisionGeometry().radius))
                             for o in self._parts]
        self.last_queries = 0  # distance queries made by the last call (after the bounding test)

    def max_rows(self, table: bool, obstacles: bool, self_collision: bool = False) -> int:
        return ((len(self._moving) if table else 0) + (self.max_obstacle_rows if obstacles else 0)
                + (len(self.self_pairs) if self_collision else 0))

    def rows(self, snapshot: ArmSnapshot, table: bool = True, obstacles: bool = True,
             self_collision: bool = False) -> Rows:
        """Rows against the table, the obstacles and/or between the self-collision pairs at the
        configuration ``snapshot`` was updated at."""
        nv = snapshot.model.nv
        self.last_queries = 0
        obstacles = obstacles and self.max_obstacle_rows > 0 and len(self._objects) > 1
        self_collision = self_collision and len(self.self_pairs) > 0
        if not (table or obstacles or self_collision):
            return Rows.empty(nv)
        centers, part_rotations = placements(snapshot, self._part_frames)
        candidates = []  # (kind, part index, object index or part index)
        if table or obstacles:
            # Bounding test: each moving part's ball against each object's world-aligned box.
            first = 0 if table else 1
            if obstacles:
                others = self._objects[1:]
                rotations = np.abs(np.array([o.getRotation() for o in others]))
                origins = np.array(([self._table_origin] if table else []) +
                                   [o.getTranslation() for o in others])
                half = np.einsum("kij,kj->ki", rotations, self._obstacle_extent)
                half = np.concatenate(([self._table_half], half)) if table else half
            else:
                origins, half = self._table_origin[None], self._table_half[None]
            moving = centers[self._moving]
            gap = np.maximum(np.abs(moving[:, None, :] - origins) - half, 0.0)
            near = np.sqrt(np.einsum("ijk,ijk->ij", gap, gap)) - self._part_radius[self._moving, None] \
                <= self.activation_distance
            parts, objects = np.nonzero(near)
            candidates += [(_TABLE if j == 0 else _OBSTACLE, i, j)
                           for i, j in zip(self._moving[parts].tolist(), (objects + first).tolist())]
        if self_collision:
            offset = centers[self._pair_a] - centers[self._pair_b]
            reach = np.sqrt(np.einsum("ij,ij->i", offset, offset)) \
                - self._part_radius[self._pair_a] - self._part_radius[self._pair_b]
            near = np.flatnonzero(reach <= self.activation_distance)
            candidates += [(_SELF, i, j) for i, j in zip(self._pair_a[near].tolist(),
                                                         self._pair_b[near].tolist())]
        self.last_queries = len(candidates)
        if not candidates:
            return Rows.empty(nv)
        # Signed distances, witness points and normals of the candidates.
        placed = set()
        found = []
        for kind, i, j in candidates:
            if kind == _SELF and self._capsule[i] and self._capsule[j]:
                d, point_a, point_b, normal = capsule_distance(
                    centers[i].tolist(), part_rotations[i][:, 2].tolist(), *self._half_radius[i],
                    centers[j].tolist(), part_rotations[j][:, 2].tolist(), *self._half_radius[j])
                if d <= self.activation_distance:
                    found.append((kind, d, i, j, point_a, point_b, normal))
                continue
            for k in ((i, j) if kind == _SELF else (i,)):
                if k not in placed:
                    self._parts[k].setRotation(part_rotations[k])
                    self._parts[k].setTranslation(centers[k])
                    placed.add(k)
            other = self._parts[j] if kind == _SELF else self._objects[j]
            d, point_a, point_b, normal, _ = signed_distance(self._parts[i], other)
            if d <= self.activation_distance:
                found.append((kind, d, i, j, point_a, point_b, normal))
        if not found:
            return Rows.empty(nv)
        obstacle_rows = sorted((f for f in found if f[0] == _OBSTACLE), key=lambda f: f[1])
        found = ([f for f in found if f[0] == _TABLE] + obstacle_rows[:self.max_obstacle_rows]
                 + [f for f in found if f[0] == _SELF])
        # The rows, all at once: row = -T n^T (J_a(p_a) - J_b(p_b)), J_b = 0 off the arm.
        distance = np.array([f[1] for f in found])
        normal = np.array([f[6] for f in found])
        frames = [self._part_frames[f[2]] for f in found]
        points = [f[4] for f in found]
        directions = list(normal)
        moving_b = [k for k, f in enumerate(found) if f[0] == _SELF]
        frames += [self._part_frames[found[k][3]] for k in moving_b]
        points += [found[k][5] for k in moving_b]
        directions += [-normal[k] for k in moving_b]
        rates = point_rows(snapshot, frames, np.array(points), np.array(directions))
        matrix = rates[:len(found)]
        if moving_b:
            matrix[moving_b] += rates[len(found):]
        names = tuple(self._self_names[self._pair_index(f[2], f[3])] if f[0] == _SELF
                      else self._names[f[2]][f[3]] for f in found)
        return Rows(-self.horizon * matrix, distance - self.safe_distance, names)

    def _pair_index(self, a: int, b: int) -> int:
        return int(np.flatnonzero((self._pair_a == a) & (self._pair_b == b))[0])
