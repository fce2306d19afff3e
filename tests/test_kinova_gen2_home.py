"""The homing step (``--home``, ahrm_stack/hardware/kinova_gen2/home.py) on the fake Kinova SDK, whose arm moves
at a finite speed through its trajectory FIFO: MoveHome to kinova-ros's j2n6s300 factory home, an
ANGULAR_POSITION point at its speed limits along a straight joint-space line
(tests/fake_kinova_sdk/fake_kinova.c). No confirmation: nothing moves; a confirmation: the arm ends
at the policy's start (task.arm.home_deg) within the tolerance and passes the deploy loop's start
check; a fault or Ctrl-C on the way: the arm stops short, its FIFO empty, and every path ends with
StopControlAPI and CloseAPI. The fake's home speed is raised (the firmware's is unknown) and the
final speed set above the configured cap, so that each test takes seconds.
(A MoveHome faster than the arm's speed alarm is stopped: the supervision watches it too.)"""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest
import yaml

from ahrm_stack.config import load_config
from ahrm_stack.deploy import DEPLOY_CONFIG, load_deploy_settings, main
from ahrm_stack.deploy.bring_up import home_limits
from ahrm_stack.deploy.start_check import start_refusal
from ahrm_stack.deploy.world import WorldModel
from ahrm_stack.hardware.kinova_gen2 import SYSTEM_ERROR_TYPES, KinovaGen2Arm
from ahrm_stack.hardware.kinova_gen2.home import (BAD_INPUT, DONE, INTERRUPTED, NOT_CONFIRMED, STOPPED,
                                       Homing, path_clearance)

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
SERIAL, FACTORY_HOME = fake_module.SERIAL, np.array(fake_module.FACTORY_HOME)
HOME_SPEED = 30.0  # deg/s, the fake firmware's MoveHome speed here (under the arm's 36 deg/s limit)
SPEED = 40.0  # deg/s, the final move's limit here (configs cap it at 20 for real arms): its joints
# 4-6 (limit 48 deg/s) may go that fast, and joints 1-3 go slower on the way to home_deg


@pytest.fixture(scope="module")
def world():
    return WorldModel(load_config().task)


@pytest.fixture
def start_deg(world):
    return np.degrees(world.task.config.arm.home)


@pytest.fixture
def fake(library):
    sdk = fake_module.FakeSdk(library)
    sdk.reset(position_deg=FACTORY_HOME)
    sdk.set_home(FACTORY_HOME, HOME_SPEED)
    return sdk


def _settings(library, **home):
    settings = load_deploy_settings(realtime=True, telemetry="")
    gen2 = settings.kinova_gen2
    home = dataclasses.replace(gen2.home, **{"speed_deg_s": SPEED, "settle": 0.2, **home})
    return dataclasses.replace(settings, kinova_gen2=dataclasses.replace(
        gen2, library=str(library), serial=SERIAL, home=home))


def _homing(library, world, answer="home", sleep=None, **home):
    settings = _settings(library, **home)
    arm = KinovaGen2Arm(world.robot, settings.kinova_gen2, command_timeout_s=0.1)
    arm.connect()
    lines: list[str] = []
    asked: list[str] = []

    def ask(prompt: str) -> str:
        asked.append(prompt)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    extra = {} if sleep is None else {"sleep": sleep}
    homing = Homing(arm, world, home_limits(world, settings), lines.append,
                    None if answer is None else ask, **extra)
    return homing, arm, lines, asked


def _ends_stopped(fake, mark=0):
    names = [c.function for c in fake.calls(mark)]
    assert names[-2:] == ["StopControlAPI", "CloseAPI"], names[-6:]
    assert fake.fifo_count() == 0 and not fake.control_on
    np.testing.assert_array_equal(fake.state()[1], 0.0)  # the fake arm holds still


def _moves(fake):
    return [c for c in fake.calls() if c.function == "MoveHome"
            or (c.function == "SendAdvanceTrajectory" and c.type == 2)]


@pytest.mark.parametrize("answer", ["", "yes", "PJ009", EOFError()])
def test_no_confirmation_no_motion(fake, library, world, answer):
    homing, arm, lines, asked = _homing(library, world, answer)
    outcome = homing.run()
    assert outcome.status == NOT_CONFIRMED and not outcome.moved, outcome
    assert len(asked) == 1 and SERIAL in asked[0]
    text = "\n".join(lines)  # where the arm is and where it will go, in Kinova's degrees
    assert "now:" in text and "MoveHome" in text and "then:" in text
    assert f"{FACTORY_HOME[0]:.1f}" in text
    assert not _moves(fake)
    np.testing.assert_allclose(fake.state()[0], FACTORY_HOME, atol=1e-9)
    _ends_stopped(fake)


