"""The distance rows: the robot parts (pusher, link capsules) keep a safe distance from the table,
from the obstacles and from each other.

For each pair (robot part a, object b) closer than the activation distance, the collision scene
gives the signed distance ``d``, the witness points ``p_a`` (on a) and ``p_b`` (on b) and the unit
normal ``n`` from b towards a (:func:`~ahrm_stack.kinematics.scene.signed_distance`: coal, guarded
so that no query can fail or abort the process; two capsules in closed form,
:func:`~ahrm_stack.kinematics.scene.capsule_distance`). With ``J_a`` the linear Jacobian of the witness
point ``p_a`` carried by part a (and ``J_b`` that of ``p_b`` carried by part b, zero for the table,
the obstacles and the base), the row is

    d + horizon * n^T (J_a - J_b) u >= d_safe     stored as   -horizon * n^T (J_a - J_b) u <= d - d_safe.

Rows against the table are named ``table:<part>`` (one per moving part at most); rows against
obstacles ``obstacle:<part>/<obstacle>``, of which only the ``max_obstacle_rows`` nearest are kept;
rows between two parts of the arm (the configured self-collision pairs) ``self:<a>/<b>``, all kept.
The base never moves: it only takes part in self-collision pairs. Pairs that cannot be within the
activation distance are skipped without a query, by a bound of each part's bounding ball against
each object's world-aligned bounding box (or the other part's ball), then, for a pair of parts, by
the distance of each one's centre to the other's segment (:func:`_segment_bound`). Obstacle pairs
are measured nearest bound first; once ``max_obstacle_rows`` are found, a pair whose bound exceeds
the farthest of them is not measured (it could not be among the nearest). These skips change no row.

The per-call work is set up once: a ``coal.ComputeDistance`` per pair of shapes, a ``Transform3s``
per robot part updated in place, one reused ``DistanceResult``
(:func:`~ahrm_stack.kinematics.scene.placed_signed_distance`, bit for bit what ``signed_distance``
answers; its guarded path where that one would take it), the pairs' names and indices in tables.
``tests/distance_rows_reference.py`` keeps the routine before this, which the tests hold this one to
(the same rows, bit for bit) and ``benchmarks/bench_distance_rows.py`` times this one against.
"""

from __future__ import annotations

import bisect
import math
from typing import Mapping, Sequence

import coal
import numpy as np

from ahrm_stack.kinematics.scene import (CollisionScene, bounding_radius, capsule_distance_floats,
                                         local_extent, placed_signed_distance, signed_distance)
from ahrm_stack.safety.constraints.base import ArmSnapshot, ConstraintDefinitionError, Rows

TABLE = "table"
_TABLE, _OBSTACLE, _SELF = 0, 1, 2  # kinds of row, in the order they are stacked
# m: an obstacle candidate whose distance's lower bound exceeds the farthest of the nearest
# max_obstacle_rows found by more than this is not measured. Far above coal's error on separated
# shapes (~3e-7 m with the scene's GJK tolerance), so no measured distance falls below the bound.
# Likewise a self-collision candidate whose lower bound (:func:`_segment_bound`) exceeds the
# activation distance by more than this.
PRUNE_MARGIN = 1e-5


def _segment_bound(center_a: list[float], axis_a: list[float], half_a: float, radius_a: float,
                   center_b: list[float], axis_b: list[float], half_b: float, radius_b: float) -> float:
    """A lower bound (m) of the distance between two capsules (segments ``center +- half * axis``,
    ``axis`` a unit vector, swept by ``radius``), or between shapes they enclose (a cylinder of
    that radius and half length): the distance from each centre to the other segment, less the
    own half length (every point of a segment is within its half length of its centre), the larger
    of the two, less both radii. Plain floats (it runs for every self-collision candidate)."""
    wx, wy, wz = center_b[0] - center_a[0], center_b[1] - center_a[1], center_b[2] - center_a[2]
    ux, uy, uz = axis_a
    t = min(max(wx * ux + wy * uy + wz * uz, -half_a), half_a)
    ex, ey, ez = wx - t * ux, wy - t * uy, wz - t * uz
    vx, vy, vz = axis_b
    s = min(max(-(wx * vx + wy * vy + wz * vz), -half_b), half_b)
    fx, fy, fz = wx + s * vx, wy + s * vy, wz + s * vz
    return max(math.sqrt(ex * ex + ey * ey + ez * ez) - half_b,
               math.sqrt(fx * fx + fy * fy + fz * fz) - half_a) - radius_a - radius_b


