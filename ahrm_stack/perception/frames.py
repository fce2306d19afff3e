"""Frame sources of a real camera: grey frames stamped on the adapter's clock.

Every source is a :class:`~ahrm_stack.perception.apriltag.FrameSource`: :meth:`grab` returns
``(timestamp, gray)``, the timestamp (s) on the ``clock`` it was given (the arm adapter's, so
poses and feedback share one time base) read when the frame arrived, the frame uint8 height ×
width (BT.601 luma of the camera's colour image). A frame of another size than
``perception.camera`` width × height is a one-line :class:`FrameError`, and so is a camera that
cannot be opened, a frame that cannot be read, and the end of a video (unless ``source.loop``).

* :class:`VideoFileFrames`: a video file or an image sequence (``frame_%04d.png``) through OpenCV's
  ``VideoCapture``, played at ``source.fps`` (the clock is slept on between frames);
* :class:`UvcFrames`: a USB/UVC camera through ``VideoCapture(device)`` (V4L2 on Linux), asked for
  the configured size and frame rate;
* :class:`RealSenseFrames`: an Intel RealSense's colour stream (``pyrealsense2``, optional).

:func:`open_frame_source` picks one from ``perception.source``; ``kind: sim`` frames are
:class:`~ahrm_stack.perception.sim_camera.SimFrames` (the sim backend only).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ahrm_stack.perception.settings import PerceptionConfigError, PerceptionSettings


class FrameError(RuntimeError):
    """A camera could not be opened or read, or its frame is not the configured size; one line."""


def _cv2():
    try:
        import cv2
    except ImportError:
        raise FrameError("OpenCV is not installed: pip install 'opencv-python-headless>=4.8,<5'") from None
    return cv2


def to_gray(image: np.ndarray, width: int, height: int, what: str) -> np.ndarray:
    """``image`` (BGR or grey, uint8) as a grey uint8 height × width frame; :class:`FrameError`
    naming ``what`` when it has another size."""
    if image.shape[:2] != (height, width):
        raise FrameError(f"{what} gives {image.shape[1]} x {image.shape[0]} px frames; "
                         f"perception.camera is {width} x {height}")
    if image.ndim == 2:
        return np.ascontiguousarray(image, dtype=np.uint8)
    return _cv2().cvtColor(image, _cv2().COLOR_BGR2GRAY)


class VideoFileFrames:
    """Frames of a video file (or image sequence) played at ``fps`` on ``clock``; ``loop``: start
    over at the end. ``fps`` None: as fast as they are asked for (each frame once)."""

    def __init__(self, path: Path | str, width: int, height: int, clock, fps: float | None = 30.0,
                 loop: bool = False) -> None:
        cv2 = _cv2()
        self.path = str(path)
        if "%" not in self.path and not Path(self.path).is_file():
            raise FrameError(f"perception.source.video_file {self.path}: no such file")
        self.capture = cv2.VideoCapture(self.path)
        if not self.capture.isOpened():
            raise FrameError(f"perception.source.video_file {self.path}: OpenCV cannot open it")
        self.width, self.height, self.clock = width, height, clock
        self.period = None if fps is None else 1.0 / fps
        self.loop = loop
        self.frames = 0  # frames read or skipped
        self.skipped = 0
        self._start: float | None = None

    def grab(self) -> tuple[float, np.ndarray]:
        """The frame a live camera would show now: waits for the next frame's time, skips the
        frames whose time passed while the caller was busy (as a camera's newest-frame buffer)."""
        import time

        if self.period is not None:
            now = self.clock.now()
            if self._start is None:
                self._start = now
            due = self._start + self.frames * self.period
            if now < due:
                time.sleep(due - now)  # never the clock's sleep: a sim clock steps its physics
            behind = int((self.clock.now() - self._start) / self.period) - self.frames
            for _ in range(max(0, behind)):
                if not self.capture.grab():
                    break
                self.frames += 1
                self.skipped += 1
        ok, image = self.capture.read()
        if not ok and self.loop and self.frames > 0:
            self.capture.set(_cv2().CAP_PROP_POS_FRAMES, 0)
            ok, image = self.capture.read()
        if not ok:
            raise FrameError(f"video {self.path} ended after {self.frames} frames")
        stamp = self.clock.now()
        self.frames += 1
        return stamp, to_gray(image, self.width, self.height, f"video {self.path}")

    def close(self) -> None:
        self.capture.release()


class UvcFrames:
    """A USB/UVC camera (``cv2.VideoCapture(device)``) at ``width`` × ``height`` and ``fps``."""

    def __init__(self, device: int, width: int, height: int, clock, fps: float = 30.0) -> None:
        cv2 = _cv2()
        self.device = device
        self.capture = cv2.VideoCapture(device)
        if not self.capture.isOpened():
            raise FrameError(f"perception.source.device {device}: no camera there (/dev/video{device})")
        self.capture.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        self.capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        self.capture.set(cv2.CAP_PROP_FPS, fps)
        self.capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # the newest frame, not a queued one
        self.width, self.height, self.clock = width, height, clock

    def grab(self) -> tuple[float, np.ndarray]:
        ok, image = self.capture.read()
        stamp = self.clock.now()
        if not ok:
            raise FrameError(f"camera /dev/video{self.device}: no frame (unplugged?)")
        return stamp, to_gray(image, self.width, self.height, f"camera /dev/video{self.device}")

    def close(self) -> None:
        self.capture.release()


class RealSenseFrames:
    """An Intel RealSense's colour stream (``pyrealsense2``) at ``width`` × ``height`` and
    ``fps`` (a D435: 1280 × 720 at 30 Hz, 69° × 42°)."""

    def __init__(self, width: int, height: int, clock, fps: float = 30.0) -> None:
        try:
            import pyrealsense2 as rs  # type: ignore[import-not-found]
        except ImportError:
            raise FrameError("perception.source.kind realsense needs pyrealsense2: "
                             "pip install pyrealsense2") from None
        self.rs, self.width, self.height, self.clock = rs, width, height, clock
        config = rs.config()
        config.enable_stream(rs.stream.color, width, height, rs.format.bgr8, int(round(fps)))
        self.pipeline = rs.pipeline()
        try:
            self.pipeline.start(config)
        except RuntimeError as error:
            raise FrameError(f"RealSense colour {width} x {height} at {fps:g} Hz: "
                             f"{(str(error).splitlines() or [''])[0]}") from None

    def grab(self) -> tuple[float, np.ndarray]:
        try:
            frames = self.pipeline.wait_for_frames(1000)
        except RuntimeError as error:
            raise FrameError(f"RealSense: no frame ({(str(error).splitlines() or [''])[0]})") from None
        stamp = self.clock.now()
        image = np.asanyarray(frames.get_color_frame().get_data())
        return stamp, to_gray(image, self.width, self.height, "RealSense colour stream")

    def close(self) -> None:
        self.pipeline.stop()


def check_source(settings: PerceptionSettings, backend: str) -> None:
    """One-line :class:`PerceptionConfigError` where ``perception.source`` cannot serve
    ``backend`` (before anything is opened): the sim render serves the sim backend only, and a
    video file must exist."""
    source = settings.source
    if source.kind == "sim" and backend != "sim":
        raise PerceptionConfigError(
            f"perception.source.kind sim renders the simulator's table: with --backend {backend} "
            "choose a real frame source (uvc, realsense or video) in configs/perception.yaml")
    if source.kind == "video" and "%" not in source.video_file and not Path(source.video_file).is_file():
        raise PerceptionConfigError(f"perception.source.video_file {source.video_file}: no such file")


def open_frame_source(settings: PerceptionSettings, clock):
    """The real frame source of ``perception.source`` (kind video, uvc or realsense) on
    ``clock``; :class:`FrameError` (one line) when it cannot be opened."""
    source, camera = settings.source, settings.camera
    if source.kind == "video":
        return VideoFileFrames(source.video_file, camera.width, camera.height, clock, source.fps,
                               source.loop)
    if source.kind == "uvc":
        return UvcFrames(source.device, camera.width, camera.height, clock, source.fps)
    if source.kind == "realsense":
        return RealSenseFrames(camera.width, camera.height, clock, source.fps)
    raise PerceptionConfigError(f"perception.source.kind {source.kind}: not a real camera")
