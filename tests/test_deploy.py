"""The deploy command: the scripted controller pushes the cube off on the sim backend; settings
are validated; Ctrl-C stops the arm; the observation is built exactly like training's; a policy
checkpoint loads and drives the loop."""

from __future__ import annotations

import io
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from ahrm_stack.config import load_config, load_raw
from ahrm_stack.deploy import (DEPLOY_CONFIG, DeployConfigError, DeployLoop, ScriptedController,
                               WorldModel, deploy_sim, load_deploy_settings, main)
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm


def test_deploy_command_pushes_the_cube_off_with_the_scripted_controller(tmp_path, capsys):
    telemetry = tmp_path / "telemetry.jsonl"
    code = main(["--backend", "sim", "--fast", "--duration", "20", "--rate", "20",
                 "--telemetry", str(telemetry)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "deploy summary: success True" in out and "deadline misses 0" in out
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    ticks = [line for line in lines if "latency_ms" in line]
    assert ticks and {"t", "phase", "x", "u_nom", "u", "active", "status"} <= set(ticks[0])
    assert {2, 3} <= {t["phase"] for t in ticks}  # pre-manipulated, then manipulated
    for tick in ticks:  # every command sent was within the velocity limits
        assert len(tick["u"]) == 6 and all(np.isfinite(tick["u"]))
    assert lines[-1]["summary"]["success"] is True
    assert lines[-1]["summary"]["deadline_misses"] == 0
    assert any(line.get("event") == "stop" and "success" in line["reason"] for line in lines)


def test_deploy_settings_errors_name_the_key(tmp_path):
    raw = yaml.safe_load(DEPLOY_CONFIG.read_text())
    settings = load_deploy_settings()
    assert settings.period == pytest.approx(1.0 / raw["rate_hz"])
    assert settings.kortex.address is None  # never a default address

    def bad(mutate) -> str:
        data = yaml.safe_load(DEPLOY_CONFIG.read_text())
        mutate(data)
        path = tmp_path / "deploy.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(DeployConfigError) as error:
            load_deploy_settings(path)
        return str(error.value)

    assert "deploy.rate_hz" in bad(lambda d: d.update(rate_hz=0))
    assert "deploy.watchdog.max_feedback_age" in bad(lambda d: d["watchdog"].update(max_feedback_age="x"))
    assert "deploy.watchdog.colour" in bad(lambda d: d["watchdog"].update(colour=1))
    assert "deploy.sim.command_delay" in bad(lambda d: d["sim"].pop("command_delay"))
    assert "deploy.realtime" in bad(lambda d: d.update(realtime="yes"))
    assert "deploy.kortex.port" in bad(lambda d: d["kortex"].update(port=-1))
    with pytest.raises(DeployConfigError, match="deploy.rate_hz"):
        load_deploy_settings(rate_hz=-5.0)


def test_bad_command_line_is_rejected(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--backend", "sim", "--fast", "--realtime"])
    assert exit_.value.code == 2
    assert main(["--backend", "sim", "--rate", "0"]) == 2
    assert "deploy.rate_hz" in capsys.readouterr().err


def _loop(settings_overrides=None):
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="", **(settings_overrides or {}))
    arm = SimArm(config.task, seed=0, clock=FastClock())
    world = WorldModel(config.task, seed=0)
    arm.connect()
    telemetry = io.StringIO()
    return arm, world, config, settings, telemetry


def test_the_loop_refuses_to_run_without_the_safety_filter():
    import dataclasses

    arm, world, config, settings, telemetry = _loop()
    unsafe = dataclasses.replace(config.safety, enabled=False)
    with pytest.raises(DeployConfigError, match="safety.enabled"):
        DeployLoop(arm, world, ScriptedController(world, config), unsafe, settings, telemetry)


def test_sigint_stops_the_arm_before_exit():
    # Python's own Ctrl-C handler (KeyboardInterrupt), as in the CLI: an earlier test in this
    # process (Ray, a collector) may have replaced it
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _sigint_run()
    finally:
        signal.signal(signal.SIGINT, previous)


def _sigint_run():
    arm, world, config, settings, telemetry = _loop()
    scripted = ScriptedController(world, config)

    class InterruptedController:
        stage = "test"
        calls = 0

        def reset(self):
            scripted.reset()

        def __call__(self):
            self.calls += 1
            if self.calls == 12:  # a real SIGINT, as Ctrl-C sends, mid-run
                os.kill(os.getpid(), signal.SIGINT)
            return scripted()

    loop = DeployLoop(arm, world, InterruptedController(), config.safety, settings, telemetry)
    summary = loop.run(10.0)
    assert loop.interrupted and "interrupted" in summary.stop_reason
    np.testing.assert_array_equal(arm.command, 0.0)  # stopped before returning
    *_, stop, last = [json.loads(line) for line in telemetry.getvalue().splitlines()]
    assert stop["event"] == "stop" and "interrupted" in stop["reason"]
    assert last["summary"]["stop_reason"] == summary.stop_reason  # the run writes its summary
    assert arm.violations == 0


def test_observation_is_built_exactly_like_training():
    arm, world, config, settings, telemetry = _loop()
    loop = DeployLoop(arm, world, ScriptedController(world, config), config.safety, settings,
                      telemetry)
    loop.start()
    sim_task = arm.task
    for step in range(40):
        assert loop.tick(), loop.stop_reason
        if step % 10 != 9:
            continue
        # The simulator's own task measures its true state, as in training (after a call that
        # brings the sim up to date: it applies the last command at the next call).
        feedback = arm.refresh_feedback()
        sim_task.after_step(arm.physics, arm.runner.random_state)
        expected = sim_task.flat_observation(arm.physics)
        info = world.update(feedback, arm.perception(), 0.0)
        assert sim_task.observation_order == world.task.observation_order
        np.testing.assert_allclose(world.observation(), expected, atol=1e-9)
        assert info.phase == sim_task.step_info.phase
        assert info.x == pytest.approx(sim_task.step_info.x, abs=1e-9)


ACTION_DIMS = {"joint": 5, "cartesian": 3}  # commanded joints 1-5; the tip's linear velocity


@pytest.mark.parametrize("mode", ["cartesian", "joint"])
def test_policy_checkpoint_drives_the_loop(tmp_path, mode):
    from ahrm_stack.learning.ppo import make_modules

    config = load_config([f"task.action.mode={mode}"])
    world = WorldModel(config.task)
    observation_dim = world.observation().shape[0]
    modules = make_modules(config.ppo, observation_dim, ACTION_DIMS[config.task.action.mode])
    run = tmp_path / "run"
    run.mkdir()
    raw = load_raw()
    raw["task"]["action"]["mode"] = mode
    (run / "config.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    torch.save({"actor": modules.actor.state_dict(), "observation_dim": observation_dim,
                "action_dim": ACTION_DIMS[config.task.action.mode], "episodes": 0, "frames": 0},
               run / "policy.pt")
    telemetry = tmp_path / "policy.jsonl"
    settings = load_deploy_settings(realtime=False, duration=1.0, telemetry=str(telemetry))
    loop = deploy_sim(settings, run)
    summary = loop.summary()
    assert summary.ticks == 20 and "duration" in summary.stop_reason, summary
    assert summary.deadline_misses == 0 and summary.emergency_stops == 0
    ticks = [json.loads(line) for line in telemetry.read_text().splitlines() if "latency_ms" in line]
    assert len(ticks) == 20 and all(t["stage"] == "policy" for t in ticks)


TRAINED = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0"


def test_trained_policy_pushes_the_cube_off_through_the_deploy_loop(tmp_path, capsys):
    """The committed policy of the learnability study's default run (AHRM, seed 0, 600 episodes)
    drives the sim backend through the whole deploy path and pushes the cube off."""
    telemetry = tmp_path / "trained.jsonl"
    code = main(["--backend", "sim", "--fast", "--duration", "20", "--checkpoint", str(TRAINED),
                 "--telemetry", str(telemetry)])
    out = capsys.readouterr().out
    assert code == 0 and "deploy summary: success True" in out, out
    ticks = [json.loads(line) for line in telemetry.read_text().splitlines() if "latency_ms" in line]
    assert ticks and all(t["stage"] == "policy" and len(t["u_nom"]) == 3 for t in ticks)
    assert {2, 3} <= {t["phase"] for t in ticks}


SCRATCH = Path(__file__).resolve().parents[1] / "docs" / "scratch-study" / "round5" / "runs" / "mirror-nj-ahrm-seed0"


def test_a_policy_learned_from_scratch_pushes_the_cube_off_through_the_deploy_loop(tmp_path, capsys):
    """The committed best policy of the scratch study's round 5 (AHRM in the lane frame, no
    demonstrations; 39/40 held-out episodes at 0.8M frames), chosen with ``--policy-file``, drives
    the sim backend through the whole deploy path (its lane frame in the numpy fast path) and pushes
    the cube off; the run folder holds no final ``policy.pt``."""
    assert not (SCRATCH / "policy.pt").exists()
    telemetry = tmp_path / "scratch.jsonl"
    code = main(["--backend", "sim", "--fast", "--duration", "20", "--checkpoint", str(SCRATCH),
                 "--policy-file", str(SCRATCH / "policies" / "episode-20472.pt"),
                 "--telemetry", str(telemetry)])
    out = capsys.readouterr().out
    assert code == 0 and "deploy summary: success True" in out, out
    ticks = [json.loads(line) for line in telemetry.read_text().splitlines() if "latency_ms" in line]
    assert ticks and all(t["stage"] == "policy" and len(t["u_nom"]) == 3 for t in ticks)


def test_the_lane_choice_is_planned_from_the_first_perceived_scene():
    """The world model's own layout at construction is a random one; the observation's lane
    (task.observation.lane_choice) must come from the first scene perception reports."""
    from ahrm_stack.env.layout import Layout, choose_lane

    config = load_config(["task.observation.lane_choice=true"])
    t = config.task
    directions = list(t.layout.lane_directions)
    for arm_seed in range(6):
        arm = SimArm(config.task, seed=arm_seed, clock=FastClock())
        world = WorldModel(config.task, seed=100)
        arm.connect()
        feedback, poses = arm.refresh_feedback(), arm.perception()
        info = world.update(feedback, poses, 0.0)
        layout = Layout(poses.cube_position[:2], poses.obstacle_positions[:, :2])
        lane = choose_lane(layout, info.tip[:2], t.cube.size / 2, np.asarray(t.obstacles.size[:2]) / 2,
                           t.table, t.layout)
        np.testing.assert_array_equal(world.observation()[-2:], np.eye(len(directions))[lane])
        arm.disconnect()
