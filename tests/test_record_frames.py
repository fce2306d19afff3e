"""Camera frames in the deploy run's record (issue 58, item 6; ``deploy.record_frames``,
ahrm_stack/perception/frame_record.py, ahrm_stack/deploy/record.py): a sim run with the sim camera
writes the frames its perception measured into the MCAP twin as Foxglove's
``foxglove.CompressedImage``, which the ``mcap`` library reads back (decodable grey images of the
camera's size, stamps non-decreasing and equal to the capture stamps the ticks name); with the
setting off there is no image channel; a failing encoder or frame write never stops the run; a run
without a camera refuses the setting in one line, before anything is written."""

from __future__ import annotations

import base64
import json
import logging

import numpy as np
import pytest

from ahrm_stack.deploy import DeployConfigError, load_deploy_settings
from ahrm_stack.deploy.record import IMAGE_TOPIC, RunLog, iter_frames, read_run
from ahrm_stack.deploy.run import deploy_sim
from ahrm_stack.perception import frame_record
from ahrm_stack.perception.frame_record import EncodedFrame, FrameRecording, TappedFrames
from ahrm_stack.perception.settings import load_perception_settings

DURATION = 0.2  # s: 4 ticks at 20 Hz (each renders and detects one 1080p frame)


def _camera_run(folder, **settings):
    telemetry = folder / "telemetry.jsonl"
    deploy_sim(load_deploy_settings(realtime=False, telemetry=str(telemetry), duration=DURATION, **settings),
               scene="camera")
    return telemetry


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two short sim runs of the scripted controller on the sim camera: frames on and off."""
    return {name: _camera_run(tmp_path_factory.mktemp(name), record_frames=on)
            for name, on in (("on", True), ("off", False))}


def test_the_frames_are_foxglove_compressed_images_a_standard_reader_reads(runs):
    import jsonschema
    from mcap.reader import make_reader

    camera = load_perception_settings().camera
    ticks = read_run(runs["on"]).ticks
    assert len(ticks) == round(DURATION * 20)
    with runs["on"].with_suffix(".mcap").open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        channel = next(c for c in summary.channels.values() if c.topic == IMAGE_TOPIC)
        schema = summary.schemas[channel.schema_id]
        assert schema.name == "foxglove.CompressedImage" and schema.encoding == "jsonschema"
        assert channel.message_encoding == "json"
        images = [(message.sequence, json.loads(message.data), message.log_time)
                  for _, _, message in reader.iter_messages(topics=[IMAGE_TOPIC], log_time_order=False)]
    assert len(images) >= len(ticks)  # one per tick, and the start-up's read
    times = []
    for _, body, _ in images:
        jsonschema.validate(body, json.loads(schema.data))
        assert body["format"] == "jpeg" and body["frame_id"] == "perception"
        import cv2

        image = cv2.imdecode(np.frombuffer(base64.b64decode(body["data"]), np.uint8), cv2.IMREAD_UNCHANGED)
        assert image.shape == (camera.height, camera.width) and image.dtype == np.uint8
        assert 50 < image.mean() < 250  # the table seen, not a blank frame
        times.append(body["timestamp"]["sec"] + body["timestamp"]["nsec"] * 1e-9)
    assert times == sorted(times) and [i[2] for i in images] == sorted(i[2] for i in images)
    assert [i[0] for i in images] == list(range(len(images)))  # every frame (record_frames_every 1)
    # each tick names the frame its poses came from: recorded, at the capture stamp the tick says
    by_index = {sequence: t for sequence, t in zip((i[0] for i in images), times)}
    for tick in ticks:
        assert tick["frame"] in by_index
        assert by_index[tick["frame"]] == pytest.approx(tick["frame_t"], abs=1e-6)
        assert tick["frame_t"] == tick["poses_t"]  # the sim camera measures in the tick
    assert [t["frame"] for t in ticks] == sorted({t["frame"] for t in ticks})


def test_the_frames_read_back_as_arrays_and_the_records_as_before(runs):
    camera = load_perception_settings().camera
    frames = list(iter_frames(runs["on"]))  # the JSONL's twin
    assert [f.index for f in frames] == list(range(len(frames)))
    assert all(f.image is not None and f.image.shape == (camera.height, camera.width) for f in frames)
    record = read_run(runs["on"].with_suffix(".mcap"))  # the image channel is not a record
    assert record.ticks == read_run(runs["on"]).ticks and record.summary is not None
    assert [f.index for f in iter_frames(runs["on"].with_suffix(".mcap"), decode=False)] == [f.index for f in frames]


def test_without_the_setting_there_is_no_image_channel(runs):
    from mcap.reader import make_reader

    with runs["off"].with_suffix(".mcap").open("rb") as stream:
        topics = {c.topic for c in make_reader(stream).get_summary().channels.values()}
    assert topics == {"/deploy/tick", "/deploy/event", "/deploy/summary"}
    assert list(iter_frames(runs["off"])) == []
    ticks = read_run(runs["off"]).ticks
    assert ticks and all(t["frame_t"] == t["poses_t"] for t in ticks)  # the ticks still name their frame


def test_a_failing_encoder_does_not_stop_the_run(tmp_path, monkeypatch, caplog):
    def broken(gray, fmt):
        raise RuntimeError("no encoder here")

    monkeypatch.setattr(frame_record, "encode_frame", broken)
    with caplog.at_level(logging.ERROR, logger="ahrm_stack.deploy"):
        telemetry = _camera_run(tmp_path, record_frames=True)
    record = read_run(telemetry.with_suffix(".mcap"))
    assert record.summary is not None and record.summary["fault"] == ""
    assert "duration" in record.summary["stop_reason"] and len(record.ticks) == round(DURATION * 20)
    assert list(iter_frames(telemetry)) == []
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "RuntimeError: no encoder here" in errors[0], errors


def test_a_frame_that_cannot_be_written_drops_the_frames_not_the_records(tmp_path, monkeypatch, caplog):
    import ahrm_stack.deploy.record as record_module

    def broken(frame, t0):
        raise ValueError("cannot serialise")

    monkeypatch.setattr(record_module, "frame_message", broken)
    frames = FrameRecording()
    log = RunLog(tmp_path / "run.jsonl", mcap=True, frames=frames)
    log.start_run(10.0)
    with caplog.at_level(logging.ERROR, logger="ahrm_stack.deploy"):
        for i in range(3):
            frames.put(EncodedFrame(i, 10.0 + i, 4, 2, "png", b"x"))
            log.write(json.dumps({"t": float(i), "q": [0.0]}) + "\n")
        log.write(json.dumps({"summary": {"success": False}}) + "\n")
        log.close()
    assert [r.levelno for r in caplog.records].count(logging.ERROR) == 1
    record = read_run(tmp_path / "run.mcap")
    assert [t["t"] for t in record.ticks] == [0.0, 1.0, 2.0] and record.summary == {"success": False}


def test_every_nth_frame_is_encoded_where_it_is_captured():
    class Frames:
        def __init__(self):
            self.t = 0.0

        def grab(self):
            self.t += 0.1
            return self.t, np.arange(12, dtype=np.uint8).reshape(3, 4) * int(self.t * 10)

    recording = FrameRecording(every=3, fmt="png")
    frames = TappedFrames(Frames(), recording.encoder())
    grabbed = [frames.grab() for _ in range(7)]
    recorded = recording.take()
    assert [f.index for f in recorded] == [0, 3, 6] and recording.take() == []
    for frame in recorded:
        assert frame.stamp == grabbed[frame.index][0] and (frame.width, frame.height) == (4, 3)
        np.testing.assert_array_equal(frame_record.decode_frame(frame.data), grabbed[frame.index][1])  # lossless
    small = FrameRecording(capacity=2)
    for i in range(5):
        small.put(EncodedFrame(i, float(i), 1, 1, "png", b""))
    assert [f.index for f in small.take()] == [3, 4] and small.dropped == 3


def test_the_setting_without_a_camera_or_without_mcap_is_refused_in_one_line(tmp_path):
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    settings = load_deploy_settings(realtime=False, telemetry=str(telemetry), duration=DURATION, record_frames=True)
    with pytest.raises(DeployConfigError, match=r"deploy\.record_frames .*--scene camera") as error:
        deploy_sim(settings, scene="sim")
    assert "\n" not in str(error.value)
    assert not telemetry.parent.exists()  # nothing written
    with pytest.raises(DeployConfigError, match=r"deploy\.record_frames needs deploy\.record_mcap true"):
        load_deploy_settings(record_frames=True, record_mcap=False)
