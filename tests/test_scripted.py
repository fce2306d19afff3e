"""The scripted mink pusher: seeded episodes succeed without touching, and reset re-binds."""

from __future__ import annotations

import numpy as np
import pytest

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask


def _setup(mode: str, seed: int = 0) -> tuple[TaskRunner, ScriptedPusher]:
    config = load_config([f"task.layout.mode={mode}"])
    task = PushOffTask(config.task)
    return TaskRunner(task, seed=seed), ScriptedPusher(task, config.scripted)


@pytest.fixture(scope="module", params=["fixed", "random"])
def rig(request) -> tuple[TaskRunner, ScriptedPusher]:
    return _setup(request.param)


def _episode(runner: TaskRunner, pusher: ScriptedPusher, seed: int) -> dict:
    """One seeded episode; returns success, touching steps, stages and the largest |command|
    relative to the velocity limits."""
    runner.seed(seed)
    runner.reset()
    pusher.reset(runner.physics)
    limit = runner.task.robot.velocity_limit
    touches, stages, worst = 0, {pusher.stage}, 0.0
    while True:
        command = pusher(runner.physics)
        assert command.shape == (runner.task.robot.num_joints,)
        worst = max(worst, float(np.max(np.abs(command) / limit)))
        info, terminated, truncated = runner.step_only(command)
        touches += int(info.touched)
        stages.add(pusher.stage)
        if terminated or truncated:
            return {"success": terminated, "touches": touches, "stages": stages, "worst": worst,
                    "time": info.elapsed}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_episode_succeeds_without_touching(rig, seed: int) -> None:
    runner, pusher = rig
    result = _episode(runner, pusher, seed)
    assert result["success"], f"{runner.task.config.layout.mode} seed {seed}: no success"
    assert result["touches"] == 0, f"{runner.task.config.layout.mode} seed {seed}: touched"
    assert {"travel", "descend", "push"} <= result["stages"]
    assert result["worst"] <= 1.0 + 1e-9  # within the velocity limits
    assert result["time"] < 10.0


def test_reset_rebinds_over_consecutive_episodes() -> None:
    runner, pusher = _setup("random", seed=0)
    assert pusher.model is None and pusher.stage == "idle"
    for seed in (3, 4):  # same physics: the binding is kept, the plan is redone
        runner.seed(seed)
        transition = runner.reset()
        pusher.reset(runner.physics)
        assert pusher.model is runner.physics.model.ptr
        assert pusher.stage == "travel"  # the home posture is above the travel height
        np.testing.assert_allclose(pusher._tip(), transition.info.tip, atol=1e-6)
        pusher(runner.physics)
        assert _episode(runner, pusher, seed)["success"]

    # A new physics (as composer.Environment builds at reset): the pusher must follow it.
    other = TaskRunner(runner.task, seed=5)
    old_model = pusher.model
    transition = other.reset()
    pusher.reset(other.physics)
    assert pusher.model is other.physics.model.ptr and pusher.model is not old_model
    np.testing.assert_allclose(pusher._tip(), transition.info.tip, atol=1e-6)
    result = _episode(other, pusher, 5)
    assert result["success"] and result["touches"] == 0


def test_bad_scripted_config_is_rejected() -> None:
    with pytest.raises(ConfigError, match="scripted.push_speed"):
        load_config(["scripted.push_speed=0"])
    with pytest.raises(ConfigError, match="scripted.collision_gain"):
        load_config(["scripted.collision_gain=2"])
    with pytest.raises(ConfigError, match="scripted.solver"):
        load_config(["scripted.solver=nope"])


def test_demo_cli_errors_are_one_line(capsys) -> None:
    from ahrm_stack import demo

    assert demo.main(["--layout", "fixed", "scripted.nope=1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "scripted.nope" in err
    with pytest.raises(SystemExit) as exit_info:
        demo.main(["--episodes", "0"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--episodes" in err
