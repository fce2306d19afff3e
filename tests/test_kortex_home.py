"""The Kortex homing step (``--home``, ahrm_stack/hardware/kortex/home.py) on the fake ``kortex_api``,
whose arm runs a ReachJointAngles action along a straight joint-space line at a bounded speed and
sends ACTION_START / ACTION_END / ACTION_ABORT through the subscribed callback on a thread of its own
(tests/fake_kortex_api/kortex_api/_fake_arm.py). No confirmation: nothing moves; a confirmation: the
arm ends at the policy's start (task.arm.home_deg) within the tolerance. Ctrl-C, the timeout, the
e-stop, a fault, a lost link, a timed-out RPC, an abort by the arm or a joint off the planned path,
mid-move: ``Base.Stop`` goes out within one control period of the event (the time from the event to
the Stop RPC, read from the fake's call log), the arm stops short, and every path ends with
Unsubscribe, Stop and CloseSession. The command line runs the fake in a child process (the
deployed path: kortex_api in a process of its own).

``python tests/test_kortex_home.py`` prints the measured stop latencies."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time

if __name__ == "__main__":  # run as a script: this checkout's packages, not an installed copy
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import yaml  # noqa: E402

from fake_kortex_api.rig import HERE, PASSWORD, child_spec, make_child, make_for  # noqa: E402
from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.deploy import DEPLOY_CONFIG, load_deploy_settings, main  # noqa: E402
from ahrm_stack.deploy.bring_up import home_limits  # noqa: E402
from ahrm_stack.deploy.start_check import start_refusal  # noqa: E402
from ahrm_stack.deploy.world import WorldModel  # noqa: E402
from ahrm_stack.hardware.kortex.home import (BAD_INPUT, DONE, INTERRUPTED, NOT_CONFIRMED,  # noqa: E402
                                             STOPPED, KortexHoming)
from ahrm_stack.hardware.kortex.moves import kortex_degrees  # noqa: E402

SPEED = 20.0  # deg/s: kortex.home.speed_deg_s's largest allowed value, so that each test is short
AWAY = np.array([10.0, -8.0, 6.0, 12.0, -10.0, 8.0])  # deg from the start: 0.6 s at SPEED
FAR = np.array([25.0, -20.0, 15.0, 30.0, -25.0, 20.0])  # deg: 1.5 s at SPEED
PERIOD = 0.05  # s: configs/deploy.yaml's rate_hz 20


@pytest.fixture(scope="module")
def world():
    return WorldModel(load_config().task)


def _settings(**home):
    settings = load_deploy_settings(realtime=True, telemetry="")
    k = settings.kortex
    home = dataclasses.replace(k.home, **{"speed_deg_s": SPEED, **home})
    return dataclasses.replace(settings, kortex=dataclasses.replace(k, home=home))


def _start(world) -> np.ndarray:
    return np.degrees(world.task.config.arm.home)


def _homing(world, offset=AWAY, answer="home", sleep=None, fake_kwargs=None, **home):
    """(homing, adapter, fake arm, printed lines, prompts) for an arm ``offset`` deg from the start."""
    settings = _settings(**home)
    adapter, fake = make_for(world.robot, positions_deg=_start(world) + offset, **(fake_kwargs or {}))
    adapter.connect()
    lines: list[str] = []
    asked: list[str] = []

    def ask(prompt: str) -> str:
        asked.append(prompt)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    extra = {} if sleep is None else {"sleep": sleep}
    homing = KortexHoming(adapter, world, home_limits(world, settings, settings.kortex.home),
                          settings.period, lines.append, None if answer is None else ask, **extra)
    return homing, adapter, fake, lines, asked


def _ends_stopped(fake, adapter):
    """Every exit: Stop, then (Unsubscribe,) Stop and CloseSession; no action runs."""
    names = [c.name for c in fake.calls]
    assert names[-2:] == ["Stop", "CloseSession"], names[-6:]
    assert not adapter.is_connected and fake.sessions == 0 and not fake.moving_action
    np.testing.assert_array_equal(fake.command, 0.0)


def _first_stop_after(fake, t: float):
    return next(c for c in fake.calls if c.name == "Stop" and c.time >= t)


def _stopped_short(fake, start):
    off = np.abs(fake.read_positions() - start)
    assert off.max() > 3.0, off  # stopped well before the target


@pytest.mark.parametrize("answer", ["", "yes", "192.0.2.999", EOFError()])
def test_no_confirmation_no_motion(world, answer):
    homing, adapter, fake, lines, asked = _homing(world, answer=answer)
    before = fake.read_positions()
    outcome = homing.run()
    assert outcome.status == NOT_CONFIRMED and not outcome.moved, outcome
    assert len(asked) == 1 and adapter.address in asked[0]
    text = "\n".join(lines)  # where the arm is and where it will go, in the arm's degrees
    assert "now:" in text and "target:" in text and "MODEL_ID_L53 (Gen3), 6 DoF" in text
    assert f"{kortex_degrees(np.radians(_start(world)), ~world.robot.limited)[0]:.1f}" in text
    assert "ExecuteAction" not in [c.name for c in fake.calls]
    np.testing.assert_allclose(fake.read_positions(), before, atol=1e-9)
    _ends_stopped(fake, adapter)


def test_confirmed_homing_ends_at_the_policy_start(world):
    """Subscribe, then one ReachJointAngles action (the target in the arm's degrees, the speed
    constraint set); ACTION_START, ACTION_END; the arm there within the tolerance, the deploy loop's
    start check passing; then Stop, Unsubscribe, Stop, CloseSession."""
    homing, adapter, fake, lines, asked = _homing(world)
    homing.ask = lambda prompt: f"  {adapter.address} "  # the arm's address confirms (or "home")
    outcome = homing.run()
    assert outcome.status == DONE and outcome.moved, outcome
    start = _start(world)
    names = [c.name for c in fake.calls if c.name != "RefreshFeedback"]
    i = names.index("ExecuteAction")
    assert names[i - 1] == "OnNotificationActionTopic"  # subscribed before the action
    assert names[i + 1:] == ["Stop", "Unsubscribe", "Stop", "CloseSession"]
    action = fake.actions[0]
    sent = np.asarray(action["target"])  # the arm's convention: equal to the start modulo 360
    np.testing.assert_allclose((sent - start + 180.0) % 360.0 - 180.0, 0.0, atol=1e-6)
    np.testing.assert_allclose(sent, kortex_degrees(np.radians(start), ~world.robot.limited), atol=1e-6)
    assert action["speed"] == pytest.approx(SPEED)
    assert [name for name, _ in fake.notified] == ["ACTION_START", "ACTION_END"]
    q = fake.read_positions()
    assert np.all(np.abs((q - start + 180) % 360 - 180) <= homing.home.tolerance_deg)
    assert start_refusal(world, np.radians(q), 0.0, 0.0, math.radians(1.0)) is None
    took = float(outcome.stages[-1].split("done in ")[1].split(" s")[0])
    assert took >= np.max(np.abs(AWAY)) / SPEED - 0.05  # a finite speed
    _ends_stopped(fake, adapter)


def test_already_at_the_start_moves_nothing_and_asks_nothing(world):
    homing, adapter, fake, lines, asked = _homing(world, offset=np.full(6, 0.3))
    outcome = homing.run()
    assert outcome.status == DONE and not outcome.moved and "nothing moved" in outcome.reason
    assert not asked and "ExecuteAction" not in [c.name for c in fake.calls]
    _ends_stopped(fake, adapter)


def test_a_path_through_the_table_is_refused_before_anything_moves(world):
    homing, adapter, fake, lines, asked = _homing(world, offset=np.full(6, 10.0), clearance=0.3)
    outcome = homing.run()
    assert outcome.status == BAD_INPUT and not outcome.moved and "above the table" in outcome.reason
    assert "kortex.home.clearance" in outcome.reason and "\n" not in outcome.reason
    assert not asked and "ExecuteAction" not in [c.name for c in fake.calls]
    _ends_stopped(fake, adapter)


# ---------------------------------------------------------------------------------------------
# Stopping mid-move: each event -> Base.Stop within one control period
# ---------------------------------------------------------------------------------------------


def ctrl_c_latency(world) -> float:
    """Ctrl-C in the supervision's sleep (where it lands) on the 8th poll: s to the Stop RPC."""
    polls: list[float] = []
    raised: list[float] = []

    def sleep(seconds):
        polls.append(seconds)
        if len(polls) == 8:
            raised.append(time.perf_counter())
            raise KeyboardInterrupt
        time.sleep(seconds)

    homing, adapter, fake, _, _ = _homing(world, offset=FAR, sleep=sleep)
    outcome = homing.run()
    assert outcome.status == INTERRUPTED and outcome.moved and "interrupted" in outcome.reason
    _stopped_short(fake, _start(world))
    assert ("ACTION_ABORT" in [name for name, _ in fake.notified])
    _ends_stopped(fake, adapter)
    return _first_stop_after(fake, raised[0]).time - raised[0]


