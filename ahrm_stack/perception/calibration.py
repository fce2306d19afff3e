"""A camera's intrinsics and lens distortion from views of a printed board (OpenCV), the
calibration file that holds them, and undistortion of its frames.

The board (``perception.calibration.board``): OpenCV's ChArUco board (a chessboard whose white
squares hold ArUco markers, so a partial view still counts) or a plain chessboard, ``squares``
along x and y of ``square_size`` m. :func:`calibrate_intrinsics` finds it in each view
(:func:`board_points`) and runs ``cv2.calibrateCamera`` on the views where it was found: the
pinhole (fx, fy, cx, cy; px, continuous coordinates, (0, 0) at the first pixel's top-left
corner) and OpenCV's distortion (k1, k2, p1, p2, k3), with the RMS reprojection error (px).

OpenCV's pixel convention puts (0, 0) at the first pixel's *centre*; the project's (MuJoCo's and
the AprilTag detector's) at its corner, half a pixel up and left: :func:`calibrate_intrinsics`
reports cx, cy in the project's convention (OpenCV's + 0.5) and :class:`Undistorter` converts back.

The calibration file (YAML, written by ``python -m ahrm_stack.perception.calibrate``; format
:class:`CalibrationFile`) replaces ``perception.camera``'s intrinsics and distortion, and its
position and orientation once the extrinsics were measured (:func:`apply_calibration`).
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Annotated, Iterable, Optional

import numpy as np
import yaml

from ahrm_stack.perception.settings import (BoardSettings, PerceptionConfigError, PerceptionSettings,
                                            Vec3, Vec4)
from ahrm_stack.schema import Float, Int, Section, Str, ge, read_yaml, unit_quaternion, validate
from ahrm_stack.hardware.scene import UNIT_TOLERANCE


class CalibrationError(ValueError):
    """A calibration could not be made (too few views with the board); one line."""


@dataclasses.dataclass(frozen=True)
class ExtrinsicsEntry(Section):
    position: Vec3  # m, world frame: the optical centre
    quaternion: Annotated[Vec4, unit_quaternion(UNIT_TOLERANCE)]  # camera-to-world (w x y z), optical
    reference_tag: Str  # what it was measured on, e.g. "tag36h11 id 1, 0.12 m at [0, 0, 0.4]"
    frames: Annotated[Int, ge(1)]  # frames averaged
    spread_mm: Float  # largest distance of one frame's optical centre from the mean, mm


@dataclasses.dataclass(frozen=True)
class CalibrationFile(Section):
    """A calibration file (the module docstring)."""

    width: Annotated[Int, ge(16)]  # px, the calibrated image size
    height: Annotated[Int, ge(16)]
    intrinsics: Vec4  # fx, fy, cx, cy, px (cx, cy: (0, 0) at the first pixel's corner)
    distortion: tuple[Float, Float, Float, Float, Float]  # OpenCV k1, k2, p1, p2, k3
    rms_px: Float  # RMS reprojection error of the calibration, px
    views: Annotated[Int, ge(1)]  # views with the board
    extrinsics: Optional[ExtrinsicsEntry]  # None: not measured yet


@dataclasses.dataclass(frozen=True)
class Intrinsic:
    """A calibration's result: ``matrix`` (3 × 3, OpenCV's pixel convention), ``distortion``
    (k1, k2, p1, p2, k3), ``rms`` px, ``views`` used, image ``size`` (width, height)."""

    matrix: np.ndarray
    distortion: np.ndarray
    rms: float
    views: int
    size: tuple[int, int]

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in the project's pixel convention (cx, cy + 0.5)."""
        K = self.matrix
        return (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5)


def _cv2():
    from ahrm_stack.perception.frames import _cv2 as load

    return load()


def aruco_dictionary(name: str):
    """``cv2.aruco``'s predefined dictionary ``name`` (e.g. DICT_4X4_50); a one-line
    :class:`PerceptionConfigError` naming the key for an unknown one."""
    aruco = _cv2().aruco
    if not name.startswith("DICT_") or not hasattr(aruco, name):
        known = sorted(n for n in dir(aruco) if n.startswith("DICT_"))
        raise PerceptionConfigError(f"perception.calibration.board.dictionary {name!r} is not one of "
                                    f"cv2.aruco's: {', '.join(known[:6])}, ...")
    return aruco.getPredefinedDictionary(getattr(aruco, name))


def charuco_board(board: BoardSettings):
    """The ``cv2.aruco.CharucoBoard`` of ``board`` (its origin at the board's top-left corner)."""
    aruco = _cv2().aruco
    return aruco.CharucoBoard(tuple(board.squares), board.square_size, board.marker_size,
                              aruco_dictionary(board.dictionary))


def chessboard_corners(board: BoardSettings) -> np.ndarray:
    """The inner corners of a plain chessboard (board frame, m, z = 0), in the order of
    ``cv2.findChessboardCorners`` (row by row)."""
    nx, ny = board.squares[0] - 1, board.squares[1] - 1
    grid = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) + 1
    return np.hstack([grid * board.square_size, np.zeros((len(grid), 1))]).astype(np.float32)


def board_points(gray: np.ndarray, board: BoardSettings) -> tuple[np.ndarray, np.ndarray] | None:
    """The board's corners seen in ``gray``: (object points (N, 3) m, board frame; image points
    (N, 2) px, OpenCV's convention), or None when too few are found (a ChArUco board: at least 6)."""
    cv2 = _cv2()
    if board.kind == "chessboard":
        pattern = (board.squares[0] - 1, board.squares[1] - 1)
        found, corners = cv2.findChessboardCorners(gray, pattern)
        if not found:
            return None
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
        return chessboard_corners(board), corners.reshape(-1, 2)
    charuco = charuco_board(board)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(charuco).detectBoard(gray)
    if ids is None or len(ids) < 6:
        return None
    objects = charuco.getChessboardCorners()[ids.ravel()]
    return objects.astype(np.float32), corners.reshape(-1, 2).astype(np.float32)


