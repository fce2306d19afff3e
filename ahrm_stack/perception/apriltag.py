"""The cube's pose from an AprilTag on its top face (``pupil-apriltags``), and a cube pose source.

One frame: ``pupil_apriltags.Detector.detect(gray)`` finds the tag's corners; its pose in the
optical camera frame (x right, y down, z forward) comes from the same C library's orthogonal
iteration with the camera's (fx, fy, cx, cy) and the tag's size (:func:`tag_pose_solutions`). The
tag frame has its origin at the tag's centre, x right and y down in the tag image, z *into* the
tag. The tag lies on the cube's top face, so the cube's centre is half the cube's size further
along the tag's z (the outward normal is -z), and the cube's axes are the tag's through the fixed
:data:`TAG_TO_CUBE`. The camera's extrinsics (:class:`~ahrm_stack.perception.geometry.CameraPose`)
take both to the world. Of the planar pose ambiguity's two solutions, see :meth:`TagDetector.measure`.

Only detections of the configured family and id, with at most ``detector.max_hamming`` corrected
bits and at least ``detector.min_decision_margin``, count; of several, the one with the largest
margin.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
from typing import Protocol

import numpy as np

from ahrm_stack.perception.geometry import CameraPose, Intrinsics, matrix_to_quaternion
from ahrm_stack.perception.settings import PerceptionSettings
from ahrm_stack.perception.tracker import CubeState, CubeTracker

#: Cube axes in the tag frame (columns: the cube's x, y, z in tag coordinates) for a tag laid on
#: the top face as :func:`~ahrm_stack.perception.tags.tag_face_image` draws it and the sim camera
#: maps it (image right = cube +x, image down = cube -y; the tag's z points into the face, -z_cube).
#: Checked against the simulator's cube orientation in ``tests/test_perception_sim.py``.
TAG_TO_CUBE = np.array([[1.0, 0.0, 0.0],
                        [0.0, -1.0, 0.0],
                        [0.0, 0.0, -1.0]])


@dataclasses.dataclass(frozen=True)
class TagMeasurement:
    """One frame's detection of the cube's tag: the cube's centre ``position`` (m) and
    ``rotation`` (cube-to-world) in the world frame; ``corners`` (4, 2) px; ``decision_margin``;
    ``pose_error`` (the detector's object-space error)."""

    position: np.ndarray
    rotation: np.ndarray
    corners: np.ndarray
    decision_margin: float
    pose_error: float
    ambiguous: bool = False  # two poses within detector.ambiguity_ratio in error
    errors: tuple[float, ...] = ()  # the solutions' errors, lower first
    choice: int = 0  # which solution was taken (1: the prior's)

    @property
    def quaternion(self) -> np.ndarray:
        return matrix_to_quaternion(self.rotation)


class FrameSource(Protocol):
    """A camera: :meth:`grab` returns (timestamp s on the adapter's clock, grey uint8 image
    height × width)."""

    def grab(self) -> tuple[float, np.ndarray]: ...


class CubePoseSource(Protocol):
    """Where the deploy loop's cube comes from: :meth:`cube` returns the current
    :class:`~ahrm_stack.perception.tracker.CubeState` (world frame, m, m/s) or raises a one-line
    error (the loop stops the arm on it)."""

    def cube(self) -> CubeState: ...


@dataclasses.dataclass(frozen=True)
class TagPose:
    """One solution of the tag's pose in the optical camera frame: ``rotation`` (tag-to-camera),
    ``translation`` (m, the tag's centre) and the object-space ``error`` of the fit."""

    rotation: np.ndarray
    translation: np.ndarray
    error: float


def tag_pose_solutions(detector, detection, intrinsics: Intrinsics, tag_size: float,
                       iterations: int) -> list[TagPose]:
    """Both local solutions of a planar tag's pose (the AprilTag library's
    ``estimate_tag_pose_orthogonal_iteration``: the homography's pose refined by orthogonal
    iteration, then the second minimum of the planar ambiguity, refined too), lower error first.

    ``detector``: the ``pupil_apriltags.Detector`` (its C library); ``detection``: one of its
    detections (corners and homography). A small, nearly fronto-parallel tag has two poses of
    almost equal error whose normals differ by tens of degrees; ``pupil_apriltags``'s own
    ``estimate_tag_pose`` keeps only the lower-error one, which is then often the wrong one."""
    from pupil_apriltags import bindings

    lib = detector.libc
    lib.matd_create.restype = ctypes.POINTER(bindings._Matd)
    lib.matd_destroy.restype = None
    lib.estimate_tag_pose_orthogonal_iteration.restype = None
    H = lib.matd_create(3, 3)
    poses = (bindings._ApriltagPose(), bindings._ApriltagPose())
    try:
        bindings._matd_get_array(H)[:, :] = np.asarray(detection.homography, dtype=float)
        det = bindings._ApriltagDetection()
        det.H = H
        for i, (u, v) in enumerate(np.asarray(detection.corners, dtype=float)):
            det.p[i][0], det.p[i][1] = float(u), float(v)
        det.c[0], det.c[1] = (float(x) for x in detection.center)
        info = bindings._ApriltagDetectionInfo(det=ctypes.pointer(det), tagsize=float(tag_size),
                                               fx=intrinsics.fx, fy=intrinsics.fy,
                                               cx=intrinsics.cx, cy=intrinsics.cy)
        errors = (ctypes.c_double(), ctypes.c_double())
        lib.estimate_tag_pose_orthogonal_iteration(
            ctypes.byref(info), ctypes.byref(errors[0]), ctypes.byref(poses[0]),
            ctypes.byref(errors[1]), ctypes.byref(poses[1]), ctypes.c_int(int(iterations)))
        solutions = []
        for pose, error in zip(poses, errors):
            if pose.R and pose.t and math.isfinite(error.value):
                solutions.append(TagPose(bindings._matd_get_array(pose.R).copy(),
                                         bindings._matd_get_array(pose.t).copy().reshape(3),
                                         float(error.value)))
    finally:
        lib.matd_destroy(H)
        for pose in poses:
            for matrix in (pose.R, pose.t):
                if matrix:
                    lib.matd_destroy(matrix)
    return sorted(solutions, key=lambda s: s.error)


class TagDetector:
    """The cube's pose in one grey frame (:meth:`measure`), or None when its tag is not seen."""

    def __init__(self, settings: PerceptionSettings, cube_size: float) -> None:
        from ahrm_stack.perception.detector import Detector

        d = settings.detector
        self.settings = settings
        self.tag = settings.tag
        self.intrinsics = Intrinsics.from_settings(settings.camera)
        self.camera = CameraPose.from_settings(settings.camera)
        self.half_cube = cube_size / 2.0
        self.detector = Detector(families=settings.tag.family, nthreads=d.threads,
                                 quad_decimate=d.quad_decimate, quad_sigma=d.quad_sigma,
                                 refine_edges=int(d.refine_edges),
                                 decode_sharpening=d.decode_sharpening)
        # pupil-apriltags 1.0.4 stores int(decode_sharpening) (0 for 0.25): set the real value
        self.detector.tag_detector_ptr.contents.decode_sharpening = float(d.decode_sharpening)

    @property
    def label(self) -> str:
        return f"tag {self.tag.family} id {self.tag.id}"

    def measure(self, gray: np.ndarray, up: np.ndarray | None = None) -> TagMeasurement | None:
        """Detect the tag in ``gray`` (uint8, height × width of the camera settings); None when it
        is not seen. ``up``: the cube's expected up axis (world; default +z, the cube upright on
        the table), which picks between two poses of nearly equal error (the planar ambiguity:
        the second is taken when its error is below ``detector.ambiguity_ratio`` × the first's
        and its up axis is closer to ``up``)."""
        expected = (self.intrinsics.height, self.intrinsics.width)
        if gray.shape != expected or gray.dtype != np.uint8:
            raise ValueError(f"camera frame is {gray.dtype} {gray.shape}; expected uint8 "
                             f"{expected} (perception.camera height, width)")
        detections = self.detector.detect(np.ascontiguousarray(gray))
        d = self.settings.detector
        good = [x for x in detections
                if x.tag_id == self.tag.id and x.hamming <= d.max_hamming
                and x.decision_margin >= d.min_decision_margin]
        if not good:
            return None
        best = max(good, key=lambda x: x.decision_margin)
        solutions = tag_pose_solutions(self.detector, best, self.intrinsics, self.tag.size,
                                       d.pose_iterations)
        if not solutions:
            return None
        up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
        rotations = [self.camera.rotation @ s.rotation @ TAG_TO_CUBE for s in solutions]
        choice = 0
        if (len(solutions) > 1 and solutions[1].error < d.ambiguity_ratio * solutions[0].error
                and rotations[1][:, 2] @ up > rotations[0][:, 2] @ up):
            choice = 1
        pose = solutions[choice]
        centre_cam = pose.translation + self.half_cube * pose.rotation[:, 2]  # into the cube
        return TagMeasurement(position=self.camera.to_world(centre_cam),
                              rotation=rotations[choice],
                              corners=np.asarray(best.corners, dtype=float),
                              decision_margin=float(best.decision_margin),
                              pose_error=pose.error, ambiguous=len(solutions) > 1
                              and solutions[1].error < d.ambiguity_ratio * solutions[0].error,
                              errors=tuple(x.error for x in solutions), choice=choice)


class AprilTagCubeSource:
    """A :class:`CubePoseSource`: each :meth:`cube` grabs a frame, measures the tag and runs the
    tracker (:class:`~ahrm_stack.perception.tracker.CubeTracker`: velocity, missed frames)."""

    def __init__(self, frames: FrameSource, detector: TagDetector, tracker: CubeTracker) -> None:
        self.frames = frames
        self.detector = detector
        self.tracker = tracker
        self.last: TagMeasurement | None = None  # the last frame's measurement with the tag
        self.measurements = 0  # frames with the tag
        self.ambiguous = 0  # of which with two poses of nearly equal error
        self.frames_read = 0
        self.frame: tuple[int, float] | None = None  # the last frame's (index from 0, capture stamp s)

    @classmethod
    def from_settings(cls, frames: FrameSource, settings: PerceptionSettings,
                      cube_size: float) -> "AprilTagCubeSource":
        detector = TagDetector(settings, cube_size)
        return cls(frames, detector, CubeTracker(settings.tracker, detector.label))

    def cube(self) -> CubeState:
        """Grab, measure (the last measured up axis as the prior; +z at the start), track."""
        time, gray = self.frames.grab()
        self.frame, self.frames_read = (self.frames_read, float(time)), self.frames_read + 1
        up = None if self.last is None else self.last.rotation[:, 2]
        measurement = self.detector.measure(gray, up)
        if measurement is not None:
            self.last = measurement
            self.measurements += 1
            self.ambiguous += int(measurement.ambiguous)
            return self.tracker.update(time, measurement.position, measurement.quaternion)
        return self.tracker.update(time, None)

    def close(self) -> None:
        close = getattr(self.frames, "close", None)
        if close is not None:
            close()