def timeout_latency(world) -> float:
    """home.timeout 0.4 s on a 1.5 s move: s from the deadline to the Stop RPC."""
    homing, adapter, fake, _, _ = _homing(world, offset=FAR, timeout=0.4)
    outcome = homing.run()
    assert outcome.status == STOPPED and "not done after 0.4 s (kortex.home.timeout)" in outcome.reason
    _stopped_short(fake, _start(world))
    _ends_stopped(fake, adapter)
    deadline = homing.move_began + 0.4
    return _first_stop_after(fake, deadline).time - deadline


def injected_latency(world, event: str, arg=None, expect: str = "") -> tuple[float, object]:
    """The fake arm's ``event`` 0.3 s into a 1.5 s move: s from it to the Stop RPC; the outcome."""
    homing, adapter, fake, _, _ = _homing(world, offset=FAR)
    fake.after_action(0.3, event, arg)
    outcome = homing.run()
    assert outcome.status == STOPPED and outcome.moved, outcome
    assert expect in outcome.reason, outcome.reason
    _stopped_short(fake, _start(world))
    assert not adapter.is_connected and not fake.moving_action
    (name, when), = fake.injected
    assert name == event
    return _first_stop_after(fake, when).time - when, outcome



def test_ctrl_c_mid_move_stops_within_one_period(world):
    assert ctrl_c_latency(world) < PERIOD