def test_confirmed_homing_ends_at_the_policy_start(fake, library, world, start_deg):
    """From an arbitrary posture: MoveHome (the fake reaches the factory home), then one
    ANGULAR_POSITION point to task.arm.home_deg with the speed limit set; the arm ends there within
    the tolerance, still, and the deploy loop's start check passes there."""
    away = FACTORY_HOME + np.array([-20.0, 10.0, 15.0, -30.0, 20.0, 40.0])
    fake.set_position(away)
    homing, arm, lines, asked = _homing(library, world, f"  {SERIAL} ")
    outcome = homing.run()
    assert outcome.status == DONE and outcome.moved, outcome
    assert len(asked) == 1
    moves = _moves(fake)
    assert [c.function for c in moves] == ["MoveHome", "SendAdvanceTrajectory"]
    # the factory home was reached before the final move was sent
    home_done = [c for c in fake.calls(function="GetAngularPosition") if c.t < moves[1].start]
    np.testing.assert_allclose(home_done[-1].values, FACTORY_HOME, atol=0.05)
    np.testing.assert_allclose(moves[1].values, start_deg, atol=1e-3)
    q, dq = fake.state()
    tolerance = homing.home.tolerance_deg
    assert np.all(np.abs((q - start_deg + 180) % 360 - 180) <= tolerance), q - start_deg
    assert start_refusal(world, np.radians(q), 0.0, 0.0, math.radians(1.0)) is None
    # a finite speed: the final move took at least its longest joint over the speed limit
    took = float(outcome.stages[-1].split("done in ")[1].split(" s")[0])
    assert took >= np.max(np.abs(start_deg - FACTORY_HOME)) / SPEED
    _ends_stopped(fake)


def test_already_at_the_start_moves_nothing_and_asks_nothing(fake, library, world, start_deg):
    fake.set_position(start_deg + 0.3)
    homing, arm, lines, asked = _homing(library, world, "home")
    outcome = homing.run()
    assert outcome.status == DONE and not outcome.moved and "nothing moved" in outcome.reason
    assert not asked and not _moves(fake)
    _ends_stopped(fake)


def test_a_fault_mid_way_stops_the_arm(fake, library, world, start_deg):
    """A system error logged while the final move runs: the status poll sees it, the USB thread
    erases the FIFO at once, the homing stops short of the target and says why."""
    fake.set_position(start_deg + np.array([25.0, -20.0, 15.0, 30.0, -25.0, 20.0]))

    def inject_later(prompt):
        threading.Timer(0.25, fake.inject_error,
                        (SYSTEM_ERROR_TYPES.index("errorlog_Actuator_Temperature"),)).start()
        return "home"

    settings = _settings(library, factory_home_first=False, speed_deg_s=10.0)
    arm = KinovaGen2Arm(world.robot, settings.kinova_gen2, command_timeout_s=0.1)
    arm.connect()
    outcome = Homing(arm, world, home_limits(world, settings), lambda line: None, inject_later).run()
    assert outcome.status == STOPPED and outcome.moved, outcome
    assert "arm fault" in outcome.reason and "errorlog_Actuator_Temperature" in outcome.reason
    q, _ = fake.state()
    assert np.max(np.abs(q - start_deg)) > 5.0  # stopped short
    point = [c for c in fake.calls(function="SendAdvanceTrajectory") if c.type == 2][0]
    assert any(c.function == "EraseAllTrajectories" and c.t > point.t for c in fake.calls())
    _ends_stopped(fake)


def test_ctrl_c_mid_way_stops_the_arm(fake, library, world, start_deg):
    """Ctrl-C during the move (in the supervision's sleep, where it lands): stopped at once."""
    fake.set_position(start_deg + np.array([25.0, -20.0, 15.0, 30.0, -25.0, 20.0]))
    polls = []

    def sleep(seconds):
        polls.append(seconds)
        if len(polls) == 5:
            raise KeyboardInterrupt
        threading.Event().wait(seconds)

    homing, arm, lines, asked = _homing(library, world, "home", sleep=sleep,
                                        factory_home_first=False, speed_deg_s=10.0)
    outcome = homing.run()
    assert outcome.status == INTERRUPTED and outcome.moved and "interrupted" in outcome.reason
    q, _ = fake.state()
    assert np.max(np.abs(q - start_deg)) > 5.0
    _ends_stopped(fake)


def test_a_path_through_the_table_is_refused_before_anything_moves(fake, library, world,
                                                                    start_deg):
    """The final move's joint-space path must keep the tip clearance above the table: with a
    clearance the start itself (0.2 m above the table) cannot meet, nothing moves."""
    fake.set_position(start_deg + 10.0)
    lowest, _ = path_clearance(world, np.radians(start_deg + 10.0), np.radians(start_deg))
    assert 0.0 < lowest < 0.3
    homing, arm, lines, asked = _homing(library, world, "home", factory_home_first=False,
                                        clearance=0.3)
    outcome = homing.run()
    assert outcome.status == BAD_INPUT and not outcome.moved and "above the table" in outcome.reason
    assert not asked and not _moves(fake)
    _ends_stopped(fake)


