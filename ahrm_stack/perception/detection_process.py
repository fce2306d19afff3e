"""Capture and tag detection in their own *process*: the control process never shares its GIL
or its CPU time slice with them.

:class:`DetectionProcess` has :class:`~ahrm_stack.perception.detection_thread.DetectionThread`'s
interface (``start``, ``since``, ``wait_first``, ``stop``, ``error``), so
:class:`~ahrm_stack.perception.detection_thread.ThreadedCubeSource` reads either. A child process
(``spawn``: a fresh interpreter, nothing of the parent's MuJoCo or GL state) opens the frame
source of ``perception.source`` and runs the same loop as the thread (grab, undistort, measure) at
niceness +10; each result (:class:`StampedMeasurement`, a few hundred bytes) comes back through a
pipe that a receiver thread empties as results come (waiting in ``recv`` without the GIL), so the
child never waits on a full pipe; :meth:`since` returns what arrived without waiting. A thread
inside a process that runs Python code holds the GIL for up to the switch interval whenever the
control thread needs it, which showed in the control tick's p99
(``benchmarks/bench_camera_thread.py``).

With a :class:`~ahrm_stack.perception.frame_record.FrameRecording` (``deploy.record_frames``), the
child also encodes the frames to record (its every-th, JPEG or PNG) and sends each through the
same pipe; the receiver thread puts them into the recording.

Time base: the child stamps frames with ``time.perf_counter`` (CLOCK_MONOTONIC, one clock for
every process on Linux), which is the adapter's clock when that is the wall clock
(:class:`~ahrm_stack.hardware.protocol.WallClock`, the sim backend's in real time); :meth:`start` checks it.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from typing import Any

from ahrm_stack.perception.detection_thread import CameraThreadError, MeasurementBuffer, StampedMeasurement
from ahrm_stack.perception.frame_record import EncodedFrame, FrameFailure, FrameRecording
from ahrm_stack.perception.settings import PerceptionSettings


def _child(settings: PerceptionSettings, cube_size: float, conn, stop, nice: int,
           record: tuple[int, str] | None = None) -> None:
    """The child process: the frame source, undistortion and detection loop; results or one
    error line through ``conn``, and with ``record`` (every, format) the encoded frames to record
    (:class:`~ahrm_stack.perception.frame_record.EncodedFrame`, or one ``FrameFailure``)."""
    try:
        os.nice(nice)
    except OSError:
        pass
    frames = detector = None
    try:
        from ahrm_stack.perception.apriltag import TagDetector
        from ahrm_stack.perception.calibration import undistorter
        from ahrm_stack.perception.frame_record import FrameEncoder, TappedFrames
        from ahrm_stack.perception.frames import open_frame_source
        from ahrm_stack.hardware.protocol import WallClock

        clock = WallClock()
        frames = open_frame_source(settings, clock)
        if record is not None:
            frames = TappedFrames(frames, FrameEncoder(record[0], record[1], conn.send))
        detector = TagDetector(settings, cube_size)
        undistort = undistorter(settings)
        up, index = None, 0
        while not stop.is_set():
            stamp, gray = frames.grab()
            if undistort is not None:
                gray = undistort(gray)
            found = detector.measure(gray, up)
            done = clock.now()
            if found is not None:
                up = found.rotation[:, 2]
            conn.send(StampedMeasurement(index, stamp, done - stamp, found))
            index += 1
    except Exception as error:  # noqa: BLE001 - reported to the control process, one line
        text = (str(error).splitlines() or [""])[0][:200]
        try:
            conn.send(f"camera process stopped: {type(error).__name__}: {text}")
        except OSError:
            pass
    except KeyboardInterrupt:
        pass  # the parent's Ctrl-C reaches the child too; the parent stops the arm
    finally:
        if frames is not None:
            frames.close()
        if detector is not None:
            detector.detector.close()
        conn.close()


class DetectionProcess(MeasurementBuffer):
    """The capture/detection loop of ``settings`` in a child process (the module docstring).
    ``history``: how many of the newest results :meth:`since` keeps."""

    kind = "camera process"
    poll = 0.005

    def __init__(self, settings: PerceptionSettings, cube_size: float, label: str, history: int = 64,
                 nice: int = 10, recording: FrameRecording | None = None) -> None:
        self.settings, self.cube_size, self.label = settings, cube_size, label
        super().__init__(history)
        self.nice = nice
        self.recording = recording  # the frames the child encodes go here
        self._receiver: threading.Thread | None = None
        self._process: Any = None  # multiprocessing's spawn Process once started
        self._conn: Any = None  # the receiving end of the pipe
        self._stop: Any = None  # the spawn context's Event

    def start(self, clock=None) -> None:
        """Start the child and the receiver thread; ``clock`` (the adapter's): must read
        ``time.perf_counter``."""
        if clock is not None and abs(clock.now() - time.perf_counter()) > 0.05:
            raise CameraThreadError("the camera process stamps frames with the wall clock "
                                    "(time.perf_counter); the adapter's clock is another")
        context = multiprocessing.get_context("spawn")
        self._conn, child_conn = context.Pipe(duplex=False)
        self._stop = context.Event()
        self._process = context.Process(target=_child, name="camera-detection", daemon=True,
                                        args=(self.settings, self.cube_size, child_conn, self._stop,
                                              self.nice, None if self.recording is None else
                                              (self.recording.every, self.recording.format)))
        self._process.start()
        child_conn.close()
        self._receiver = threading.Thread(target=self._receive, name="camera-receiver", daemon=True)
        self._receiver.start()

    def _receive(self) -> None:
        """Empty the pipe as results come (so the child never waits on a full pipe and the
        newest result is always the newest frame's); ends at the child's end."""
        conn = self._conn
        try:
            while True:
                item = conn.recv()  # waits without the GIL
                if isinstance(item, (EncodedFrame, FrameFailure)):
                    if self.recording is not None:
                        self.recording.put(item)
                    continue
                if isinstance(item, str):
                    with self._lock:
                        self.error = item
                    continue
                self._add(item)
        except (EOFError, OSError):
            with self._lock:
                if not self.error and not self._stop.is_set():
                    self.error = "camera process stopped: it ended without a word (killed?)"

    @property
    def started(self) -> bool:
        return self._process is not None

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.is_alive()

    def stop(self, timeout: float = 3.0) -> None:
        if self._process is None:
            return
        self._stop.set()
        self._process.join(timeout)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(1.0)
        if self._receiver is not None:
            self._receiver.join(1.0)  # the child's end closed the pipe: it has returned
        if self._receiver is None or not self._receiver.is_alive():
            self._conn.close()
