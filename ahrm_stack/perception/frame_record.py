"""Camera frames for the run's record (``deploy.record_frames``): encoded where they are captured,
handed to the deploy record's MCAP twin (:class:`~ahrm_stack.deploy.record.RunLog`).

The frames recorded are the grey frames the perception measured, as its frame source gave them
(before any undistortion): every ``every``-th frame of the source, counted from its first
(:class:`TappedFrames`; the sim camera renders one per control tick, a real camera one per
``1 / source.fps`` s), encoded as JPEG (quality :data:`JPEG_QUALITY`) or PNG (lossless) by
:func:`encode_frame` where it was captured: in the control tick (``source.kind: sim``), in the
detection thread, or in the detection child process, which sends the encoded bytes back through
its pipe (``source.isolation``). :class:`FrameRecording` is the thread-safe queue between the
producer and the record, which takes the frames at each record it writes.

Each frame keeps its ``index`` (frames since the source started, the same count as the
perception's :class:`~ahrm_stack.perception.detection_thread.StampedMeasurement` index and
:attr:`~ahrm_stack.perception.apriltag.AprilTagCubeSource.frame`) and its capture ``stamp`` (s,
the adapter's clock): a tick's record names the frame its poses came from by both.

Recording never stops a run: an encoder that fails is reported once (:class:`FrameFailure`, logged
as an ERROR by the recording) and records nothing from then on; a queue that is full drops its
oldest frame.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections import deque
from typing import Callable, Literal

import numpy as np

from ahrm_stack.perception.apriltag import FrameSource

log = logging.getLogger("ahrm_stack.deploy")

FrameFormat = Literal["jpeg", "png"]
JPEG_QUALITY = 90  # OpenCV's JPEG quality (0-100) of a recorded frame
PNG_COMPRESSION = 1  # OpenCV's PNG compression level (0-9): fast, lossless at every level


@dataclasses.dataclass(frozen=True)
class EncodedFrame:
    """One recorded frame: ``index`` (frames since the source started), ``stamp`` (s, capture time
    on the adapter's clock), ``width`` × ``height`` px, ``format`` (``jpeg`` or ``png``) and the
    encoded ``data``."""

    index: int
    stamp: float
    width: int
    height: int
    format: str
    data: bytes


@dataclasses.dataclass(frozen=True)
class FrameFailure:
    """The encoder failed (one line, ``text``); it records nothing more."""

    text: str


FrameItem = EncodedFrame | FrameFailure
FrameSink = Callable[[FrameItem], None]


def encode_frame(gray: np.ndarray, fmt: str) -> bytes:
    """``gray`` (uint8, height × width, or height × width × 3 BGR) as ``fmt`` (``jpeg``: quality
    :data:`JPEG_QUALITY`; ``png``: lossless) bytes (OpenCV)."""
    import cv2

    if fmt == "jpeg":
        ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(gray), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    elif fmt == "png":
        ok, buffer = cv2.imencode(".png", np.ascontiguousarray(gray), [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    else:
        raise ValueError(f"frame format {fmt!r}: jpeg or png")
    if not ok:
        raise ValueError(f"OpenCV could not encode a {gray.dtype} {gray.shape} frame as {fmt}")
    return buffer.tobytes()


def decode_frame(data: bytes) -> np.ndarray:
    """Encoded JPEG or PNG ``data`` as an image array (uint8; height × width for a grey frame);
    :class:`ValueError` when it is not an image."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{len(data)} bytes that are not a JPEG or PNG image")
    return image


class FrameEncoder:
    """Called with each captured frame (``index``, ``stamp`` s, ``gray``): every ``every``-th
    (index 0, every, 2 every, ...) is encoded as ``fmt`` and given to ``sink``. A failure is given
    to ``sink`` once as a :class:`FrameFailure`; nothing is encoded after it. Never raises."""

    def __init__(self, every: int, fmt: str, sink: FrameSink) -> None:
        self.every, self.format, self.sink = int(every), fmt, sink
        self.failed = False

    def __call__(self, index: int, stamp: float, gray: np.ndarray) -> None:
        if self.failed or index % self.every:
            return
        try:
            data = encode_frame(gray, self.format)
            height, width = gray.shape[:2]
            self.sink(EncodedFrame(int(index), float(stamp), int(width), int(height), self.format, data))
        except Exception as error:  # noqa: BLE001 - recording never stops the perception
            self.failed = True
            text = (str(error).splitlines() or [""])[0][:200]
            try:
                self.sink(FrameFailure(f"{type(error).__name__}: {text}"))
            except Exception:  # noqa: BLE001 - e.g. the child's pipe closed: nothing to report to
                pass


class TappedFrames:
    """A :class:`~ahrm_stack.perception.apriltag.FrameSource` that shows each frame of ``frames``
    to ``tap`` (index, stamp, frame) as it passes; the frame is returned unchanged."""

    def __init__(self, frames: FrameSource, tap: Callable[[int, float, np.ndarray], None]) -> None:
        self.frames, self.tap = frames, tap
        self.count = 0  # frames grabbed

    def grab(self) -> tuple[float, np.ndarray]:
        stamp, gray = self.frames.grab()
        index, self.count = self.count, self.count + 1
        self.tap(index, stamp, gray)
        return stamp, gray

    def close(self) -> None:
        close = getattr(self.frames, "close", None)
        if close is not None:
            close()


class FrameRecording:
    """The recorded frames between their producer and the record: :meth:`put` (any thread),
    :meth:`take` (the record). ``every``, ``format``: the encoder's (:meth:`encoder`); ``capacity``
    frames are held at most (the oldest dropped, counted in :attr:`dropped`)."""

    def __init__(self, every: int = 1, fmt: FrameFormat = "jpeg", capacity: int = 64) -> None:
        self.every, self.format = int(every), fmt
        self._lock = threading.Lock()
        self._frames: deque[EncodedFrame] = deque()
        self.capacity = capacity
        self.dropped = 0  # frames dropped from a full queue
        self.failure = ""  # the encoder's failure, if any

    def encoder(self) -> FrameEncoder:
        """An encoder that puts its frames here (for a producer in this process)."""
        return FrameEncoder(self.every, self.format, self.put)

    def put(self, item: FrameItem) -> None:
        """A frame, or the encoder's failure (logged once)."""
        if isinstance(item, FrameFailure):
            if not self.failure:
                self.failure = item.text
                log.error("deploy: encoding a camera frame failed (%s); no more frames are recorded, "
                          "the run goes on", item.text)
            return
        with self._lock:
            if len(self._frames) >= self.capacity:
                self._frames.popleft()
                self.dropped += 1
            self._frames.append(item)

    def take(self) -> list[EncodedFrame]:
        """The frames put since the last call, oldest first."""
        with self._lock:
            frames, self._frames = list(self._frames), deque()
        return frames
