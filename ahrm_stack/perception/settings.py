"""The perception settings (``configs/perception.yaml``): sections of the project's configuration
system (:mod:`ahrm_stack.schema`: the rules sit beside the fields).

Every error is one line that names the key and the file (``perception.camera.fovy_deg must be in
(0, 180), got 180.0 (configs/perception.yaml)``); nothing is built before the whole file has passed.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

import numpy as np
from pydantic import AfterValidator

from ahrm_stack.config import CONFIG_DIR, ConfigError
from ahrm_stack.hardware.scene import UNIT_TOLERANCE
from ahrm_stack.schema import (Bool, Float, Int, Section, Str, fail, ge, gt, load_file, unit_quaternion, validate,
                               within)

PERCEPTION_CONFIG = CONFIG_DIR / "perception.yaml"
#: The families pupil-apriltags can detect (``pupil_apriltags.Detector(families=...)``).
TagFamily = Literal["tag16h5", "tag25h9", "tag36h11", "tagCircle21h7", "tagCircle49h12",
                    "tagCustom48h12", "tagStandard41h12", "tagStandard52h13"]
TAG_FAMILIES: tuple[str, ...] = typing.get_args(TagFamily)

Vec3 = tuple[Float, Float, Float]
Vec4 = tuple[Float, Float, Float, Float]
Pos = Annotated[Float, gt(0)]
NonNeg = Annotated[Float, ge(0)]


class PerceptionConfigError(ConfigError):
    """A perception setting or a layout file is missing, unknown or invalid; names the key."""


def _focal_lengths(value: tuple[float, ...] | None) -> tuple[float, ...] | None:
    if value is not None and (value[0] <= 0 or value[1] <= 0):
        fail(f": fx and fy must be > 0, got {list(value)}")
    return value


@dataclasses.dataclass(frozen=True)
class CameraSettings(Section):
    width: Annotated[Int, ge(16)]  # px
    height: Annotated[Int, ge(16)]  # px
    fovy_deg: Annotated[Float, within(0, 180, "()")]  # vertical field of view, degrees
    # fx, fy, cx, cy (px); None: from fovy
    intrinsics: Annotated[Optional[Vec4], AfterValidator(_focal_lengths)]
    # OpenCV (k1, k2, p1, p2, k3) of a calibrated camera; None: none (a pinhole)
    distortion: Optional[tuple[Float, Float, Float, Float, Float]]
    # a calibration command's file (intrinsics, distortion; extrinsics when measured); '' none
    calibration_file: Str
    position: Vec3  # optical centre, m, world frame
    look_at: Optional[Vec3]  # m, world frame
    # camera-to-world (w, x, y, z), optical frame; normalised when read
    quaternion: Annotated[Optional[Vec4], unit_quaternion(UNIT_TOLERANCE)]

    def check(self, key: str) -> None:
        if (self.look_at is None) == (self.quaternion is None):
            raise ConfigError(f"{key}: give exactly one of look_at and quaternion (got look_at "
                              f"{_listed(self.look_at)}, quaternion {_listed(self.quaternion)})")
        if self.look_at is not None:
            axis = np.subtract(self.look_at, self.position)
            length = np.linalg.norm(axis)
            if length < 1e-6 or np.linalg.norm(np.cross(axis, [0, 0, 1])) < 1e-6 * length:
                raise ConfigError(f"{key}.look_at {list(self.look_at)} must differ from "
                                  f"camera.position {list(self.position)} and not lie straight above "
                                  "or below it (the image's up would be undefined)")


def _listed(value: tuple[float, ...] | None) -> list[float] | None:
    return None if value is None else list(value)


@dataclasses.dataclass(frozen=True)
class TagSettings(Section):
    family: TagFamily
    id: Annotated[Int, ge(0)]
    size: Pos  # m, black-square edge
    texture_cell_px: Annotated[Int, within(1, 256)]  # sim texture pixels per tag cell


@dataclasses.dataclass(frozen=True)
class DetectorSettings(Section):
    threads: Annotated[Int, ge(1)]
    quad_decimate: Annotated[Float, ge(1.0)]
    quad_sigma: NonNeg  # px
    refine_edges: Bool
    decode_sharpening: NonNeg
    max_hamming: Annotated[Int, within(0, 2)]
    min_decision_margin: NonNeg
    pose_iterations: Annotated[Int, ge(1)]
    ambiguity_ratio: Annotated[Float, ge(1.0)]


@dataclasses.dataclass(frozen=True)
class TrackerSettings(Section):
    position_noise: Pos  # m
    acceleration_noise: Pos  # m/s^2/sqrt(Hz)
    initial_velocity_noise: Pos  # m/s
    max_hold: NonNeg  # s


@dataclasses.dataclass(frozen=True)
class SimCameraSettings(Section):
    offscreen_samples: Annotated[Int, within(0, 16)]


#: Where ``--scene camera`` takes its frames from (:mod:`ahrm_stack.perception.frames`).
SourceKind = Literal["sim", "video", "uvc", "realsense"]


@dataclasses.dataclass(frozen=True)
class SourceSettings(Section):
    kind: SourceKind
    video_file: Str  # kind video: a file or image-sequence pattern (frame_%04d.png) OpenCV reads
    device: Annotated[Int, ge(0)]  # kind uvc: the /dev/videoN index
    fps: Pos  # frames/s requested from a camera; a video file is played at this rate
    loop: Bool  # kind video: start over at the end (else the end is a perception fault)
    isolation: Literal["process", "thread"]  # where a real source's capture and detection run

    def check(self, key: str) -> None:
        if self.kind == "video" and not self.video_file:
            raise ConfigError(f"{key}.video_file: give the video file with kind video")


#: The calibration board's kinds and OpenCV's predefined ArUco dictionaries it may use.
BoardKind = Literal["charuco", "chessboard"]


@dataclasses.dataclass(frozen=True)
class BoardSettings(Section):
    kind: BoardKind
    squares: tuple[Annotated[Int, ge(3)], Annotated[Int, ge(3)]]  # squares along x, y
    square_size: Pos  # m, edge of one square
    marker_size: Pos  # m, edge of a ChArUco marker (< square_size)
    dictionary: Str  # cv2.aruco predefined dictionary name, e.g. DICT_4X4_50
    min_views: Annotated[Int, ge(3)]  # views with the board found, at least

    def check(self, key: str) -> None:
        if self.kind == "charuco" and self.marker_size >= self.square_size:
            raise ConfigError(f"{key}.marker_size {self.marker_size} must be below square_size "
                              f"{self.square_size}")


@dataclasses.dataclass(frozen=True)
class ReferenceTagSettings(Section):
    family: TagFamily
    id: Annotated[Int, ge(0)]
    size: Pos  # m, black-square edge
    position: Vec3  # m, world frame: the tag's centre, surveyed on the table
    yaw_deg: Float  # degrees about world z; 0: the tag image's right along world +x, up along +y


@dataclasses.dataclass(frozen=True)
class CalibrationSettings(Section):
    board: BoardSettings
    reference_tag: ReferenceTagSettings
    frames: Annotated[Int, ge(1)]  # extrinsics: frames averaged


@dataclasses.dataclass(frozen=True)
class PerceptionSettings(Section):
    camera: CameraSettings
    source: SourceSettings
    tag: TagSettings
    detector: DetectorSettings
    tracker: TrackerSettings
    sim: SimCameraSettings
    calibration: CalibrationSettings
    layout_file: Str  # '' for none


def perception_settings_from_dict(data: Any) -> PerceptionSettings:
    """Validate a parsed ``perception.yaml``; :class:`PerceptionConfigError` names the first bad
    key."""
    return validate(PerceptionSettings, data, "perception", error=PerceptionConfigError)


def load_perception_settings(path: Path | str = PERCEPTION_CONFIG) -> PerceptionSettings:
    """Read and validate ``path``; errors are one line naming the key and the file. The camera's
    ``calibration_file`` is applied by
    :func:`ahrm_stack.perception.calibration.load_calibrated_settings`."""
    return load_file(PerceptionSettings, path, "perception", error=PerceptionConfigError)
