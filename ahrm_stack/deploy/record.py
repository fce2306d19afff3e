"""The record of a deploy run: the telemetry, one JSON line per tick and per event and the summary
last (``deploy.telemetry``), and the same records in MCAP beside it (``<telemetry>.mcap``, when
``deploy.record_mcap``), the log format robotics viewers open (Foxglove; the ``mcap`` CLI and
library).

**A tick's record** (:func:`tick_record`) holds what a replay or a dataset needs, all in the world
frame and SI units, times in s from the run's start on the adapter's clock:

* ``t`` the tick's time; ``feedback_t`` the feedback frame's stamp; ``q`` (rad), ``dq`` (rad/s),
  ``tau`` (N·m): the joint state the loop read;
* ``poses_t`` the perception's capture stamp; ``cube`` (position m, quaternion w x y z),
  ``obstacles`` (one ``[x, y, z, w, qx, qy, qz]`` per obstacle): what it perceived;
* ``u_nom`` (the controller's request) and ``u`` (the filter's command as the adapter took it,
  rad/s; in a dry run, what would have been sent), ``sent_t`` when it was sent (the adapter's
  clock: a ``--fast`` run's computation takes none of it), ``active`` and ``status`` of the filter,
  ``phase``, ``x``, ``stage``, ``touched``, ``latency_ms``.

**MCAP**: one channel per kind, ``/deploy/tick``, ``/deploy/event``, ``/deploy/summary``, JSON
messages, each channel with a JSON Schema; a message's log time is the wall clock when it was
written (ns; never decreasing), its record's own ``t`` the run's time. Chunks are small
(:data:`CHUNK_BYTES`), so that a run killed mid-way loses at most the last few ticks of the twin;
:func:`read_run` reads a twin without its summary section (a killed run) too. The twin never stops
a run: a failure writing it is logged once and the twin dropped; the JSONL goes on.

**Camera frames** (``deploy.record_frames``, a run with ``--scene camera``): the frames the
perception measured (every ``record_frames_every``-th of its source, grey, JPEG or PNG;
:mod:`ahrm_stack.perception.frame_record`) go into the twin on :data:`IMAGE_TOPIC` as Foxglove's
``foxglove.CompressedImage`` (JSON: ``timestamp`` {sec, nsec} the frame's capture stamp in the
run's time, as ``poses_t``; ``frame_id`` :data:`CAMERA_FRAME`; ``format``; ``data`` base64), the
MCAP message's ``sequence`` the frame's index. Each is written before the first record that
follows its capture; frames captured before the run's start (:meth:`RunLog.start_run`) or after its
last record are not recorded. In a camera run every tick names the frame its poses came from,
``frame`` (its index) and ``frame_t`` (its capture stamp, s), whether that frame was recorded or
not; :func:`iter_frames` reads the frames back, decoded. A frame that cannot be written is logged
once and the frames dropped; the records go on.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:
    from ahrm_stack.perception.frame_record import EncodedFrame, FrameRecording

import numpy as np

log = logging.getLogger("ahrm_stack.deploy")

CHANNELS = ("tick", "event", "summary")
CHUNK_BYTES = 8192  # an MCAP chunk is written once this much is buffered (a tick's record is ~1 kB)
_SCHEMAS = {
    "tick": {"type": "object", "title": "ahrm_stack deploy tick",
             "properties": {name: {"type": "array", "items": {"type": "number"}}
                            for name in ("q", "dq", "tau", "u_nom", "u", "cube")}},
    "event": {"type": "object", "title": "ahrm_stack deploy event",
              "properties": {"event": {"type": "string"}, "reason": {"type": "string"}}},
    "summary": {"type": "object", "title": "ahrm_stack deploy summary",
                "properties": {"summary": {"type": "object"}}},
}
IMAGE_TOPIC = "/camera/image"
IMAGE_SCHEMA = "foxglove.CompressedImage"
CAMERA_FRAME = "perception"  # frame_id of a recorded frame: the perception camera's optical frame
#: Foxglove's foxglove.CompressedImage JSON Schema (github.com/foxglove/schemas)
_IMAGE_SCHEMA = {
    "title": IMAGE_SCHEMA, "description": "A compressed image", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "title": "time", "description": "Timestamp of image",
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
        "frame_id": {"type": "string", "description": "Frame of reference for the image"},
        "data": {"type": "string", "contentEncoding": "base64", "description": "Compressed image data"},
        "format": {"type": "string", "description": "Image format"}}}


def _round(values: Any, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(values, dtype=float).reshape(-1)]


def tick_record(elapsed: float, t0: float, info: Any, stage: str, feedback: Any, poses: Any,
                u_nom: np.ndarray, sent: np.ndarray, sent_at: float, result: Any, touched: bool,
                latency: float, frame: tuple[int, float] | None = None) -> dict[str, Any]:
    """One tick's telemetry line (see the module docstring): ``elapsed`` s since the run's start
    ``t0`` (adapter clock, which also stamps ``feedback`` and ``poses`` and gave ``sent_at``, when
    the command was sent). ``frame``: the camera frame the poses came from (index, capture stamp
    s on the adapter's clock), recorded as ``frame`` and ``frame_t``; None: no camera."""
    obstacles = np.hstack([np.asarray(poses.obstacle_positions, dtype=float).reshape(-1, 3),
                           np.asarray(poses.obstacle_quaternions, dtype=float).reshape(-1, 4)])
    return {
        "t": round(elapsed, 6), "phase": int(info.phase), "x": round(float(info.x), 6), "stage": stage,
        "feedback_t": round(float(feedback.timestamp) - t0, 6), "q": _round(feedback.position),
        "dq": _round(feedback.velocity), "tau": _round(feedback.torque, 4),
        "poses_t": round(float(poses.timestamp) - t0, 6),
        "cube": _round(np.hstack([poses.cube_position, poses.cube_quaternion])),
        "obstacles": [_round(row) for row in obstacles],
        "u_nom": _round(u_nom), "u": _round(sent), "sent_t": round(sent_at - t0, 6),
        "active": list(result.active),
        "status": result.status, "touched": touched, "latency_ms": round(latency * 1e3, 4),
        **({} if frame is None else {"frame": int(frame[0]), "frame_t": round(float(frame[1]) - t0, 6)})}


def twin_path(telemetry: Path) -> Path:
    """The MCAP twin of a telemetry file: ``x.jsonl`` -> ``x.mcap``; any other name gets ``.mcap``
    appended (``run-06.01`` -> ``run-06.01.mcap``, never another run's twin)."""
    telemetry = Path(telemetry)
    return telemetry.with_suffix(".mcap") if telemetry.suffix == ".jsonl" else telemetry.with_name(
        telemetry.name + ".mcap")


def frame_message(frame: EncodedFrame, t0: float) -> bytes:
    """A recorded frame as a ``foxglove.CompressedImage`` JSON message, its timestamp the capture
    stamp less ``t0`` (s: the run's time, never negative)."""
    ns = max(0, round((frame.stamp - t0) * 1e9))
    return json.dumps({"timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
                       "frame_id": CAMERA_FRAME, "format": frame.format,
                       "data": base64.b64encode(frame.data).decode("ascii")}).encode()


def kind_of(record: dict[str, Any]) -> str:
    """The channel of a telemetry record: ``summary``, ``event`` or ``tick``."""
    return "summary" if "summary" in record else "event" if "event" in record else "tick"


class RunLog:
    """The run's telemetry file (JSON lines, written as given) and, with ``mcap``, the same records
    in :func:`twin_path` of it; with ``frames`` too, the camera frames put there (the module
    docstring). File-like: :meth:`write` takes one JSON line."""

    def __init__(self, path: Path, mcap: bool, frames: FrameRecording | None = None) -> None:
        self.path = Path(path)
        self.mcap_path = twin_path(self.path) if mcap else None
        self.frames = frames if mcap else None
        self.frames_written = 0
        self.frames_early = 0  # captured before the run's start: not recorded
        self._t0: float | None = None
        self._file: IO[str] = self.path.open("w")
        self._writer: Any = None
        self._mcap_file: IO[bytes] | None = None
        self._channels: dict[str, int] = {}
        self._last_ns = 0
        if self.mcap_path is not None:
            from mcap.writer import Writer

            self._mcap_file = self.mcap_path.open("wb")
            self._writer = Writer(self._mcap_file, chunk_size=CHUNK_BYTES)
            self._writer.start(profile="", library="ahrm_stack deploy")
            for kind in CHANNELS:
                schema = self._writer.register_schema(name=f"ahrm_stack.deploy.{kind}", encoding="jsonschema",
                                                      data=json.dumps(_SCHEMAS[kind]).encode())
                self._channels[kind] = self._writer.register_channel(
                    topic=f"/deploy/{kind}", message_encoding="json", schema_id=schema)
            if self.frames is not None:
                schema = self._writer.register_schema(name=IMAGE_SCHEMA, encoding="jsonschema",
                                                      data=json.dumps(_IMAGE_SCHEMA).encode())
                self._channels["image"] = self._writer.register_channel(
                    topic=IMAGE_TOPIC, message_encoding="json", schema_id=schema)

    def start_run(self, t0: float) -> None:
        """The run starts at ``t0`` s on the adapter's clock: the frames' timestamps are the time
        since (the deploy loop calls this when its first tick is due)."""
        self._t0 = float(t0)

    def _stamp(self) -> int:
        self._last_ns = max(self._last_ns, time.time_ns())
        return self._last_ns

    def write(self, line: str) -> None:
        self._file.write(line)
        if self._writer is None:
            return
        text = line.strip()
        if not text:
            return
        self._write_frames()
        try:
            stamp = self._stamp()
            self._writer.add_message(channel_id=self._channels[kind_of(json.loads(text))], log_time=stamp,
                                     publish_time=stamp, data=text.encode())
        except Exception as error:  # noqa: BLE001 - the twin never stops a run
            self._twin_failed(error)

    def _twin_failed(self, error: BaseException) -> None:
        log.error("deploy: the MCAP twin %s failed (%s: %s); the JSONL telemetry goes on",
                  self.mcap_path, type(error).__name__, error)
        self._drop_twin()

    def _write_frames(self) -> None:
        """The frames put since the last record (once the run started), before it."""
        if self.frames is None or self._t0 is None:
            return
        for frame in self.frames.take():
            if frame.stamp < self._t0 - 1e-9:
                self.frames_early += 1
                continue
            try:
                data = frame_message(frame, self._t0)
            except Exception as error:  # noqa: BLE001 - a frame never stops a run
                log.error("deploy: a camera frame could not be recorded (%s: %s); no more frames are "
                          "recorded, the run goes on", type(error).__name__, error)
                self.frames = None
                return
            try:
                stamp = self._stamp()
                self._writer.add_message(channel_id=self._channels["image"], log_time=stamp, publish_time=stamp,
                                         data=data, sequence=frame.index & 0xFFFFFFFF)
            except Exception as error:  # noqa: BLE001 - the twin never stops a run
                self._twin_failed(error)
                return
            self.frames_written += 1

    def _drop_twin(self) -> None:
        writer, stream, self._writer, self._mcap_file = self._writer, self._mcap_file, None, None
        try:
            if writer is not None:
                writer.finish()
        except Exception as error:  # noqa: BLE001 - logged; the file is closed below
            log.error("deploy: finishing the MCAP twin %s failed (%s)", self.mcap_path, error)
        finally:
            if stream is not None:
                stream.close()

    def flush(self) -> None:
        self._file.flush()
        if self._mcap_file is not None:
            self._mcap_file.flush()

    def close(self) -> None:
        try:
            self._file.close()
        finally:
            if self.frames is not None:
                log.info("deploy: %d camera frames recorded in %s (%d dropped from a full queue, %d captured "
                         "before the run's start)", self.frames_written, self.mcap_path, self.frames.dropped,
                         self.frames_early)
            self._drop_twin()


@dataclasses.dataclass
class RunRecord:
    """A deploy run read back: its ``ticks``, ``events`` and ``summary`` (None if the run did not
    end cleanly), in order."""

    ticks: list[dict[str, Any]]
    events: list[dict[str, Any]]
    summary: dict[str, Any] | None


def read_run(path: Path | str) -> RunRecord:
    """A run's telemetry (``.jsonl``) or MCAP record (``.mcap``, read with the ``mcap`` library;
    its camera frames are :func:`iter_frames`'); :class:`ValueError` (one line naming the file)
    when it is neither or is damaged."""
    path = Path(path)
    records: list[dict[str, Any]] = []
    try:
        if path.suffix == ".mcap":
            from mcap.reader import NonSeekingReader

            with path.open("rb") as stream:  # in file order; a killed run's twin has no summary section
                for _, channel, message in NonSeekingReader(stream).iter_messages():
                    if channel.topic != IMAGE_TOPIC:
                        records.append(json.loads(message.data))
        else:
            with path.open() as stream:
                records = [json.loads(line) for line in stream if line.strip()]
    except OSError as error:
        raise ValueError(f"{path}: cannot read ({error.strerror or error})") from None
    except Exception as error:  # noqa: BLE001 - a damaged file, whatever the library raises
        raise ValueError(f"{path}: not a deploy record ({type(error).__name__}: "
                         f"{(str(error).splitlines() or [''])[0]})") from None
    ticks = [r for r in records if kind_of(r) == "tick"]
    events = [r for r in records if kind_of(r) == "event"]
    summaries = [r["summary"] for r in records if kind_of(r) == "summary"]
    return RunRecord(ticks, events, summaries[-1] if summaries else None)


@dataclasses.dataclass(frozen=True)
class RecordedFrame:
    """A camera frame read back from a run's MCAP record: ``index`` (frames since the source
    started: a tick's ``frame``), ``t`` s (capture stamp in the run's time: a tick's ``frame_t``),
    ``format``, and ``image`` (uint8, height × width grey; None when not decoded)."""

    index: int
    t: float
    format: str
    image: np.ndarray | None


def iter_frames(path: Path | str, decode: bool = True) -> Iterator[RecordedFrame]:
    """The camera frames of a run's MCAP record (``.mcap``; or its JSONL telemetry, whose twin is
    read), in file order, decoded to arrays (``decode``); none for a run without them.
    :class:`ValueError` (one line naming the file) when it cannot be read or a frame is damaged."""
    from ahrm_stack.perception.frame_record import decode_frame

    path = Path(path)
    path = path if path.suffix == ".mcap" else twin_path(path)
    try:
        from mcap.reader import NonSeekingReader

        with path.open("rb") as stream:
            for _, _, message in NonSeekingReader(stream).iter_messages(topics=[IMAGE_TOPIC]):
                body = json.loads(message.data)
                stamp = body["timestamp"]
                data = base64.b64decode(body["data"])
                yield RecordedFrame(int(message.sequence), stamp["sec"] + stamp["nsec"] * 1e-9, body["format"],
                                    decode_frame(data) if decode else None)
    except OSError as error:
        raise ValueError(f"{path}: cannot read ({error.strerror or error})") from None
    except Exception as error:  # noqa: BLE001 - a damaged file, whatever the library raises
        raise ValueError(f"{path}: not a deploy record with camera frames ({type(error).__name__}: "
                         f"{(str(error).splitlines() or [''])[0]})") from None
