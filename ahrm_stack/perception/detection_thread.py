"""Capture and tag detection in their own thread; the control tick only reads the newest pose.

:class:`DetectionThread` runs ``frames.grab()`` (stamped on the adapter's clock when the frame
arrived), the lens undistortion (when the camera has distortion) and
:meth:`~ahrm_stack.perception.apriltag.TagDetector.measure` in a loop, and keeps the newest
:class:`StampedMeasurement` (capture time, latency = capture to pose, s) under a lock. OpenCV,
the AprilTag detector (ctypes) and the frame reads release the GIL while they work, so the control
thread runs beside them.

:class:`ThreadedCubeSource` is the deploy loop's
:class:`~ahrm_stack.perception.apriltag.CubePoseSource`: each :meth:`~ThreadedCubeSource.cube`
(once per control tick; never waits for a frame) feeds the measurements that arrived since the
last tick to the :class:`~ahrm_stack.perception.tracker.CubeTracker` at their capture times, then
returns the tracker's state predicted to the tick's time (:meth:`CubeTracker.at`). Its staleness
rule is the tracker's: a tag not measured in a frame captured within ``tracker.max_hold`` s of
the tick (a missing tag, a stalled camera or a slow detector alike) is a
:class:`~ahrm_stack.perception.tracker.TagLostError`, and an error in the thread (the camera
unplugged, the video's end) is raised by the next :meth:`cube` as one line: the deploy loop stops
the arm on both (a perception fault).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import threading
import time
from collections import deque
from typing import Callable, Protocol

import numpy as np

from ahrm_stack.perception.apriltag import FrameSource, TagDetector, TagMeasurement
from ahrm_stack.perception.tracker import CubeState, CubeTracker


class CameraThreadError(RuntimeError):
    """The capture/detection thread stopped on an error (the first line of it)."""


@dataclasses.dataclass(frozen=True)
class StampedMeasurement:
    """One frame's result: ``index`` (frames since the start), ``capture_time`` s (the adapter's
    clock), ``latency`` s (capture to pose), ``measurement`` (None: the tag not seen)."""

    index: int
    capture_time: float
    latency: float
    measurement: TagMeasurement | None


class MeasurementBuffer:
    """What a detection runner (:class:`DetectionThread`, or the child process's
    :class:`~ahrm_stack.perception.detection_process.DetectionProcess`) shares with the control
    thread: the ``history`` newest stamped measurements, every frame's capture-to-pose latency (s),
    the frame count and the first line of the error that stopped it. ``kind`` names the runner in
    errors; ``poll`` (s) is :meth:`wait_first`'s sleep."""

    kind = "camera thread"
    poll = 0.002

    def __init__(self, history: int) -> None:
        self._lock = threading.Lock()
        self._results: deque[StampedMeasurement] = deque(maxlen=history)
        self.error = ""
        self.frames_done = 0
        self.latencies: list[float] = []

    def _add(self, result: StampedMeasurement) -> None:
        with self._lock:
            self._results.append(result)
            self.latencies.append(result.latency)
            self.frames_done += 1

    def since(self, index: int) -> list[StampedMeasurement]:
        """The results with ``index`` or later (oldest first; at most ``history``); never waits."""
        with self._lock:
            return [r for r in self._results if r.index >= index]

    def wait_first(self, timeout: float) -> None:
        """Block (before a run) until the first frame was measured; :class:`CameraThreadError`
        when the runner failed or ``timeout`` s of wall time passed."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.error:
                raise CameraThreadError(self.error)
            if self.frames_done:
                return
            time.sleep(self.poll)
        raise CameraThreadError(f"{self.kind}: no frame measured within {timeout:g} s")


class DetectionThread(MeasurementBuffer):
    """``frames`` → (``undistort``) → ``detector`` in a daemon thread (the module docstring).

    ``clock``: the adapter's clock (its ``now`` only: never slept on here). ``history``: how many
    of the newest results :meth:`since` can return. ``nice``: the thread's own niceness (Linux:
    +10, so that the OS runs the control thread first when the CPUs are busy). ``switch_interval``
    (s): the interpreter's GIL switch interval is lowered to it at :meth:`start` (Python's default
    5 ms is how long the control thread may wait for the GIL while this thread runs Python code;
    a process-wide setting, never raised here)."""

    def __init__(self, frames: FrameSource, detector: TagDetector, clock,
                 undistort: Callable[[np.ndarray], np.ndarray] | None = None,
                 history: int = 64, nice: int = 10, switch_interval: float = 0.0005) -> None:
        self.frames, self.detector, self.clock, self.undistort = frames, detector, clock, undistort
        super().__init__(history)
        self.history, self.nice, self.switch_interval = history, nice, switch_interval
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    def start(self, clock=None) -> None:
        """Start the thread (``clock``: unused, the thread stamps with the one it was given)."""
        if sys.getswitchinterval() > self.switch_interval:
            sys.setswitchinterval(self.switch_interval)  # the control thread waits less for the GIL
        self._thread = threading.Thread(target=self._run, name="camera-detection", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        up = None
        try:
            if self.nice and hasattr(os, "setpriority"):  # this thread only (Linux: per-thread nice)
                try:
                    os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self.nice)
                except OSError:
                    pass  # not allowed: it runs at the process's priority
            while not self._stop.is_set():
                stamp, gray = self.frames.grab()
                if self.undistort is not None:
                    gray = self.undistort(gray)
                found = self.detector.measure(gray, up)
                done = self.clock.now()
                if found is not None:
                    up = found.rotation[:, 2]
                self._add(StampedMeasurement(self.frames_done, stamp, done - stamp, found))
        except Exception as error:  # noqa: BLE001 - reported to the control thread, one line
            text = (str(error).splitlines() or [""])[0][:200]
            self.error = f"camera thread stopped: {type(error).__name__}: {text}"

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread, then close the frame source and the detector (left to the process's
        end when the thread is stuck in a read after ``timeout`` s)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self.alive or self._closed:
            return
        self._closed = True
        close = getattr(self.frames, "close", None)
        if close is not None:
            close()
        self.detector.detector.close()

    @property
    def started(self) -> bool:
        return self._thread is not None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()


class DetectionRunner(Protocol):
    """What :class:`ThreadedCubeSource` reads: a :class:`DetectionThread` or a
    :class:`~ahrm_stack.perception.detection_process.DetectionProcess`."""

    error: str
    frames_done: int
    latencies: list[float]

    def start(self, clock=None) -> None: ...

    def wait_first(self, timeout: float) -> None: ...

    def since(self, index: int) -> list[StampedMeasurement]: ...

    def stop(self, timeout: float = ...) -> None: ...

    @property
    def started(self) -> bool: ...


class ThreadedCubeSource:
    """A :class:`~ahrm_stack.perception.apriltag.CubePoseSource` on a :class:`DetectionThread`
    or a :class:`~ahrm_stack.perception.detection_process.DetectionProcess` (the module
    docstring). :meth:`start` starts it and waits up to ``start_timeout`` s (wall time) for its
    first frame."""

    def __init__(self, runner: DetectionRunner, tracker: CubeTracker, clock,
                 start_timeout: float = 20.0) -> None:
        self.thread, self.tracker, self.clock = runner, tracker, clock
        self.start_timeout = start_timeout
        self._next = 0  # the next result index to feed the tracker
        self._latency = 0.0
        self.measurements = 0  # frames with the tag
        self.misses = 0  # frames without it
        self.ambiguous = 0
        self.frame: tuple[int, float] | None = None  # the newest frame fed: (index, capture stamp s)

    def start(self) -> None:
        self.thread.start(self.clock)
        self.thread.wait_first(self.start_timeout)

    def cube(self) -> CubeState:
        """The cube at the clock's now (non-blocking); raises :class:`CameraThreadError` or
        :class:`~ahrm_stack.perception.tracker.TagLostError` (one line) as the module says."""
        if not self.thread.started:
            raise CameraThreadError("camera thread not started (ThreadedCubeSource.start)")
        for result in self.thread.since(self._next):
            self._next = result.index + 1
            self.frame = (result.index, result.capture_time)
            found = result.measurement
            if found is None:
                self.misses += 1
                continue  # the staleness rule (tracker.at) judges the gap at the tick's time
            self.measurements += 1
            self.ambiguous += int(found.ambiguous)
            self.tracker.update(result.capture_time, found.position, found.quaternion)
            self._latency = result.latency
        if self.thread.error:
            raise CameraThreadError(self.thread.error)
        return self.tracker.at(self.clock.now(), self._latency)

    def close(self) -> None:
        self.thread.stop()
