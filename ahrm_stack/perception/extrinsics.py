"""The camera's pose in the world (the arm base's frame, ``configs/task.yaml``) from a reference
AprilTag lying flat on the table at a surveyed pose.

The reference tag (``perception.calibration.reference_tag``): its centre at ``position`` (m,
world) and its image turned by ``yaw_deg`` about world z (0: the tag image's right along world
+x, its up along world +y, its face up). In the AprilTag tag frame (x right, y down in the tag
image, z into the tag) that is ``R_world_tag = Rz(yaw) @ diag(1, -1, -1)``.

Per frame the tag's four corners (``pupil_apriltags``; corners in the project's pixel convention,
:mod:`~ahrm_stack.perception.geometry`) give its pose in the optical camera frame by
``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)`` with the calibrated intrinsics and distortion (no
undistorted image needed), and ``T_world_camera = T_world_tag @ inverse(T_camera_tag)``. Over
several frames the optical centres are averaged and the rotations too (the mean rotation matrix
projected back onto SO(3)).
"""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from ahrm_stack.perception.calibration import camera_matrix
from ahrm_stack.perception.geometry import CameraPose
from ahrm_stack.perception.settings import ReferenceTagSettings

#: The tag frame's axes in the world for a tag lying face up at yaw 0 (x right = world +x, y down
#: = world -y, z into the tag = world -z).
FLAT_TAG = np.diag([1.0, -1.0, -1.0])


class ExtrinsicsError(RuntimeError):
    """The reference tag was not seen (often enough); one line."""


def reference_tag_pose(tag: ReferenceTagSettings) -> tuple[np.ndarray, np.ndarray]:
    """(rotation tag-to-world, centre m) of the reference tag (the module docstring)."""
    yaw = math.radians(tag.yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ FLAT_TAG, np.asarray(tag.position, dtype=float)


def tag_corners(size: float) -> np.ndarray:
    """The tag's black-square corners in the tag frame (m), in ``pupil_apriltags``' order (and
    ``SOLVEPNP_IPPE_SQUARE``'s): (-s, s), (s, s), (s, -s), (-s, -s), s = size / 2."""
    s = size / 2.0
    return np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])


def tag_in_camera(corners_px: np.ndarray, size: float, intrinsics, distortion) -> tuple[np.ndarray, np.ndarray]:
    """(rotation tag-to-camera, translation m) of a square tag of edge ``size`` m whose corners
    (4, 2; project pixel convention, detector order) were seen by a camera of ``intrinsics``
    (fx, fy, cx, cy) and OpenCV ``distortion`` (None: none)."""
    from ahrm_stack.perception.frames import _cv2

    cv2 = _cv2()
    image = np.asarray(corners_px, dtype=np.float64).reshape(4, 1, 2) - 0.5  # OpenCV's convention
    dist = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=float)
    ok, rvec, tvec = cv2.solvePnP(tag_corners(size), image, camera_matrix(intrinsics), dist,
                                  flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not ok:
        raise ExtrinsicsError("solvePnP found no pose for the reference tag")
    return cv2.Rodrigues(rvec)[0], tvec.reshape(3)


def camera_from_tag(R_camera_tag: np.ndarray, t_camera_tag: np.ndarray,
                    tag: ReferenceTagSettings) -> CameraPose:
    """The camera's pose in the world from the reference tag's pose in the camera."""
    R_world_tag, p_world_tag = reference_tag_pose(tag)
    rotation = R_world_tag @ R_camera_tag.T
    return CameraPose(p_world_tag - rotation @ t_camera_tag, rotation)


def mean_pose(poses: list[CameraPose]) -> CameraPose:
    """The mean optical centre and the mean rotation (projected onto SO(3) by SVD)."""
    position = np.mean([p.position for p in poses], axis=0)
    U, _, Vt = np.linalg.svd(np.mean([p.rotation for p in poses], axis=0))
    rotation = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return CameraPose(position, rotation)


def measure_extrinsics(frames: Iterable[np.ndarray], tag: ReferenceTagSettings, intrinsics,
                       distortion, count: int, detector_threads: int = 1) -> tuple[CameraPose, float, int]:
    """The camera's pose from the first ``count`` frames (grey uint8) showing the reference tag:
    (mean pose, spread m: the largest distance of one frame's optical centre from the mean,
    frames used). :class:`ExtrinsicsError` when fewer frames show it."""
    from ahrm_stack.perception.detector import Detector

    detector = Detector(families=tag.family, nthreads=detector_threads, quad_decimate=1.0,
                        refine_edges=1)
    poses: list[CameraPose] = []
    seen = 0
    try:
        for gray in frames:
            seen += 1
            found = [d for d in detector.detect(np.ascontiguousarray(gray))
                     if d.tag_id == tag.id and d.hamming == 0]
            if found:
                R, t = tag_in_camera(np.asarray(found[0].corners), tag.size, intrinsics, distortion)
                poses.append(camera_from_tag(R, t, tag))
            if len(poses) >= count:
                break
    finally:
        detector.close()
    if len(poses) < count:
        raise ExtrinsicsError(f"the reference tag ({tag.family} id {tag.id}) was seen in {len(poses)} "
                              f"of {seen} frames; perception.calibration.frames is {count}")
    mean = mean_pose(poses)
    spread = max(float(np.linalg.norm(p.position - mean.position)) for p in poses)
    return mean, spread, len(poses)
