"""The arm must start near the posture the policy was trained from (ahrm_stack/deploy/start_check.py):
by hand for both ``task.arm.start`` kinds, and ``deploy --backend kinova-gen2`` refusing an arm left
elsewhere in one line, before any motion (the fake SDK)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from ahrm_stack.deploy import DEPLOY_CONFIG, WorldModel, main
from ahrm_stack.deploy.start_check import start_refusal
from conftest import touched_off

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "scenes" / "default.yaml"
JOINT, MARGIN, TILT = math.radians(5.0), 0.03, math.radians(10.0)


@pytest.fixture(scope="module")
def world(task_config):
    return WorldModel(task_config)


def test_random_start_checks_the_tip_region_and_the_tilt(world, task_config):
    assert task_config.arm.start == "random"
    home = np.asarray(task_config.arm.home)
    tip, axis = world.tip_pose(home)  # the home posture: tip at (0.1, 0.2, 0.6), pusher down
    np.testing.assert_allclose(tip, [0.1, 0.2, 0.6], atol=0.01)
    assert axis[2] < -0.99
    assert start_refusal(world, home, JOINT, MARGIN, TILT) is None
    swung = home.copy()
    swung[0] += math.radians(90)  # the base joint: the tip leaves the region (x -0.3 m)
    refusal = start_refusal(world, swung, JOINT, MARGIN, TILT)
    assert refusal is not None and "task.arm.start_region" in refusal and "\n" not in refusal
    assert "outside" in refusal and "move the arm there first" in refusal
    tilted = home.copy()
    tilted[4] += math.radians(25)  # the wrist: the tip stays near, the pusher tilts
    refusal = start_refusal(world, tilted, JOINT, 0.3, TILT)
    assert refusal is not None and "deg from straight down" in refusal
    assert start_refusal(world, tilted, JOINT, 0.3, math.radians(40)) is None


def test_home_start_checks_each_joint(task_config):
    arm = dataclasses.replace(task_config.arm, start="home")
    world = WorldModel(dataclasses.replace(task_config, arm=arm))
    home = np.asarray(task_config.arm.home)
    near = home + math.radians(3.0)  # within joint_jitter (2.9 deg) + 5 deg on every joint
    assert start_refusal(world, near, JOINT, MARGIN, TILT) is None
    turned = home.copy()
    turned[0] += 2 * math.pi  # a continuous joint a whole turn on: the same posture
    assert start_refusal(world, turned, JOINT, MARGIN, TILT) is None
    off = home.copy()
    off[2] += math.radians(12.0)
    refusal = start_refusal(world, off, JOINT, MARGIN, TILT)
    assert refusal is not None and "joint 2" in refusal and "12.0 deg from task.arm.home_deg" in refusal
    assert "allowed 7.9" in refusal and "\n" not in refusal


def test_deploy_refuses_an_arm_left_elsewhere_in_one_line(tmp_path, task_config, capsys):
    fake_module = pytest.importorskip("fake_kinova_sdk.fake")
    try:
        library = fake_module.session_library()
    except fake_module.CompilerMissing as error:
        pytest.skip(str(error))
    fake = fake_module.FakeSdk(library)
    away = np.degrees(task_config.arm.home) + [90.0, 0, 0, 0, 0, 0]
    fake.reset(position_deg=away)
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kinova_gen2"].update(library=str(library), serial=fake_module.SERIAL, scene=str(SCENE))
    touched_off(data, tmp_path)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--telemetry", ""]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "does not start near the posture the policy was trained from" in err[0]
    assert "Traceback" not in captured.err
    assert not any(c.values.any() for c in fake.calls(function="SendAdvanceTrajectory"))
    np.testing.assert_allclose(fake.state()[0], away, atol=1e-4)  # nothing moved
    assert [c.function for c in fake.calls()][-2:] == ["StopControlAPI", "CloseAPI"]