def test_the_timeout_stops_within_one_period(world):
    assert timeout_latency(world) < PERIOD


def test_the_estop_mid_move_stops_within_one_period(world):
    """The arm's e-stop button: it stops itself and reports the fault; the homing sees it at the
    next poll and sends Stop."""
    latency, outcome = injected_latency(world, "estop", expect="arm fault")
    assert "EMERGENCY_STOP" in outcome.reason
    assert latency < PERIOD


def test_a_fault_mid_move_stops_within_one_period(world):
    latency, outcome = injected_latency(world, "fault", expect="arm fault")
    assert latency < PERIOD


def test_a_lost_link_mid_move_sends_stop_and_disconnects(world):
    """The link drops: the next read fails, the adapter sends its best-effort Stop (with the
    lost-link timeout) and closes, and the homing says why."""
    latency, outcome = injected_latency(world, "lose_connection", expect="connection lost")
    assert "RefreshFeedback" in outcome.reason
    assert latency < PERIOD


def test_the_arm_aborting_the_action_stops_the_homing(world):
    latency, outcome = injected_latency(world, "abort", expect="the arm aborted the action (ACTION_ABORT")
    assert latency < PERIOD


def test_a_feedback_rpc_timing_out_mid_move_stops_the_arm(world):
    """Every RefreshFeedback from 0.3 s on takes 1 s (past the 40 ms rpc timeout): the read fails
    after its timeout and Stop follows at once."""
    homing, adapter, fake, _, _ = _homing(world, offset=FAR)
    fake.after_action(0.3, "latency", ["RefreshFeedback", 1.0])
    outcome = homing.run()
    assert outcome.status == STOPPED and "RefreshFeedback: no answer within 40 ms" in outcome.reason
    (_, when), = fake.injected
    timed_out = next(c for c in fake.calls if c.name == "RefreshFeedback" and c.time >= when)
    stop = _first_stop_after(fake, timed_out.time)
    assert stop.time - (timed_out.time + 0.04) < PERIOD
    _stopped_short(fake, _start(world))


def test_a_continuous_joint_going_the_long_way_round_is_stopped(world):
    """An arm that took a continuous joint the long way round would leave the path whose clearance
    was checked: stopped once a joint is path_tolerance_deg off it."""
    homing, adapter, fake, _, _ = _homing(world, offset=AWAY, fake_kwargs={"long_way": True})
    outcome = homing.run()
    assert outcome.status == STOPPED and "off the planned joint-space path" in outcome.reason
    _ends_stopped(fake, adapter)


def test_the_child_process_link_stops_on_ctrl_c_mid_call(world, monkeypatch, tmp_path):
    """Through the kortex_api process (the deployed link): a Ctrl-C lands while a feedback read
    waits for its answer, which stays in the pipe; the Stop after it goes out at once and is
    answered as the Stop, and Unsubscribe and the disconnect work (the fake arm's log, on the
    machine's monotonic clock)."""
    log = tmp_path / "calls.jsonl"
    settings = _settings()
    adapter = make_child(world.robot, monkeypatch, log=str(log),
                         positions_deg=(_start(world) + FAR).tolist())
    adapter.connect()
    link, raised = adapter.link, []
    receive, reads = link._receive, []

    def interrupted(limit_ms, what):
        if what == "feedback":
            reads.append(what)
            if len(reads) == 6 and not raised:  # the 4th poll's read: mid-move
                raised.append(time.monotonic())
                raise KeyboardInterrupt
        return receive(limit_ms, what)

    monkeypatch.setattr(link, "_receive", interrupted)
    homing = KortexHoming(adapter, world, home_limits(world, settings, settings.kortex.home),
                          settings.period, lambda line: None, None)
    outcome = homing.run()
    assert outcome.status == INTERRUPTED and outcome.moved and raised
    seen = [json.loads(line) for line in log.read_text().splitlines()]
    names = [c["name"] for c in seen if c["name"] != "RefreshFeedback"]
    assert names[-6:] == ["OnNotificationActionTopic", "ExecuteAction", "Stop", "Unsubscribe", "Stop",
                          "CloseSession"], names
    stop = next(c for c in seen if c["name"] == "Stop" and c["t"] >= raised[0])
    assert stop["t"] - raised[0] < PERIOD
    assert not adapter.is_connected and link.pid is None  # closed cleanly, the child ended