class DistanceLimit:
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
        self._pair_parts = pairs  # (part a, part b) of each self pair, plain ints
        # A frame at each part's origin, fixed to the frame carrying it, as the scene placed it.
        self._part_frames = [snapshot.attach_frame(f"safety/{name}", int(part_frames[name]),
                                                   obj.getTranslation(), obj.getRotation())
                             for name, obj in zip(self.part_names, self._parts)]
        # Column 0 is the table, then the obstacles.
        self.object_names = (TABLE,) + tuple(n for n in scene.environment if n.startswith("obstacle_"))
        self._objects = [scene.environment[name] for name in self.object_names]
        self._part_radius = np.array([bounding_radius(o.collisionGeometry()) for o in self._parts])
        self._pair_radius = (self._part_radius[self._pair_a], self._part_radius[self._pair_b])
        self._moving_radius = self._part_radius[self._moving, None]
        # the moving parts' rows of the placements: a slice when they are consecutive (no copy)
        first = int(self._moving[0]) if len(self._moving) else 0
        consecutive = np.array_equal(self._moving, np.arange(first, first + len(self._moving)))
        self._moving_rows = slice(first, first + len(self._moving)) if consecutive else self._moving
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
        # Set up once for the queries: each part's placement (updated in place), one result, and
        # a distance functor per (part, object) and per self pair that coal answers.
        self._transforms = [coal.Transform3s() for _ in self._parts]
        self._result = coal.DistanceResult()
        moving = set(self._moving.tolist())
        self._object_compute = [[coal.ComputeDistance(part.collisionGeometry(), obj.collisionGeometry())
                                 for obj in self._objects] if i in moving else []
                                for i, part in enumerate(self._parts)]
        self._self_compute = [None if self._capsule[a] and self._capsule[b] else
                              coal.ComputeDistance(self._parts[a].collisionGeometry(),
                                                   self._parts[b].collisionGeometry())
                              for a, b in pairs]
        self.last_queries = 0  # distance queries made by the last call (after the bounding test)
        # Per-call work space: the parts' world positions (m), the moving parts' rows of it (a view
        # when they are consecutive), the table's box as the bounding test takes it.
        # the parts' centres, then the table's (fixed) origin: one array for the bounding test
        self._points = np.zeros((len(self._parts) + 1, 3))
        self._points[-1] = self._table_origin
        self._centers = self._points[:-1]
        # The bounding test without obstacles in one pass: each moving part's ball against the table's
        # box, then each self pair's two balls (a box of half size 0 about the second centre).
        moving_count = len(self._moving)
        self._near_first = np.concatenate((self._moving, self._pair_a)).astype(int)
        self._near_second = np.concatenate((np.full(moving_count, len(self._parts)), self._pair_b)).astype(int)
        self._near_half = np.concatenate((np.tile(self._table_half, (moving_count, 1)), np.zeros((len(pairs), 3))))
        self._near_radius = np.concatenate((self._part_radius[self._moving],
                                            self._part_radius[self._pair_a] + self._part_radius[self._pair_b]))
        self._near_kinds = ([(_TABLE, part, 0) for part in self._moving.tolist()]
                            + [(_SELF, a, k) for k, (a, _) in enumerate(pairs)])
        self._moving_list = self._moving.tolist()
        self._table_origins, self._table_halves = self._table_origin[None], self._table_half[None]
        self._moving_view = (self._centers[self._moving_rows][:, None, :]
                             if isinstance(self._moving_rows, slice) else None)

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
        centers = self._centers
        placed = snapshot.place(self._part_frames, centers)  # rotations only where a query needs them
        candidates = []  # (kind, part index, object index or self pair index)
        ranked: list[tuple[float, int, int]] = []  # obstacle candidates: (lower bound, part, object)
        if table and self_collision and not obstacles:  # the default rows: one bounding test
            points = self._points
            gap = np.abs(points[self._near_first] - points[self._near_second])
            np.subtract(gap, self._near_half, out=gap)
            np.maximum(gap, 0.0, out=gap)
            reach = np.sqrt(np.einsum("ij,ij->i", gap, gap))
            np.subtract(reach, self._near_radius, out=reach)
            kinds = self._near_kinds
            candidates = [kinds[k] for k in (reach <= self.activation_distance).nonzero()[0].tolist()]
        elif table or obstacles:
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
                origins, half = self._table_origins, self._table_halves
            moving_centers = (self._moving_view if self._moving_view is not None
                              else centers[self._moving][:, None, :])
            gap = np.abs(moving_centers - origins)
            np.subtract(gap, half, out=gap)
            np.maximum(gap, 0.0, out=gap)
            reach = np.sqrt(np.einsum("ijk,ijk->ij", gap, gap))
            np.subtract(reach, self._moving_radius, out=reach)
            parts, objects = (reach <= self.activation_distance).nonzero()
            moving = self._moving_list
            if obstacles:
                bounds = reach[parts, objects].tolist()
                for p, j, bound in zip(parts.tolist(), (objects + first).tolist(), bounds):
                    if j == 0:
                        candidates.append((_TABLE, moving[p], 0))
                    else:
                        ranked.append((bound, moving[p], j))
            else:
                candidates += [(_TABLE, moving[p], 0) for p in parts.tolist()]
        if self_collision and (obstacles or not table):
            offset = centers[self._pair_a] - centers[self._pair_b]
            reach = np.sqrt(np.einsum("ij,ij->i", offset, offset)) - self._pair_radius[0] - self._pair_radius[1]
            near = (reach <= self.activation_distance).nonzero()[0]
            candidates += [(_SELF, self._pair_parts[k][0], k) for k in near.tolist()]
        if not (candidates or ranked):
            return Rows.empty(nv)
        # Signed distances, witness points and normals of the candidates: (kind, d, part, object
        # or pair index, 9 floats: witness on the part, witness on the other, normal towards the part).
        found, nearest = self._measure(candidates, ranked, snapshot, placed)
        if not (found or nearest):
            return Rows.empty(nv)
        table_rows = [f for f in found if f[0] == _TABLE]
        found = table_rows + nearest + [f for f in found if f[0] == _SELF] if table_rows else nearest + found
        # The rows, all at once: row = -T n^T (J_a(p_a) - J_b(p_b)), J_b = 0 off the arm; the
        # self rows (last) get -n^T J_b(p_b) as rows of their own, added below.
        count = len(found)
        carriers = [f[2] for f in found]  # the part carrying each witness point
        witnesses = [f[4][:3] for f in found]
        directions: list = [f[4][6:] for f in found]
        own = count
        for f in found:
            if f[0] == _SELF:
                own -= 1
                b = self._pair_parts[f[3]][1]
                carriers.append(b)
                witnesses.append(f[4][3:6])
                directions.append(tuple(-x for x in f[4][6:]))
        part_frames = self._part_frames
        rates = snapshot.point_rows([part_frames[k] for k in carriers], np.array(witnesses),
                                    np.array(directions), centers[carriers])
        matrix = rates[:count]
        if own < count:
            matrix[own:] += rates[count:]
        names = tuple([self._self_names[f[3]] if f[0] == _SELF else self._names[f[2]][f[3]] for f in found])
        return Rows(-self.horizon * matrix, np.array([f[1] for f in found]) - self.safe_distance, names)

    def _measure(self, candidates: list[tuple[int, int, int]], ranked: list[tuple[float, int, int]],
                 snapshot: ArmSnapshot, placed: list) -> tuple[list, list]:
        """The candidates within the activation distance, measured: one tuple (kind, d, a, b,
        the 9 floats of witness a, witness b, normal) each, in the candidates' order; ``b`` is
        the object index for table and obstacle rows, the pair index for self rows (a self pair
        whose :func:`_segment_bound` exceeds the activation distance by ``PRUNE_MARGIN`` is not
        measured: it could give no row). Then the
        obstacle candidates ``ranked`` (lower bound of the distance, part, object; in the
        bounding test's order): the ``max_obstacle_rows`` nearest within the activation
        distance, ordered by distance and, on ties, by their place in ``ranked`` (as a stable
        sort of all of them would order them). Those measured in order of their lower bound,
        and once ``max_obstacle_rows`` are found, a candidate whose lower bound exceeds both
        ``PRUNE_MARGIN`` and the farthest of them by ``PRUNE_MARGIN`` is not measured: its
        distance is at least its lower bound, so it could not be among them. Counts the queries
        in ``last_queries``."""
        centers = self._centers
        centers_list = centers.tolist()
        rotations: list = [None] * len(self._parts)  # world rotation of each part, when needed

        def rotation(k: int) -> np.ndarray:
            if rotations[k] is None:
                rotations[k] = snapshot.world_rotation(placed[k])
            return rotations[k]

        transforms, placed_parts = self._transforms, [False] * len(self._parts)
        result, activation = self._result, self.activation_distance
        objects: dict[int, tuple[coal.Transform3s, list[float]]] = {}  # object index -> transform, origin

        def against_object(a: int, j: int) -> tuple[float, ...]:
            if not placed_parts[a]:
                transforms[a].setRotation(rotation(a))
                transforms[a].setTranslation(centers[a])
                placed_parts[a] = True
            other = objects.get(j)
            if other is None:
                obj = self._objects[j]
                other = objects[j] = (obj.getTransform(), obj.getTranslation().tolist())
            return (placed_signed_distance(self._object_compute[a][j], result, transforms[a],
                                           other[0], centers_list[a], other[1])
                    or self._guarded(a, self._objects[j], rotation))

        axes: list = [None] * len(self._parts)  # each part's world axis (local z): x, y, z

        def axis(k: int) -> list[float]:
            if axes[k] is None:
                axes[k] = rotation(k)[:, 2].tolist()
            return axes[k]

        half_radius = self._half_radius
        found = []
        queries = 0
        for kind, i, j in candidates:
            if kind == _SELF:
                a, b = self._pair_parts[j]
                axis_a, axis_b = axis(a), axis(b)
                if (_segment_bound(centers_list[a], axis_a, *half_radius[a], centers_list[b], axis_b, *half_radius[b])
                        > activation + PRUNE_MARGIN):
                    continue  # farther than the activation distance: no row, no query
                queries += 1
                compute = self._self_compute[j]
                if compute is None:  # two capsules: closed form
                    answer = capsule_distance_floats(centers_list[a], axis_a, *half_radius[a],
                                                     centers_list[b], axis_b, *half_radius[b])
                else:
                    for k in (a, b):
                        if not placed_parts[k]:
                            transforms[k].setRotation(rotation(k))
                            transforms[k].setTranslation(centers[k])
                            placed_parts[k] = True
                    answer = (placed_signed_distance(compute, result, transforms[a], transforms[b],
                                                     centers_list[a], centers_list[b])
                              or self._guarded(a, rotation=rotation, b=b))
            else:
                a = i
                queries += 1
                answer = against_object(a, j)
            if answer[0] <= activation:
                found.append((kind, answer[0], a, j, answer[1:]))
        keep = self.max_obstacle_rows
        nearest: list = []
        if ranked:
            order = sorted(range(len(ranked)), key=lambda k: ranked[k][0]) if len(ranked) > keep else range(len(ranked))
            kept: list[float] = []  # the distances found, ascending
            for k in order:
                bound, a, j = ranked[k]
                if len(kept) >= keep and bound > PRUNE_MARGIN and bound - PRUNE_MARGIN > kept[keep - 1]:
                    break  # this and every later candidate: lower bound beyond the nearest found
                answer = against_object(a, j)
                queries += 1
                if answer[0] <= activation:
                    nearest.append((answer[0], k, (_OBSTACLE, answer[0], a, j, answer[1:])))
                    bisect.insort(kept, answer[0])
            nearest.sort(key=lambda n: (n[0], n[1]))
            nearest = [n[2] for n in nearest[:keep]]
        self.last_queries = queries
        return found, nearest

    def _guarded(self, a: int, other: coal.CollisionObject | None = None, rotation=None,
                 b: int | None = None) -> tuple[float, ...]:
        """:func:`signed_distance` itself on the scene's objects, placed (part ``a`` against
        ``other``, or against part ``b``; ``rotation(k)`` gives part k's world rotation): the
        guarded answer (counted in ``GUARD``), as the ten floats of ``placed_signed_distance``."""
        centers = self._centers
        for k in (a,) if b is None else (a, b):
            self._parts[k].setRotation(rotation(k))
            self._parts[k].setTranslation(centers[k])
        d, point_a, point_b, normal, _ = signed_distance(self._parts[a], self._parts[b] if b is not None else other)
        return (d, *point_a.tolist(), *point_b.tolist(), *normal.tolist())
