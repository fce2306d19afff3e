"""The camera calibration command (bring-up of a real camera, docs/camera.md)::

    python -m ahrm_stack.perception.calibrate intrinsics --out configs/camera.yaml VIEW...
    python -m ahrm_stack.perception.calibrate extrinsics --calibration configs/camera.yaml [VIEW...]

``intrinsics``: views of the printed board of ``perception.calibration.board`` (image files, or
one video file, or ``--capture N`` frames of ``perception.source``, one every ``--every`` s)
→ the calibration file (:mod:`~ahrm_stack.perception.calibration`): fx, fy, cx, cy, the lens
distortion, the RMS reprojection error. ``extrinsics``: frames showing the reference tag of
``perception.calibration.reference_tag`` lying at its surveyed pose on the table (image files,
or frames of ``perception.source``) → the camera's pose in the world, added to the calibration
file (:mod:`~ahrm_stack.perception.extrinsics`). Then set ``perception.camera.calibration_file``.

Bad input (a setting, a missing or unreadable view, views of another size) is one line and exit
status 2, with nothing written; a board or tag seen too rarely is one line and exit status 1.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from ahrm_stack.cli import Parser

PROG = "python -m ahrm_stack.perception.calibrate"
VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".webm")


class InputError(ValueError):
    """A view that cannot be read; one line."""


def read_views(paths: Sequence[Path]) -> list[np.ndarray]:
    """Grey views from image files, or every frame of one video file (OpenCV)."""
    from ahrm_stack.perception.frames import _cv2

    cv2 = _cv2()
    if len(paths) == 1 and paths[0].suffix.lower() in VIDEO_SUFFIXES:
        if not paths[0].is_file():
            raise InputError(f"{paths[0]}: no such file")
        capture = cv2.VideoCapture(str(paths[0]))
        views = []
        while True:
            ok, image = capture.read()
            if not ok:
                break
            views.append(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        capture.release()
        if not views:
            raise InputError(f"{paths[0]}: OpenCV reads no frame from it")
        return views
    views = []
    for path in paths:
        if not path.is_file():
            raise InputError(f"{path}: no such file")
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise InputError(f"{path}: not an image OpenCV reads")
        views.append(image)
    return views


def capture_views(settings, count: int, every: float) -> Iterator[np.ndarray]:
    """``count`` frames of ``perception.source`` (a real camera), one every ``every`` s."""
    from ahrm_stack.perception.frames import open_frame_source
    from ahrm_stack.hardware.protocol import WallClock

    frames = open_frame_source(settings, WallClock())
    try:
        last = -math.inf
        taken = 0
        while taken < count:
            stamp, gray = frames.grab()
            if stamp - last >= every:
                last, taken = stamp, taken + 1
                print(f"view {taken}/{count}", file=sys.stderr)
                yield gray
    finally:
        frames.close()


def _intrinsics(args, settings) -> int:
    from ahrm_stack.perception.calibration import CalibrationFile, calibrate_intrinsics, write_calibration

    board = settings.calibration.board
    views = read_views(args.views) if args.views else list(capture_views(settings, args.capture, args.every))
    calibration = calibrate_intrinsics(views, board)
    width, height = calibration.size
    entry = CalibrationFile(width=width, height=height,
                            intrinsics=tuple(round(v, 4) for v in calibration.intrinsics),  # type: ignore[arg-type]
                            distortion=tuple(round(float(v), 6) for v in calibration.distortion),  # type: ignore[arg-type]
                            rms_px=round(calibration.rms, 4), views=calibration.views, extrinsics=None)
    write_calibration(args.out, entry, f"{board.kind} board {board.squares[0]} x {board.squares[1]} "
                                       f"squares of {board.square_size} m")
    fx, fy, cx, cy = entry.intrinsics
    fovy = math.degrees(2 * math.atan(height / 2 / fy))
    fovx = math.degrees(2 * math.atan(width / 2 / fx))
    print(f"{args.out}: {width} x {height} px, fx {fx:.1f} fy {fy:.1f} cx {cx:.1f} cy {cy:.1f} px "
          f"({fovx:.1f} x {fovy:.1f} deg), distortion {list(entry.distortion)}, RMS "
          f"{entry.rms_px:.3f} px over {entry.views} of {len(views)} views")
    return 0


def _extrinsics(args, settings) -> int:
    from ahrm_stack.perception.calibration import ExtrinsicsEntry, read_calibration, write_calibration
    from ahrm_stack.perception.extrinsics import measure_extrinsics
    from ahrm_stack.perception.geometry import matrix_to_quaternion

    calibration = read_calibration(args.calibration)
    tag, count = settings.calibration.reference_tag, settings.calibration.frames
    if args.views:
        views = read_views(args.views)
        frames: Iterator[np.ndarray] = iter(views)
        count = min(count, len(views))  # a few photos of a still camera are enough
    else:
        frames = capture_views(settings, 10 * count, 0.0)
    pose, spread, used = measure_extrinsics(
        _sized(frames, calibration.width, calibration.height), tag, calibration.intrinsics,
        calibration.distortion, count)
    entry = ExtrinsicsEntry(
        position=tuple(round(float(v), 6) for v in pose.position),  # type: ignore[arg-type]
        quaternion=tuple(round(float(v), 8) for v in matrix_to_quaternion(pose.rotation)),  # type: ignore[arg-type]
        reference_tag=f"{tag.family} id {tag.id}, {tag.size} m at {list(tag.position)} yaw {tag.yaw_deg} deg",
        frames=used, spread_mm=round(spread * 1e3, 3))
    out = args.out or args.calibration
    write_calibration(out, dataclasses.replace(calibration, extrinsics=entry))
    distance = float(np.linalg.norm(pose.position - np.asarray(tag.position)))
    print(f"{out}: camera at {[round(v, 4) for v in entry.position]} m (world), "
          f"{distance:.3f} m from the reference tag, optical axis {np.round(pose.rotation[:, 2], 3).tolist()}; "
          f"{used} frames, spread {entry.spread_mm:.1f} mm")
    return 0


def _sized(frames, width: int, height: int) -> Iterator[np.ndarray]:
    for gray in frames:
        if gray.shape != (height, width):
            raise InputError(f"a view is {gray.shape[1]} x {gray.shape[0]} px; the calibration is "
                             f"for {width} x {height}")
        yield gray


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog=PROG, description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    intrinsics = sub.add_parser("intrinsics", help="intrinsics and lens distortion from board views")
    intrinsics.add_argument("--out", type=Path, required=True, help="the calibration file to write")
    intrinsics.add_argument("--capture", type=int, default=0, metavar="N",
                            help="without VIEW: take N views from perception.source")
    intrinsics.add_argument("--every", type=float, default=1.0, metavar="S",
                            help="with --capture: s between views (move the board meanwhile)")
    intrinsics.add_argument("views", nargs="*", type=Path, metavar="VIEW", help="image files or one video")
    extrinsics = sub.add_parser("extrinsics", help="the camera's pose from the reference tag")
    extrinsics.add_argument("--calibration", type=Path, required=True,
                            help="the intrinsics' calibration file")
    extrinsics.add_argument("--out", type=Path, help="where to write (default: --calibration)")
    extrinsics.add_argument("views", nargs="*", type=Path, metavar="VIEW",
                            help="image files or one video (default: frames of perception.source)")
    parser.add_argument("--config", type=Path, help="perception settings (default configs/perception.yaml)")
    args = parser.parse_args(argv)
    from ahrm_stack.config import ConfigError
    from ahrm_stack.perception.calibration import CalibrationError
    from ahrm_stack.perception.extrinsics import ExtrinsicsError
    from ahrm_stack.perception.frames import FrameError
    from ahrm_stack.perception.settings import PERCEPTION_CONFIG, load_perception_settings

    start = time.perf_counter()
    try:
        settings = load_perception_settings(args.config or PERCEPTION_CONFIG)
        if args.command == "intrinsics" and not args.views and args.capture < settings.calibration.board.min_views:
            raise InputError(f"give VIEW files or --capture N (N >= perception.calibration.board.min_views "
                             f"{settings.calibration.board.min_views})")
        code = _intrinsics(args, settings) if args.command == "intrinsics" else _extrinsics(args, settings)
    except (ConfigError, InputError, FrameError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except (CalibrationError, ExtrinsicsError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130
    print(f"({time.perf_counter() - start:.1f} s)", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
