"""The record of a deploy run (issue 58, item 6; ahrm_stack/deploy/record.py, deploy/replay.py): the
telemetry and its MCAP twin hold, per tick, the joint state and torques, the perceived poses with
their stamps, the request and the filtered command; the MCAP file is read back with the ``mcap``
library's own reader (channels, JSON Schemas, every record); a sim run replayed open loop in the
simulator reproduces its joint angles and cube exactly, and a run under a real arm's imperfections
(configs/realism.yaml jaco2) does not, by the lag those imperfections add."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ahrm_stack.deploy import DeployConfigError, load_deploy_settings
from ahrm_stack.deploy.record import read_run
from ahrm_stack.deploy.replay import main as replay_main
from ahrm_stack.deploy.replay import replay
from ahrm_stack.deploy.run import deploy_sim, load_controller_config, open_telemetry
from ahrm_stack.realism import realism_profiles

POLICY = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two runs of the committed default policy on the sim backend, unpaced: without and with a
    JACO2's imperfections."""
    folder = tmp_path_factory.mktemp("record")
    out = {}
    for realism in ("ideal", "jaco2"):
        telemetry = folder / f"{realism}.jsonl"
        settings = load_deploy_settings(realtime=False, telemetry=str(telemetry), duration=4.0, realism=realism)
        deploy_sim(settings, checkpoint=POLICY)
        out[realism] = telemetry
    return out


def test_the_mcap_twin_holds_every_record_for_a_standard_reader(runs):
    from mcap.reader import make_reader

    telemetry = runs["ideal"]
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    with telemetry.with_suffix(".mcap").open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        topics = {channel.topic: channel for channel in summary.channels.values()}
        assert set(topics) == {"/deploy/tick", "/deploy/event", "/deploy/summary"}
        for channel in topics.values():
            assert channel.message_encoding == "json"
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == "jsonschema" and json.loads(schema.data)["type"] == "object"
        messages = [(channel.topic, json.loads(message.data), message.log_time)
                    for _, channel, message in reader.iter_messages(log_time_order=False)]
    assert [m[1] for m in messages] == lines  # every record, in order
    assert messages[-1][0] == "/deploy/summary" and messages[-2][0] == "/deploy/event"
    stamps = [m[2] for m in messages]
    assert stamps == sorted(stamps)


def test_a_tick_holds_the_state_the_perception_and_the_commands(runs):
    record = read_run(runs["ideal"])
    n = 6  # the jaco's joints
    assert record.summary is not None and record.summary["success"]
    assert any(e["event"] == "stop" for e in record.events)
    for tick in record.ticks:
        assert len(tick["q"]) == len(tick["dq"]) == len(tick["tau"]) == len(tick["u"]) == n
        assert len(tick["cube"]) == 7 and all(len(o) == 7 for o in tick["obstacles"])
        assert tick["feedback_t"] <= tick["sent_t"] and tick["poses_t"] <= tick["sent_t"]
        assert abs(np.linalg.norm(tick["cube"][3:]) - 1.0) < 1e-5
    assert len(record.ticks[0]["obstacles"]) >= 1
    torques = np.array([t["tau"] for t in record.ticks])
    assert np.abs(torques).max() > 0.1  # the actuators' forces, not zeros
    assert read_run(runs["ideal"].with_suffix(".mcap")).ticks == record.ticks


def test_a_sim_run_replays_exactly_and_a_run_with_imperfections_does_not(runs):
    config, _ = load_controller_config(POLICY)
    ideal = realism_profiles()["ideal"]
    same = replay(read_run(runs["ideal"].with_suffix(".mcap")), config.task, ideal)
    assert same.recorded.shape == same.predicted.shape and same.recorded.shape[0] > 40
    assert same.largest.max() < 1e-6, same.largest
    np.testing.assert_allclose(same.cube_predicted, same.cube_recorded, atol=1e-5)
    other = replay(read_run(runs["jaco2"]), config.task, ideal)
    assert np.degrees(other.rms.max()) > 0.5  # a JACO2's latency and lag: the arm trails the model


def test_the_replay_command(runs, tmp_path, capsys):
    figure = tmp_path / "replay.png"
    assert replay_main([str(runs["ideal"].with_suffix(".mcap")), "--checkpoint", str(POLICY),
                        "--out", str(figure)]) == 0
    out = capsys.readouterr().out
    assert "RMS" in out and "cube at the last tick" in out and figure.stat().st_size > 10_000
    for argv in ([str(tmp_path / "missing.mcap")], [str(figure)],
                 [str(runs["ideal"]), "--realism", "nosuch"]):
        assert replay_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("error:"), err


def test_a_telemetry_path_named_like_its_twin_is_refused(tmp_path):
    with pytest.raises(DeployConfigError, match="record_mcap"):
        open_telemetry(str(tmp_path / "run.mcap"), mcap=True)
    assert not list(tmp_path.iterdir())  # nothing written
    log = open_telemetry(str(tmp_path / "run.jsonl"), mcap=False)
    log.write(json.dumps({"t": 0.0, "event": "stop", "reason": "x"}) + "\n")
    log.close()
    assert [p.name for p in tmp_path.iterdir()] == ["run.jsonl"]