def _cli_config(tmp_path, monkeypatch, world, *, models=True, **kortex):
    """deploy.yaml with the Kortex arm's address, a 6-DoF Gen3 entry for the policy's robot (the
    fake reports one), the credentials in the environment and the fake kortex_api (and its arm
    FAR from the start) on the child's path."""
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kortex"].update({"address": "192.0.2.201", **kortex})
    data["kortex"]["home"]["speed_deg_s"] = SPEED
    if models:
        data["kortex"]["models"] = {"jaco": {"model": "MODEL_ID_L53", "dof": 6}}
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("KORTEX_USERNAME", "admin")
    monkeypatch.setenv("KORTEX_PASSWORD", PASSWORD)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("FAKE_KORTEX_ARM", child_spec(world.robot, positions_deg=_start(world) + AWAY))
    return path


def test_home_command_line(world, tmp_path, monkeypatch, capsys):
    """``python -m ahrm_stack.deploy --backend kortex --home --yes`` (the fake in the child
    process); bad input: one line, exit 2, nothing contacted."""
    path = _cli_config(tmp_path, monkeypatch, world)
    assert main(["--backend", "kortex", "--config", str(path), "--home", "--yes"]) == DONE
    out = capsys.readouterr().out
    assert "homing: at the policy's start posture" in out and "now:" in out
    for argv, expected in ((["--touch-off"], "--touch-off moves a Kinova arm (--backend kinova-gen2)"),
                           (["--home", "--check"], "separate steps")):
        assert main(["--backend", "kortex", "--config", str(path), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, err
    path = _cli_config(tmp_path, monkeypatch, world, models=False)
    assert main(["--backend", "kortex", "--config", str(path), "--home", "--yes"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "has no deploy.kortex.models entry" in err and "'jaco'" in err
    path = _cli_config(tmp_path, monkeypatch, world, address=None)
    assert main(["--backend", "kortex", "--config", str(path), "--home"]) == 2
    assert "deploy.kortex.address is not set" in capsys.readouterr().err
    path = _cli_config(tmp_path, monkeypatch, world)
    data = yaml.safe_load(path.read_text())
    data["kortex"]["home"]["poll_periods"] = 0.8
    path.write_text(yaml.safe_dump(data))
    assert main(["--backend", "kortex", "--config", str(path), "--home"]) == 2
    err = capsys.readouterr().err.strip()
    assert "deploy.kortex.home.poll_periods must be <= 0.5" in err and "\n" not in err


def test_a_soft_limit_below_the_policy_refuses_home_in_one_line(world, tmp_path, monkeypatch, capsys):
    path = _cli_config(tmp_path, monkeypatch, world)
    slow = np.degrees(world.robot.velocity_limit)
    slow[2] *= 0.5
    soft = [{"control_mode": mode, "joint_speed": slow.tolist(), "joint_acceleration": []}
            for mode in ("ANGULAR_JOYSTICK", "ANGULAR_TRAJECTORY")]
    monkeypatch.setenv("FAKE_KORTEX_ARM", child_spec(world.robot, soft_limits=soft))
    assert main(["--backend", "kortex", "--config", str(path), "--home", "--yes"]) == 3
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in captured.err
    assert (f"has a joint speed soft limit of {slow[2]:.1f} deg/s on joint 2 (ANGULAR_JOYSTICK); the "
            f"policy's robot 'jaco' (6 joints) was trained with {2 * slow[2]:.1f} deg/s") in err


if __name__ == "__main__":
    here = WorldModel(load_config().task)
    runs = {"Ctrl-C": [], "timeout": [], "e-stop": [], "fault": [], "lost link": []}
    for _ in range(5):
        runs["Ctrl-C"].append(ctrl_c_latency(here))
        runs["timeout"].append(timeout_latency(here))
        runs["e-stop"].append(injected_latency(here, "estop")[0])
        runs["fault"].append(injected_latency(here, "fault")[0])
        runs["lost link"].append(injected_latency(here, "lose_connection")[0])
    for name, values in runs.items():
        ms = np.asarray(values) * 1e3
        print(f"{name:10s} event -> Stop RPC (ms, 5 runs): min {ms.min():.2f}, median {np.median(ms):.2f}, "
              f"max {ms.max():.2f}; limit one period {PERIOD * 1e3:.0f} ms")
