"""``python -m ahrm_stack.deploy --backend kinova-gen2 --check`` (ahrm_stack/hardware/kinova_gen2/check.py): the
judgement by hand, and the command against the fake SDK in this process (the fake is this process's
library): it measures each call, says whether the budget fits, never moves the arm, and without an
arm ends in the one-line "no arm found" error. Kinova's own binary without an arm:
tests/test_kinova_gen2_vendor.py."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from ahrm_stack.deploy import main
from ahrm_stack.hardware.kinova_gen2.check import TIMED, CallStats, Measurement, Rates, judge, report

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "scenes" / "default.yaml"
RATES = Rates(control_hz=20.0, command_deadline=0.025, send_rate_hz=100.0, send_ahead=0.01,
              status_rate_hz=2.0, torque_each_tick=False)


def _measured(call_ms: float, read_ms: float, rate: float = 100.0) -> Measurement:
    stats = CallStats(100, call_ms, call_ms * 1.1, call_ms * 1.3)
    return Measurement(serial="X", calls={name: stats for name in TIMED},
                       read=CallStats(100, read_ms, read_ms, read_ms), ticks=100, point_rate_hz=rate,
                       raw_velocity_std=1.0, derived_velocity_std=0.0)


def test_the_judgement_by_hand():
    """3 ms calls: bus load 100 x 3 + 20 x 3 + 2 x 9 ms = 37.8 %; the read 6 ms of 25; a held-back point
    3.3 + 3.3 ms within 10 ms: fits. 5 ms calls: 63 % of the bus, and 5.5 + 5.5 > 10 ms: does not."""
    verdict = judge(_measured(3.0, 6.0), RATES)
    assert verdict.fits and all(line.startswith("  fits: ") for line in verdict.lines)
    assert "bus load 38 %" in verdict.lines[0] and "6.60 ms" in verdict.lines[2]
    verdict = judge(_measured(5.0, 6.0), RATES)
    assert not verdict.fits
    assert [line.split(":")[0].strip() for line in verdict.lines] == ["DOES NOT FIT", "fits",
                                                                      "DOES NOT FIT", "fits"]
    slow_read = judge(_measured(3.0, 13.0), RATES)  # over half the 25 ms deadline
    assert not slow_read.fits and "DOES NOT FIT: a tick's position read p99 13.00 ms" in slow_read.lines[1]
    starved = judge(_measured(3.0, 6.0, rate=97.0), RATES)
    assert not starved.fits and "97.0 points/s" in starved.lines[3]
    lines, fits = report(_measured(3.0, 6.0), RATES)
    assert fits and lines[-1] == "the USB budget fits at 20 Hz"
    # torques with every tick (kinova_gen2.torque_each_tick, for the contact stop): 100 x 3 + 20 x
    # (3 + 3) + 2 x (3 + 3) ms = 43.2 %, the status poll down to two calls
    each_tick = judge(_measured(3.0, 6.0), dataclasses.replace(RATES, torque_each_tick=True))
    assert each_tick.fits and "bus load 43 %" in each_tick.lines[0], each_tick.lines[0]
    assert "20 position and torque reads/s, 2 status polls/s of 2 calls" in each_tick.lines[0]


def test_check_measures_the_fake_arm_held_still(library, tmp_path, task_config, capsys, gen2_config):
    """At 3 ms per call the budget fits; a loaded machine may stretch the p99 of a few of the 20
    calls timed here past a timing rule (as it would on a busy robot computer: the check says so),
    never the bus load, which is judged on medians."""
    fake = fake_module.FakeSdk(library)
    home = np.degrees(task_config.arm.home)
    fake.reset(position_deg=home)
    path = gen2_config(library=str(library), serial=fake_module.SERIAL, scene=str(SCENE),
                   check_calls=20)
    code = main(["--backend", "kinova-gen2", "--config", str(path), "--check"])
    out = capsys.readouterr().out
    assert f"serial {fake_module.SERIAL} (held still" in out
    for name in TIMED:
        assert f"  {name}" in out
    # the fake spends at least 3 ms per call: (100 + 20 + 2 x 3) x 3 ms = 37.8 % of each second at the
    # least; a loaded machine stretches the medians (and may then push the load past its limit)
    load = re.search(r"  (fits|DOES NOT FIT): bus load (\d+) %", out)
    assert load is not None, out
    assert int(load.group(2)) >= 38
    if code == 0:
        assert "the USB budget fits at 20 Hz" in out and "DOES NOT FIT" not in out
    else:
        assert code == 1 and "the USB budget does NOT fit at 20 Hz" in out, out
    sends = fake.calls(function="SendAdvanceTrajectory")
    assert len(sends) >= 20 * 5 and not any(c.values.any() for c in sends)  # zero velocities only
    np.testing.assert_allclose(fake.state()[0], home, atol=1e-4)  # the arm never moved
    names = [c.function for c in fake.calls()]
    assert names[-2:] == ["StopControlAPI", "CloseAPI"] and not fake.control_on


def test_check_says_when_the_budget_does_not_fit(library, tmp_path, task_config, capsys, gen2_config):
    """9 ms per call (a slow hub, say): 100 points/s alone fill 90 % of the bus."""
    fake = fake_module.FakeSdk(library)
    fake.reset(position_deg=np.degrees(task_config.arm.home), latency=0.009)
    path = gen2_config(library=str(library), serial=fake_module.SERIAL, scene=str(SCENE),
                   check_calls=10)
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--check"]) == 1
    out = capsys.readouterr().out
    assert "DOES NOT FIT: bus load" in out and "the USB budget does NOT fit at 20 Hz" in out


def test_check_without_an_arm_is_one_line(library, tmp_path, capsys, gen2_config):
    fake = fake_module.FakeSdk(library)
    fake.reset(serials=())
    path = gen2_config(library=str(library), serial=fake_module.SERIAL, scene=str(SCENE))
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--check"]) == 3
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "no Kinova arm found on USB" in err[0] and "Traceback" not in captured.err
    assert [c.function for c in fake.calls()] == ["InitAPI", "CloseAPI"]


def test_check_refuses_a_backend_without_one_and_bad_settings(tmp_path, capsys, gen2_config):
    assert main(["--backend", "sim", "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--backend sim has none" in err
    path = gen2_config(library=None)
    assert main(["--backend", "kinova-gen2", "--config", str(path), "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "deploy.kinova_gen2.library is not set" in err
