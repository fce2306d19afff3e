"""The tool's touch-off (issue 58, item 3; ahrm_stack/hardware/kinova_gen2/touch_off.py) on the fake
Kinova SDK, whose arm executes position moves at their speed limits: the user's answers are
scripted (down, up, touching). The error at each point is the model's tip height when the user says
"touching", so a tool as modelled passes, a tool 5 mm longer fails; its record is written either
way and a deploy run on the Gen2 backend refuses without a passing record of this arm. A point out
of reach or a path through the table moves nothing; "q", a jog past ``below`` and Ctrl-C stop the
arm, and every path ends with StopControlAPI and CloseAPI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml

from ahrm_stack.config import load_config
from ahrm_stack.deploy import DEPLOY_CONFIG, load_deploy_settings, main
from ahrm_stack.deploy.bring_up import home_limits
from ahrm_stack.deploy.world import WorldModel
from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm
from ahrm_stack.hardware.kinova_gen2.home import BAD_INPUT, DONE, INTERRUPTED, NOT_CONFIRMED, STOPPED
from ahrm_stack.hardware.kinova_gen2.touch_off import FAILED, TouchOff, touch_off_refusal
from test_kinova_gen2_home import _ends_stopped

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
SERIAL = fake_module.SERIAL


@pytest.fixture(scope="module")
def world():
    return WorldModel(load_config().task)


@pytest.fixture
def fake(library, world):
    sdk = fake_module.FakeSdk(library)
    sdk.reset(position_deg=np.degrees(world.task.config.arm.home), velocity_noise=0.0)
    return sdk


def _settings(library, **touch):
    settings = load_deploy_settings(realtime=True, telemetry="")
    gen2 = settings.kinova_gen2
    home = dataclasses.replace(gen2.home, settle=0.1)
    touch_off = dataclasses.replace(gen2.touch_off, **{"speed_deg_s": 20.0, **touch})
    return dataclasses.replace(settings, kinova_gen2=dataclasses.replace(
        gen2, library=str(library), serial=SERIAL, home=home, touch_off=touch_off))


def _touch_off(library, world, answers, **touch):
    settings = _settings(library, **touch)
    arm = KinovaGen2Arm(world.robot, settings.kinova_gen2, command_timeout_s=0.1)
    arm.connect()
    script = iter(answers)
    asked: list[str] = []

    def ask(prompt):
        asked.append(prompt)
        answer = next(script)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    step = TouchOff(arm, world, home_limits(world, settings), settings.kinova_gen2.touch_off,
                    lambda line: None, ask)
    return step, settings, asked


def _answers(downs: int) -> list[str]:
    return ["touch"] + ([""] * downs + ["t"]) * 3


def test_a_tool_as_modelled_passes(fake, library, world, tmp_path):
    """Touching after 30 mm of jogging from the 30 mm approach: the model's tip is at the table."""
    step, settings, asked = _touch_off(library, world, _answers(3), step=0.01)
    outcome = step.run()
    assert outcome.status == DONE and step.passed, outcome
    # the model's tip at its table, to the IK's and Kinova's float angles (a fraction of a mm)
    assert all(abs(r.error) <= 5e-4 for r in step.results), [r.error for r in step.results]
    record = step.record(tmp_path / "touch-off.json")
    assert record["passed"] and record["serial"] == SERIAL and len(record["points"]) == 3
    assert touch_off_refusal(tmp_path / "touch-off.json", SERIAL) is None
    _ends_stopped(fake)


def test_a_longer_tool_fails_and_a_deploy_run_is_refused(fake, library, world, tmp_path):
    """The user feels the touch 5 mm above the model's table (a tool 5 mm longer than modelled,
    or a table 5 mm higher): beyond max_error; the record says so; deploy refuses in one line."""
    step, settings, asked = _touch_off(library, world, ["touch"] + ([""] * 6 + ["t"]) * 3,
                                       step=0.005, approach=0.035)
    outcome = step.run()
    assert outcome.status == FAILED and not step.passed and "FAILED" in outcome.reason, outcome
    np.testing.assert_allclose([r.error for r in step.results], 0.005, atol=5e-4)
    path = tmp_path / "touch-off.json"
    step.record(path)
    assert "failed" in touch_off_refusal(path, SERIAL)
    assert "of arm" in touch_off_refusal(path, "PJ00000000000000000")
    assert "no touch-off record" in touch_off_refusal(tmp_path / "none.json", SERIAL)
    _ends_stopped(fake)
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kinova_gen2"].update(library=str(library), serial=SERIAL, scene="configs/scenes/default.yaml")
    data["kinova_gen2"]["touch_off"].update(record=str(path), required=True)
    config = tmp_path / "deploy.yaml"
    config.write_text(yaml.safe_dump(data))
    mark = fake.call_count()
    assert main(["--backend", "kinova-gen2", "--config", str(config), "--duration", "1"]) == 2
    assert fake.call_count() == mark  # refused before the arm was contacted


def test_nothing_moves_without_a_start_or_out_of_reach(fake, library, world):
    step, settings, asked = _touch_off(library, world, [""])
    outcome = step.run()
    assert outcome.status == NOT_CONFIRMED and not outcome.moved
    _ends_stopped(fake)
    step, settings, asked = _touch_off(library, world, ["touch"], points=((0.0, -0.4), (0.1, 0.1), (0.0, 0.1)))
    outcome = step.run()
    assert outcome.status == BAD_INPUT and not outcome.moved and "out of the arm's reach" in outcome.reason
    assert not asked  # refused before the confirmation
    assert not [c for c in fake.calls() if c.function == "SendAdvanceTrajectory" and c.type == 2]
    _ends_stopped(fake)


@pytest.mark.parametrize("how", ["q", "below", "ctrl-c"])
def test_a_stop_mid_way_stops_the_arm(fake, library, world, how):
    downs = {"q": ["", "q"], "below": [""] * 10, "ctrl-c": ["", KeyboardInterrupt()]}[how]
    step, settings, asked = _touch_off(library, world, ["touch", *downs], step=0.005, below=0.005,
                                       approach=0.01)
    outcome = step.run()
    if how == "ctrl-c":
        assert outcome.status == INTERRUPTED, outcome
    else:
        assert outcome.status == STOPPED, outcome
        assert ("stopped by the user" if how == "q" else "below the model's table") in outcome.reason
    assert outcome.moved and not step.passed
    _ends_stopped(fake)


def test_the_command_line_refuses_two_steps_and_other_backends(tmp_path, capsys):
    for argv in (["--backend", "kinova-gen2", "--touch-off", "--home"],
                 ["--backend", "kinova-gen2", "--touch-off", "--dry-run"],
                 ["--backend", "sim", "--touch-off"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--touch-off" in err or "separate steps" in err, err


def test_the_record_is_json_with_each_points_angles(fake, library, world, tmp_path):
    step, settings, asked = _touch_off(library, world, _answers(3), step=0.01)
    step.run()
    data = json.loads(json.dumps(step.record(tmp_path / "r.json")))
    assert [len(p["q"]) for p in data["points"]] == [6, 6, 6]
    assert [p["point"] for p in data["points"]] == [list(p) for p in settings.kinova_gen2.touch_off.points]
