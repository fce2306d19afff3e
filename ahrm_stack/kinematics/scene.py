"""FCL collision scene: the pusher and link capsules of the arm, the table, cube, obstacles and the
two phase regions, with signed distances and witness points between them.

Link capsules are derived from the robot description itself: each link's collision mesh, as MuJoCo
compiled it, is enclosed by the tightest capsule along the mesh's principal axis
(:func:`fit_capsule`), so no link dimension is written by hand.

python-fcl sizes are full lengths (``fcl.Box(2 hx, 2 hy, 2 hz)``, ``fcl.Cylinder(r, 2 h)``,
``fcl.Capsule(r, segment length)``); distances are signed (``enable_signed_distance=True``), with a
fresh ``DistanceResult`` per query. Units: metres, world frame.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import fcl
import mujoco
import numpy as np

from ahrm_stack.kinematics.model import ArmKinematics
from ahrm_stack.kinematics.phases import Box

_REQUEST = fcl.DistanceRequest(enable_signed_distance=True, enable_nearest_points=True)


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


def link_capsules(model: mujoco.MjModel, arm_bodies: Sequence[tuple[int, str]]) -> list[Capsule]:
    """One capsule per arm body that carries collision meshes, from MuJoCo's compiled vertices.

    ``arm_bodies``: (MuJoCo body id, arm-model frame name) pairs.
    """
    capsules = []
    for body_id, frame in arm_bodies:
        points = []
        for geom in range(model.ngeom):
            if model.geom_bodyid[geom] != body_id or model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH:
                continue
            if model.geom_contype[geom] == 0 and model.geom_conaffinity[geom] == 0:
                continue  # visual only
            mesh = model.geom_dataid[geom]
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            vertices = np.asarray(model.mesh_vert[start:start + count], dtype=float)
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
            points.append(vertices @ rotation.reshape(3, 3).T + model.geom_pos[geom])
        if points:
            capsules.append(fit_capsule(np.concatenate(points), frame))
    return capsules


@dataclasses.dataclass(frozen=True)
class Distance:
    """Signed distance (m) between two named objects and the witness points on each (world)."""

    a: str
    b: str
    distance: float
    point_a: np.ndarray
    point_b: np.ndarray


def _transform(rotation: np.ndarray, translation: np.ndarray) -> fcl.Transform:
    return fcl.Transform(np.ascontiguousarray(rotation, dtype=float),
                         np.ascontiguousarray(translation, dtype=float))


def _capsule_rotation(direction: np.ndarray) -> np.ndarray:
    """A rotation whose z axis is ``direction`` (FCL capsules and cylinders lie along local z)."""
    z = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


class CollisionScene:
    """FCL objects for the robot parts (``pusher`` and one capsule per link) and the environment
    (``table``, ``cube``, ``obstacle_i``, ``B_target``, ``B_obstacles``).

    Robot parts are placed from :class:`ArmKinematics` (call ``update_robot`` after
    ``kinematics.update(q)``); environment objects from poses (``update_objects``).
    """

    def __init__(self, kinematics: ArmKinematics, capsules: Sequence[Capsule], pusher_frame: str,
                 pusher_radius: float, pusher_half_length: float, table_half_extent: Sequence[float],
                 table_height: float, table_thickness: float, cube_size: float,
                 obstacle_half_sizes: np.ndarray) -> None:
        self.kinematics = kinematics
        self.capsules = list(capsules)
        self._capsule_frames = [kinematics.frame_id(c.frame) for c in self.capsules]
        self._capsule_local = []
        self.robot: dict[str, fcl.CollisionObject] = {}
        for capsule in self.capsules:
            length = capsule.length
            rotation = _capsule_rotation(capsule.end - capsule.start) if length > 0 else np.eye(3)
            self._capsule_local.append((rotation, capsule.center))
            self.robot[capsule.frame] = fcl.CollisionObject(fcl.Capsule(capsule.radius, length))
        self._pusher_frame = kinematics.frame_id(pusher_frame)
        self.robot["pusher"] = fcl.CollisionObject(fcl.Cylinder(pusher_radius, 2 * pusher_half_length))
        hx, hy = table_half_extent
        self.table_top = table_height
        self.environment: dict[str, fcl.CollisionObject] = {
            "table": fcl.CollisionObject(fcl.Box(2 * hx, 2 * hy, table_thickness),
                                         _transform(np.eye(3), [0, 0, table_height - table_thickness / 2])),
            "cube": fcl.CollisionObject(fcl.Box(cube_size, cube_size, cube_size)),
        }
        for i, half in enumerate(np.asarray(obstacle_half_sizes, dtype=float)):
            self.environment[f"obstacle_{i}"] = fcl.CollisionObject(fcl.Box(*(2 * half)))
        self._regions: dict[str, fcl.CollisionObject] = {}

    def update_robot(self) -> None:
        """Place the pusher and the link capsules at the kinematics' current configuration."""
        for (name, obj), fid, (rotation, center) in zip(
                self.robot.items(), self._capsule_frames, self._capsule_local):
            position, frame_rotation = self.kinematics.frame_pose(fid)
            obj.setTransform(_transform(frame_rotation @ rotation, position + frame_rotation @ center))
            del name
        position, rotation = self.kinematics.frame_pose(self._pusher_frame)
        self.robot["pusher"].setTransform(_transform(rotation, position))

    def update_objects(self, cube_position: np.ndarray, cube_rotation: np.ndarray,
                       obstacle_positions: np.ndarray, obstacle_rotations: np.ndarray,
                       regions: dict[str, Box] | None = None) -> None:
        """Place the cube, the obstacles (positions m, rotation matrices) and the phase regions."""
        self.environment["cube"].setTransform(_transform(cube_rotation, cube_position))
        for i, (p, r) in enumerate(zip(obstacle_positions, obstacle_rotations)):
            self.environment[f"obstacle_{i}"].setTransform(_transform(r, p))
        for name, box in (regions or {}).items():
            obj = fcl.CollisionObject(fcl.Box(*(2 * np.asarray(box.half_size))))
            obj.setTransform(_transform(np.eye(3), box.center))
            self.environment[name] = obj

    def distance(self, robot_part: str, other: str) -> Distance:
        """Signed distance and witness points between a robot part and an environment object."""
        result = fcl.DistanceResult()
        d = fcl.distance(self.robot[robot_part], self.environment[other], _REQUEST, result)
        return Distance(robot_part, other, float(d), np.array(result.nearest_points[0]),
                        np.array(result.nearest_points[1]))

    def distances(self, robot_parts: Sequence[str] | None = None,
                  others: Sequence[str] | None = None) -> list[Distance]:
        """All pairs of ``robot_parts`` (default: all) x ``others`` (default: table and obstacles)."""
        parts = list(self.robot) if robot_parts is None else robot_parts
        if others is None:
            others = ["table"] + [n for n in self.environment if n.startswith("obstacle_")]
        return [self.distance(p, o) for p in parts for o in others]
