"""Pinhole camera geometry: intrinsics, the camera's pose in the world, rotations.

Frames: the *optical* camera frame of OpenCV and AprilTag (x right, y down, z forward along the
optical axis); MuJoCo's camera frame looks along its -z with y up, so ``R_mujoco = R_optical @
diag(1, -1, -1)``. Pixel coordinates are continuous, (0, 0) at the top-left corner of the first
pixel, so a pixel's centre is at (i + 0.5, j + 0.5) — the convention of MuJoCo's renderer and of
the AprilTag detector's corners (checked in ``tests/test_perception.py``). Quaternions are
(w, x, y, z).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrm_stack.arms.urdf import matrix_to_quaternion  # noqa: F401 - the perception's too
from ahrm_stack.perception.settings import CameraSettings

#: MuJoCo camera frame from the optical frame (and back: it is its own inverse).
OPTICAL_TO_MUJOCO = np.diag([1.0, -1.0, -1.0])


def quaternion_to_matrix(q) -> np.ndarray:
    """The rotation matrix of the unit quaternion ``q`` = (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def look_at_rotation(position, target) -> np.ndarray:
    """Camera-to-world rotation (optical frame) of a camera at ``position`` whose optical axis
    passes through ``target`` (m, world) and whose image up is on world +z's side."""
    forward = np.subtract(target, position).astype(float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics, px: focal lengths ``fx``, ``fy`` and principal point ``cx``, ``cy``
    (continuous pixel coordinates), for an image of ``width`` × ``height`` px."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_fovy(cls, fovy_deg: float, width: int, height: int) -> "Intrinsics":
        """Square pixels, principal point at the image centre: a MuJoCo camera's intrinsics,
        ``f = height / 2 / tan(fovy / 2)``."""
        f = height / 2.0 / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(f, f, width / 2.0, height / 2.0, width, height)

    @classmethod
    def from_settings(cls, camera: CameraSettings) -> "Intrinsics":
        if camera.intrinsics is not None:
            fx, fy, cx, cy = camera.intrinsics
            return cls(fx, fy, cx, cy, camera.width, camera.height)
        return cls.from_fovy(camera.fovy_deg, camera.width, camera.height)

    @property
    def params(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy), as ``pupil_apriltags`` takes them."""
        return (self.fx, self.fy, self.cx, self.cy)

    def project(self, points) -> np.ndarray:
        """Pixel coordinates (…, 2) of points (…, 3) given in the optical frame, m."""
        p = np.asarray(points, dtype=float)
        return np.stack([self.fx * p[..., 0] / p[..., 2] + self.cx,
                         self.fy * p[..., 1] / p[..., 2] + self.cy], axis=-1)


@dataclasses.dataclass(frozen=True)
class CameraPose:
    """The camera's pose in the world: ``position`` (m) of the optical centre and ``rotation``
    (camera-to-world, optical frame), so that ``p_world = rotation @ p_camera + position``."""

    position: np.ndarray
    rotation: np.ndarray

    @classmethod
    def from_settings(cls, camera: CameraSettings) -> "CameraPose":
        position = np.asarray(camera.position, dtype=float)
        if camera.quaternion is not None:
            rotation = quaternion_to_matrix(camera.quaternion)
        else:
            rotation = look_at_rotation(position, camera.look_at)
        return cls(position, rotation)

    def to_world(self, points) -> np.ndarray:
        """World coordinates (…, 3) of points given in the optical frame, m."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.position

    def to_camera(self, points) -> np.ndarray:
        """Optical-frame coordinates (…, 3) of world points, m."""
        return (np.asarray(points, dtype=float) - self.position) @ self.rotation

    @property
    def mujoco_quaternion(self) -> np.ndarray:
        """The quaternion (w, x, y, z) of a MuJoCo ``<camera>`` with this orientation."""
        return matrix_to_quaternion(self.rotation @ OPTICAL_TO_MUJOCO)
