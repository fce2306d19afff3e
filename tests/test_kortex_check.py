"""``python -m ahrm_stack.deploy --backend kortex --check`` (ahrm_stack/hardware/kortex/check.py): the
judgement by hand, and the command against the fake ``kortex_api`` in a child process (the deployed
link): it times a run's per-tick RPCs (RefreshFeedback, a zero SendJointSpeedsCommand) here and in
the kortex_api process, prints the arm's model, soft limits and protection zones, never moves the
arm, and fails (exit 1) when the fake's RPCs are slower than the send deadline or time out; without
a Gen3 policy or an address, one line and exit 2; without an arm, one line and exit 3."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest
import yaml

from fake_kortex_api.rig import HERE, PASSWORD, child_spec
from ahrm_stack.deploy import DEPLOY_CONFIG, main
from ahrm_stack.hardware.call_stats import CallStats
from ahrm_stack.hardware.kortex.check import CALLS, Measurement, Rates, judge, report

RATES = Rates(control_hz=20.0, send_deadline=0.025, rpc_timeout_ms=40)
TICKS = 20


def _measured(read_ms: float, send_ms: float, timeouts: int = 0) -> Measurement:
    def stats(ms):
        return CallStats(100, ms, ms * 1.2, ms * 1.5)

    calls = {"RefreshFeedback": stats(read_ms), "SendJointSpeedsCommand": stats(send_ms)}
    return Measurement(address="192.0.2.9", arm="MODEL_ID_L53 (Gen3), 7 DoF", ticks=100,
                       calls=calls, vendor=calls, tick=stats(read_ms + send_ms), timeouts=timeouts,
                       soft_limits=("ANGULAR_JOYSTICK: speed (50.0) deg/s, acceleration not reported",),
                       zones="kortex arm: ...; no protection zones")


def test_the_judgement_by_hand():
    """2 + 1 ms: the tick's p99 3.6 ms of 25: fits. 15 + 7 ms: p99 26.4 ms: does not. A timed-out
    call fails whatever the percentiles."""
    verdict = judge(_measured(2.0, 1.0), RATES)
    assert verdict.fits and all(line.startswith("  fits: ") for line in verdict.lines)
    assert "p99 3.60 ms of the 25 ms send deadline" in verdict.lines[0]
    slow = judge(_measured(15.0, 7.0), RATES)
    assert not slow.fits and slow.lines[0].startswith("  DOES NOT FIT: a tick's") and "26.40" in slow.lines[0]
    assert slow.lines[1].startswith("  fits: 0 of 200 calls unanswered")
    lost = judge(_measured(2.0, 1.0, timeouts=1), RATES)
    assert not lost.fits and lost.lines[1].startswith("  DOES NOT FIT: 1 of 200 calls unanswered within "
                                                      "kortex.rpc_timeout_ms (40 ms")
    lines, fits = report(_measured(2.0, 1.0), RATES)
    assert fits and lines[-1] == "the Kortex link fits at 20 Hz"
    assert any("ANGULAR_JOYSTICK" in line for line in lines) and "no protection zones" in "\n".join(lines)


def _config(tmp_path, monkeypatch, robot, *, models=True, log=None, **arm):
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kortex"].update(address="192.0.2.202", check_ticks=TICKS)
    if models:
        data["kortex"]["models"] = {"jaco": {"model": "MODEL_ID_L53", "dof": 6}}
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("KORTEX_USERNAME", "admin")
    monkeypatch.setenv("KORTEX_PASSWORD", PASSWORD)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    if log is not None:
        arm["log"] = str(log)
    monkeypatch.setenv("FAKE_KORTEX_ARM", child_spec(robot, **arm))
    return path


@pytest.fixture(scope="module")
def robot():
    from ahrm_stack.robot import describe, make_arm

    return describe("jaco", make_arm("jaco"))


def _calls(log) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()]


def test_check_measures_the_fake_arm_held_still(robot, tmp_path, monkeypatch, capsys):
    """The fake answers in well under a millisecond: the tick fits (a loaded machine may stretch a
    p99 past 25 ms: then the check says so, exit 1). The arm never moves: zero speeds only."""
    log = tmp_path / "calls.jsonl"
    zones = [{"name": "shelf", "enabled": True, "shape_type": 3, "origin": [2.0, 2.0, 0.5],
              "dimensions": [0.2, 0.2, 0.2], "envelope": 0.01}]
    path = _config(tmp_path, monkeypatch, robot, log=log, zones=zones)
    code = main(["--backend", "kortex", "--config", str(path), "--check"])
    out = capsys.readouterr().out
    assert "kortex --check on the arm at 192.0.2.202: MODEL_ID_L53 (Gen3), 6 DoF (held still" in out
    assert f"{TICKS} ticks at 20 Hz" in out
    for name in CALLS:
        assert re.search(rf"  {name} +p50 [\d.]+ / p99 [\d.]+ / max [\d.]+ ms \({TICKS} calls\) \| "
                         rf"p50 [\d.]+ / p99 [\d.]+ / max [\d.]+ ms \({TICKS} calls\)", out), out
    assert "ANGULAR_JOYSTICK: speed (36.0, 36.0, 36.0, 48.0, 48.0, 48.0) deg/s" in out
    assert "'shelf'" in out  # the protection zones
    if code == 0:
        assert out.rstrip().endswith("the Kortex link fits at 20 Hz") and "DOES NOT FIT" not in out
    else:
        assert code == 1 and "DOES NOT FIT: a tick's" in out, out
    seen = _calls(log)
    names = [c["name"] for c in seen]
    assert names.count("RefreshFeedback") >= TICKS and names.count("SendJointSpeedsCommand") == TICKS
    assert names[-2:] == ["Stop", "CloseSession"] and "ExecuteAction" not in names
    assert all(c["timeout_ms"] == 40 for c in seen if c["name"] in CALLS)


def test_check_fails_when_the_rpcs_are_slower_than_the_deadline(robot, tmp_path, monkeypatch, capsys):
    """RefreshFeedback takes 30 ms (within its 40 ms timeout, past the 25 ms send deadline)."""
    path = _config(tmp_path, monkeypatch, robot, latency={"RefreshFeedback": 0.03})
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 1
    out = capsys.readouterr().out
    p99 = float(re.search(r"DOES NOT FIT: a tick's RefreshFeedback \+ SendJointSpeedsCommand p99 "
                          r"([\d.]+) ms of the 25 ms send deadline", out).group(1))
    assert p99 >= 30.0
    assert "fits: 0 of 40 calls unanswered" in out
    assert out.rstrip().endswith("the Kortex link does NOT fit at 20 Hz: see docs/kortex.md (Bring-up, "
                                 "--check) before any motion")


def test_check_fails_when_rpcs_time_out(robot, tmp_path, monkeypatch, capsys):
    path = _config(tmp_path, monkeypatch, robot, latency={"SendJointSpeedsCommand": 0.06})
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 1
    out = capsys.readouterr().out
    assert f"DOES NOT FIT: {TICKS} of {2 * TICKS} calls unanswered within kortex.rpc_timeout_ms (40 ms" in out


def test_check_refuses_bad_input_in_one_line(robot, tmp_path, monkeypatch, capsys):
    path = _config(tmp_path, monkeypatch, robot, models=False)
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "has no deploy.kortex.models entry" in err and "Traceback" not in captured.err
    data = yaml.safe_load(path.read_text())
    data["kortex"]["check_ticks"] = 3
    path.write_text(yaml.safe_dump(data))
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert "deploy.kortex.check_ticks must be >= 10" in err and "\n" not in err


def test_check_without_an_arm_is_one_line(robot, tmp_path, monkeypatch, capsys):
    path = _config(tmp_path, monkeypatch, robot)
    monkeypatch.delenv("FAKE_KORTEX_ARM")  # no arm at the address
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 3
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "192.0.2.202" in err and "Traceback" not in captured.err
    assert PASSWORD not in captured.err


def test_check_a_soft_limit_below_the_policy_is_refused(robot, tmp_path, monkeypatch, capsys):
    slow = np.degrees(robot.velocity_limit)
    slow[4] = 10.0
    soft = [{"control_mode": mode, "joint_speed": slow.tolist(), "joint_acceleration": []}
            for mode in ("ANGULAR_JOYSTICK", "ANGULAR_TRAJECTORY")]
    path = _config(tmp_path, monkeypatch, robot, soft_limits=soft)
    assert main(["--backend", "kortex", "--config", str(path), "--check"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "joint speed soft limit of 10.0 deg/s on joint 4 (ANGULAR_JOYSTICK)" in err