def test_home_command_line(library, tmp_path, capsys, start_deg):
    """`python -m ahrm_stack.deploy --backend kinova-gen2 --home --yes` (this process's fake)."""
    fake = fake_module.FakeSdk(library)
    fake.reset(position_deg=start_deg + np.array([4.0, -3.0, 3.0, 5.0, -4.0, 3.0]))
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kinova_gen2"].update(library=str(library), serial=SERIAL)
    data["kinova_gen2"]["home"].update(factory_home_first=False, speed_deg_s=20.0, settle=0.2)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--home", "--yes"]) == DONE
    assert "homing: at the policy's start posture" in capsys.readouterr().out
    q, _ = fake.state()
    assert np.max(np.abs(q - start_deg)) <= 1.0
    _ends_stopped(fake)
    for argv in (["--backend", "sim", "--home"], ["--backend", "kinova-gen2", "--yes"],
                 ["--backend", "kinova-gen2", "--home", "--check"]):
        mark = fake.call_count()
        assert main([*argv, "--config", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--" in err, err
        assert fake.call_count() == mark  # the arm was never contacted
    data["kinova_gen2"]["home"]["speed_deg_s"] = 90.0
    path.write_text(yaml.safe_dump(data))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--home"]) == 2
    assert "speed_deg_s" in capsys.readouterr().err


def test_the_fake_moves_a_position_point_at_its_speed_limit(fake):
    """The fake's model of an ANGULAR_POSITION point, against the closed form: a straight joint-space
    line, the slowest joint at its limit, all arriving together (no other point queued)."""
    from ahrm_stack.hardware.kinova_gen2 import TrajectoryPoint, position_point

    fake.set_latency(0.0)
    lib = fake.lib
    assert lib.InitAPI() == 1
    lib.StartControlAPI(), lib.StopControlAPI(), lib.StartControlAPI(), lib.SetAngularControl()
    target = FACTORY_HOME + np.array([12.0, -6.0, 3.0, 0.0, 24.0, -2.0])
    lib.SendAdvanceTrajectory.argtypes = [TrajectoryPoint]
    assert lib.SendAdvanceTrajectory(position_point(target, 40.0)) == 1
    began = fake.calls()[-1].t
    threading.Event().wait(0.3)
    q, dq = fake.state()
    # joints 4-6 move at speedParameter2 = 40 deg/s: joint 5 (24 deg) needs 0.6 s, the others follow
    share = (q - FACTORY_HOME) / (target - FACTORY_HOME + 1e-300)
    moving = target != FACTORY_HOME
    assert np.ptp(share[moving]) < 1e-5  # one straight line (the targets are float32)
    np.testing.assert_allclose(dq[moving] / (target - FACTORY_HOME)[moving], 40.0 / 24.0, rtol=1e-4)
    threading.Event().wait(0.45)
    q, dq = fake.state()
    np.testing.assert_allclose(q, target, atol=1e-4)  # float32
    np.testing.assert_array_equal(dq, 0.0)
    assert fake.fifo_count() == 0 and began > 0
    lib.CloseAPI()


@pytest.mark.parametrize("case", ["timeout", "link lost"])
def test_a_slow_stage_or_a_lost_link_stops_the_homing(fake, library, world, start_deg, case):
    """A stage longer than home.timeout: the arm is stopped (its FIFO erased) short of the target.
    The USB cable pulled mid-way: the homing ends at the next read, saying so (the arm finishes
    what it holds: the fake's pessimistic model of a pulled cable)."""
    fake.set_position(start_deg + np.array([25.0, -20.0, 15.0, 30.0, -25.0, 20.0]))
    if case == "timeout":
        homing, arm, lines, asked = _homing(library, world, "home", factory_home_first=False,
                                            speed_deg_s=10.0, timeout=0.4)
    else:
        def unplug_later(prompt):
            threading.Timer(0.3, fake.set_unplugged, (True,)).start()
            return "home"

        settings = _settings(library, factory_home_first=False, speed_deg_s=10.0)
        arm = KinovaGen2Arm(world.robot, settings.kinova_gen2, command_timeout_s=0.1)
        arm.connect()
        homing = Homing(arm, world, home_limits(world, settings), lambda line: None, unplug_later)
    outcome = homing.run()
    assert outcome.status == STOPPED and outcome.moved, outcome
    if case == "timeout":
        assert "not done after 0.4 s" in outcome.reason
        q, _ = fake.state()
        assert np.max(np.abs(q - start_deg)) > 5.0
        _ends_stopped(fake)
    else:
        assert "lost" in outcome.reason, outcome.reason
        assert not arm.is_connected
        names = [c.function for c in fake.calls()]
        assert names[-1] == "CloseAPI"
