"""The Kinova Gen2 backend in the full deploy loop on the fake SDK (the goal of issue 19 item 1,
briefly: `python benchmarks/bench_kinova_gen2.py` measures it at full size), the static scene, and
`python -m ahrm_stack.deploy --backend kinova-gen2` end to end."""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from ahrm_stack.deploy import DEPLOY_CONFIG, main
from hardware.scene import SceneError, StaticScene

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "scenes" / "default.yaml"


@pytest.fixture(scope="module")
def library():
    try:
        return fake_module.session_library()
    except fake_module.CompilerMissing as error:
        pytest.skip(str(error))


def _bench():
    spec = importlib.util.spec_from_file_location("bench_kinova_gen2",
                                                  ROOT / "benchmarks" / "bench_kinova_gen2.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_deploy_loop_at_20_hz_sends_at_100_hz_within_limits_and_the_watchdog_stops(library):
    r = _bench().deploy_on_fake(duration=1.5, freezes=3)
    assert r["over"] == 0 and r["commands"] > 0  # nothing outside the filter's bound reached the arm
    assert r["moved_deg"] > 1.0  # the scripted controller moved the arm
    assert r["send_gap_p50_ms"] == pytest.approx(10.0, abs=2.0)  # 100 Hz between policy ticks
    # the goal (<= 20 ms) on the median; every stop well inside one command timeout even on a
    # loaded machine (the benchmark reports the maximum)
    latencies = r["latencies_ms"]
    assert (latencies >= 0).all() and np.median(latencies) <= 20.0, latencies
    assert (latencies <= r["timeout_ms"]).all(), latencies


def test_static_scene_reads_and_validates(tmp_path):
    scene = StaticScene(SCENE, num_obstacles=4)
    poses = scene.poses(12.5)
    assert poses.timestamp == 12.5 and poses.finite
    assert poses.obstacle_positions.shape == (4, 3) and not poses.obstacle_velocities.any()
    np.testing.assert_allclose(poses.cube_quaternion, [1, 0, 0, 0])

    def bad(text: str, **kwargs) -> str:
        path = tmp_path / "scene.yaml"
        path.write_text(text)
        with pytest.raises(SceneError) as error:
            StaticScene(path, **kwargs)
        assert "\n" not in str(error.value) and str(path) in str(error.value)
        return str(error.value)

    good = yaml.safe_load(SCENE.read_text())
    assert "obstacles has 4 entries; the task has 3" in bad(yaml.safe_dump(good), num_obstacles=3)
    assert "cube.position" in bad(yaml.safe_dump({**good, "cube": {"position": [0, 0]}}))
    assert "cube.quaternion" in bad(yaml.safe_dump({**good, "cube": {"position": [0, 0, 0.4],
                                                                    "quaternion": [1, 0, 0, 1]}}))
    assert "obstacles[1].position" in bad(yaml.safe_dump(
        {**good, "obstacles": [good["obstacles"][0], {"position": [0, ".nan", 0]}]}))
    assert "unknown key colour" in bad(yaml.safe_dump({**good, "colour": "red"}))
    with pytest.raises(SceneError, match="cannot read the scene layout"):
        StaticScene(tmp_path / "none.yaml")


def _config(tmp_path: Path, **gen2) -> Path:
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kinova_gen2"].update(gen2)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_deploy_refuses_a_missing_sdk_in_one_line(tmp_path, capsys):
    missing = tmp_path / "USBCommandLayerUbuntu.so"
    path = _config(tmp_path, library=str(missing), serial=fake_module.SERIAL, scene=str(SCENE))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--telemetry", ""]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(missing) in err and "docs/hardware.md" in err
    path = _config(tmp_path, library=str(missing), serial=None, scene=str(SCENE))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--telemetry", ""]) == 2


def test_deploy_command_runs_the_fake_arm(library, tmp_path, task_config, capsys, caplog):
    """`python -m ahrm_stack.deploy --backend kinova-gen2` (its main, in this process: the fake
    SDK is this process's library). Missed deadlines are tolerated here (a loaded machine); the
    run must connect by serial, tick, end when the duration runs out and leave the arm stopped."""
    fake = fake_module.FakeSdk(library)
    fake.reset(position_deg=np.degrees(task_config.arm.home))
    path = _config(tmp_path, library=str(library), serial=fake_module.SERIAL, scene=str(SCENE))
    data = yaml.safe_load(path.read_text())
    data["watchdog"]["max_deadline_misses"] = 1000
    path.write_text(yaml.safe_dump(data))
    telemetry = tmp_path / "telemetry.jsonl"
    with caplog.at_level(logging.INFO, logger="hardware.kinova_gen2"):
        code = main(["--backend", "kinova-gen2", "--config", str(path), "--duration", "1",
                     "--telemetry", str(telemetry)])
    out = capsys.readouterr().out
    assert code == 1, out  # the duration ran out (a static cube never leaves the table)
    assert "deploy summary" in out and "duration of 1 s reached" in out
    messages = " ".join(r.getMessage() for r in caplog.records)
    assert f"connected to the arm with serial {fake_module.SERIAL}" in messages
    assert "disconnected" in messages
    lines = telemetry.read_text().splitlines()
    assert '"summary"' in lines[-1] and len(lines) > 10
    names = [c.function for c in fake.calls()]
    assert names[-2:] == ["StopControlAPI", "CloseAPI"] and not fake.control_on
    assert len(fake.calls(function="SendAdvanceTrajectory")) > 20