def calibrate_intrinsics(images: Iterable[np.ndarray], board: BoardSettings) -> Intrinsic:
    """Intrinsics and distortion from grey views (uint8, all the same size) of ``board``;
    :class:`CalibrationError` when fewer than ``board.min_views`` views show it."""
    cv2 = _cv2()
    objects, points, size = [], [], None
    seen = 0
    for gray in images:
        seen += 1
        if size is None:
            size = (gray.shape[1], gray.shape[0])
        elif (gray.shape[1], gray.shape[0]) != size:
            raise CalibrationError(f"view {seen} is {gray.shape[1]} x {gray.shape[0]} px, the first "
                                   f"{size[0]} x {size[1]}: one camera, one size")
        found = board_points(gray, board)
        if found is not None:
            objects.append(found[0])
            points.append(found[1])
    if size is None or len(objects) < board.min_views:
        raise CalibrationError(f"the {board.kind} board was found in {len(objects)} of {seen} views; "
                               f"perception.calibration.board.min_views is {board.min_views}")
    rms, K, dist, _, _ = cv2.calibrateCamera(objects, points, size, None, None,
                                             flags=cv2.CALIB_FIX_K3)  # k3: see the docstring
    return Intrinsic(K, np.asarray(dist, dtype=float).ravel()[:5], float(rms), len(objects), size)


def write_calibration(path: Path | str, calibration: CalibrationFile, comment: str = "") -> Path:
    """Write ``calibration`` as a calibration file (after it passed the schema: nothing invalid
    is written)."""
    validate(CalibrationFile, dataclasses.asdict(calibration), "calibration", error=PerceptionConfigError)
    path = Path(path)
    data = dataclasses.asdict(calibration)
    rounded = yaml.safe_load(yaml.safe_dump(data))
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    head = f"# camera calibration, {stamp}: python -m ahrm_stack.perception.calibrate\n"
    head += "".join(f"# {line}\n" for line in comment.splitlines())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(head + yaml.safe_dump(rounded, sort_keys=False, default_flow_style=None))
    return path


def read_calibration(path: Path | str) -> CalibrationFile:
    """A calibration file, validated; one-line :class:`PerceptionConfigError` naming the file and
    the key."""
    path = Path(path)
    where = f"calibration file {path}"
    if not path.is_file():
        raise PerceptionConfigError(f"cannot read the {where}: no such file")
    return validate(CalibrationFile, read_yaml(path, PerceptionConfigError), "",
                    source=lambda key: where, error=PerceptionConfigError)


def apply_calibration(settings: PerceptionSettings, path: Path | str) -> PerceptionSettings:
    """``settings`` with the camera's intrinsics and distortion (and, when measured, its position
    and orientation) from the calibration file ``path``; its image size must be the camera's."""
    calibration = read_calibration(path)
    camera = settings.camera
    if (calibration.width, calibration.height) != (camera.width, camera.height):
        raise PerceptionConfigError(
            f"calibration file {path} is for {calibration.width} x {calibration.height} px; "
            f"perception.camera is {camera.width} x {camera.height}")
    changes: dict = {"intrinsics": calibration.intrinsics, "distortion": calibration.distortion}
    if calibration.extrinsics is not None:
        changes.update(position=calibration.extrinsics.position,
                       quaternion=calibration.extrinsics.quaternion, look_at=None)
    return dataclasses.replace(settings, camera=dataclasses.replace(camera, **changes))


def load_calibrated_settings(path: Path | str | None = None) -> PerceptionSettings:
    """The perception settings (``path``, default ``configs/perception.yaml``) with the camera's
    ``calibration_file`` applied when one is set (:func:`apply_calibration`); what a run uses."""
    from ahrm_stack.perception import settings as perception_settings

    settings = (perception_settings.load_perception_settings() if path is None
                else perception_settings.load_perception_settings(path))
    if settings.camera.calibration_file:
        settings = apply_calibration(settings, settings.camera.calibration_file)
    return settings


def camera_matrix(intrinsics: tuple[float, float, float, float]) -> np.ndarray:
    """OpenCV's 3 × 3 camera matrix of (fx, fy, cx, cy) in the project's pixel convention."""
    fx, fy, cx, cy = intrinsics
    return np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])


class Undistorter:
    """Frames of a camera with lens ``distortion`` resampled to the distortion-free pinhole of
    the same ``intrinsics`` (fx, fy, cx, cy; the maps made once, ``cv2.remap`` bilinear per
    frame), which the tag detector then takes as exact."""

    def __init__(self, intrinsics: tuple[float, float, float, float], distortion, width: int,
                 height: int) -> None:
        cv2 = _cv2()
        K = camera_matrix(intrinsics)
        self.maps = cv2.initUndistortRectifyMap(K, np.asarray(distortion, dtype=float), None, K,
                                                (width, height), cv2.CV_16SC2)

    def __call__(self, gray: np.ndarray) -> np.ndarray:
        cv2 = _cv2()
        return cv2.remap(gray, self.maps[0], self.maps[1], cv2.INTER_LINEAR)


def undistorter(settings: PerceptionSettings) -> Undistorter | None:
    """The :class:`Undistorter` of ``perception.camera`` (None without distortion)."""
    camera = settings.camera
    if camera.distortion is None or not any(camera.distortion):
        return None
    from ahrm_stack.perception.geometry import Intrinsics

    return Undistorter(Intrinsics.from_settings(camera).params, camera.distortion, camera.width,
                       camera.height)
