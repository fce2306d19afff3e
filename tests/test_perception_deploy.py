"""The camera scene source in the deploy loop: ``deploy --scene camera`` runs the loop on AprilTag
frames with a surveyed layout file; a lost tag stops the arm with a one-line perception fault; a
bad layout file is bad input (exit 2, nothing written)."""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.deploy import (DeployFault, DeployLoop, ScriptedController, WorldModel,
                               load_deploy_settings, main)
from ahrm_stack.perception.scene_source import LayoutFileObstacles, MeasuredScene, write_layout_file
from ahrm_stack.perception.settings import load_perception_settings
from ahrm_stack.perception.tracker import CubeTracker
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm

TRAINED = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0"


class ReplayCube:
    """A cube pose source that reports the simulator's cube through the real tracker and stops
    seeing the tag after ``visible`` frames."""

    def __init__(self, arm, visible: int) -> None:
        self.arm, self.visible, self.frames = arm, visible, 0
        self.tracker = CubeTracker(load_perception_settings().tracker, "tag tag36h11 id 0")

    def cube(self):
        self.frames += 1
        poses = self.arm.perception()
        seen = self.frames <= self.visible
        return self.tracker.update(self.arm.clock.now(), poses.cube_position if seen else None,
                                   poses.cube_quaternion if seen else None)


def test_a_lost_tag_stops_the_loop_with_a_perception_fault(tmp_path):
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="")
    arm = SimArm(config.task, seed=0, clock=FastClock())
    world = WorldModel(config.task, seed=0)
    arm.connect()
    truth = arm.perception()
    layout = write_layout_file(tmp_path / "layout.yaml", truth.obstacle_positions,
                               truth.obstacle_quaternions)
    scene = MeasuredScene(LayoutFileObstacles(layout, count=len(truth.obstacle_positions)),
                          ReplayCube(arm, visible=15))
    telemetry = io.StringIO()
    loop = DeployLoop(arm, world, ScriptedController(world, config), config.safety, settings,
                      telemetry, scene)
    with pytest.raises(DeployFault, match=r"perception fault: TagLostError: tag tag36h11 id 0 "
                                          r"not seen for 0\.300 s > tracker\.max_hold 0\.25 s"):
        loop.run(10.0)
    # the tag was held for max_hold (5 ticks at 20 Hz) with prediction, then the arm stopped
    assert loop.summary().ticks == 15 + 5 + 1 - 1  # start-up used frame 1
    np.testing.assert_array_equal(arm.command, 0.0)
    *_, stop, last = [json.loads(line) for line in telemetry.getvalue().splitlines()]
    assert stop["event"] == "stop" and "TagLostError" in stop["reason"]
    assert "TagLostError" in last["summary"]["fault"]
    assert arm.violations == 0


def test_bad_layout_file_is_bad_input(tmp_path, capsys):
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    layout = tmp_path / "layout.yaml"
    layout.write_text("obstacles:\n- {position: [0.1, 0.1, 0.45], yaw_deg: 0}\n")
    code = main(["--backend", "sim", "--fast", "--scene", "camera", "--layout-file", str(layout),
                 "--telemetry", str(telemetry)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"layout file {layout}: 1 obstacles; the task has 4" in err
    assert not telemetry.parent.exists()  # nothing written


def test_deploy_scene_camera_runs_the_trained_policy_on_tag_frames(tmp_path, capsys):
    telemetry = tmp_path / "run" / "telemetry.jsonl"
    code = main(["--backend", "sim", "--fast", "--scene", "camera", "--duration", "0.6",
                 "--checkpoint", str(TRAINED), "--telemetry", str(telemetry)])
    out = capsys.readouterr().out
    assert code == 1 and "stop: duration of 0.6 s reached" in out, out  # ran, no fault
    surveyed = LayoutFileObstacles(telemetry.parent / "layout.yaml", count=4)
    assert np.isfinite(surveyed.positions).all()
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    ticks = [line for line in lines if "latency_ms" in line]
    assert len(ticks) == 12 and lines[-1]["summary"]["fault"] == ""


def test_a_camera_that_cannot_see_the_tag_is_a_start_up_fault(tmp_path, capsys, monkeypatch):
    import ahrm_stack.perception.settings as perception_settings

    real = perception_settings.load_perception_settings()
    away = dataclasses.replace(real, camera=dataclasses.replace(real.camera,
                                                                look_at=(0.0, -3.0, 0.0)))
    monkeypatch.setattr(perception_settings, "load_perception_settings", lambda *a, **k: away)
    telemetry = tmp_path / "telemetry.jsonl"
    code = main(["--backend", "sim", "--fast", "--scene", "camera", "--duration", "1",
                 "--telemetry", str(telemetry)])
    captured = capsys.readouterr()
    assert code == 3, captured.out + captured.err
    assert "not in the camera image at the start" in captured.err
    last = json.loads(telemetry.read_text().splitlines()[-1])
    assert "TagLostError" in last["summary"]["fault"]


def test_a_survey_without_telemetry_lives_in_a_temporary_folder_removed_at_the_end(
        tmp_path, capsys, monkeypatch):
    import tempfile

    import ahrm_stack.perception.sim_camera as sim_camera

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    written: list[Path] = []
    survey = sim_camera.survey_obstacles

    def recording_survey(arm, path):
        written.append(Path(survey(arm, path)))
        return written[-1]

    monkeypatch.setattr(sim_camera, "survey_obstacles", recording_survey)
    code = main(["--backend", "sim", "--fast", "--scene", "camera", "--duration", "0.3",
                 "--telemetry", ""])
    out = capsys.readouterr().out
    assert code == 1 and "stop: duration of 0.3 s reached" in out, out
    assert len(written) == 1 and written[0].parent.parent == tmp_path  # surveyed into tmp_path
    assert list(tmp_path.iterdir()) == []  # and removed when the run ended
