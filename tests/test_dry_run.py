"""--dry-run on the sim backend (ahrm_stack.hardware.dry_run): the loop runs as live and writes the
same telemetry, the command gate still refuses a bad command (and e-stops), and nothing reaches the
simulated arm's actuators."""

import json

import numpy as np
import pytest

from ahrm_stack.deploy import load_deploy_settings
from ahrm_stack.deploy.run import deploy_sim
from ahrm_stack.hardware.dry_run import DryRunArm
from ahrm_stack.hardware.protocol import CommandRefusedError, FastClock, Fault
from ahrm_stack.sim_arm import SimArm


def test_a_dry_run_computes_and_logs_every_command_and_moves_nothing(tmp_path, monkeypatch):
    seen = []
    read = DryRunArm.refresh_feedback

    def recording(self):
        frame = read(self)
        seen.append(np.array(frame.position))
        return frame

    monkeypatch.setattr(DryRunArm, "refresh_feedback", recording)
    telemetry = tmp_path / "t.jsonl"
    settings = load_deploy_settings(realtime=False, telemetry=str(telemetry), duration=1.0)
    loop = deploy_sim(settings, dry_run=True)
    assert isinstance(loop.arm, DryRunArm) and loop.arm.withheld == loop.summary().ticks > 10
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    assert lines[0]["event"] == "dry run" and "summary" in lines[-1]
    commands = np.array([line["u"] for line in lines if "u" in line])
    asked = np.abs(commands.sum(axis=0) * settings.period).max()  # rad the filtered commands would move
    assert asked > 0.1
    # the joints moved by far less: the simulated arm's sag under gravity alone (a few mrad per s)
    assert np.abs(np.array(seen) - seen[0]).max() < 0.1 * asked
    live = deploy_sim(load_deploy_settings(realtime=False, telemetry="", duration=1.0))
    assert live.summary().ticks == loop.summary().ticks


def test_the_gate_still_refuses_and_e_stops_in_a_dry_run(task_config):
    arm = DryRunArm(SimArm(task_config, seed=0, clock=FastClock()))
    arm.connect()
    try:
        arm.send_joint_speeds(np.zeros(arm.num_joints))
        assert arm.withheld == 1
        with pytest.raises(CommandRefusedError):
            arm.send_joint_speeds(arm.velocity_limit * 2)
        assert arm._fault_state()[0] & Fault.EMERGENCY_STOP and arm.withheld == 1
    finally:
        arm.disconnect()
