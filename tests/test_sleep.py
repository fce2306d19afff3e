"""``task.episode.sleep``: MuJoCo's body sleeping in the stepped physics (TaskRunner).

Sleeping objects leave the physics step; what must not change is what the task sees: a touch of a
sleeping obstacle, a state written into a sleeping object, the arm's response to commands. Each
check compares against the same physics with sleeping off (the reference), not against itself.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from ahrm_stack.config import config_from_dict, load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask

ROOT = Path(__file__).resolve().parent.parent
SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)


def _runner(sleep: bool, seed: int = 3) -> TaskRunner:
    config = load_config(["task.layout.mode=random", f"task.episode.sleep={str(sleep).lower()}"])
    runner = TaskRunner(PushOffTask(config.task), seed=seed, safety=config.safety)
    runner.reset()
    return runner


def _trees(runner: TaskRunner) -> tuple[int, list[int]]:
    """(the arm's kinematic tree, the free objects' trees) of the runner's model."""
    model, task = runner.physics.model.ptr, runner.task
    arm = int(model.body_treeid[model.jnt_bodyid[runner.physics.bind(task._arm.joints[0]).element_id]])
    objects = sorted({int(model.body_treeid[b]) for b in [task._cube_body, *task._obstacle_bodies]})
    return arm, objects


def test_the_flag_follows_the_config():
    assert runner_flag(_runner(True)) and not runner_flag(_runner(False))


def runner_flag(runner: TaskRunner) -> bool:
    return bool(runner.physics.model.ptr.opt.enableflags & SLEEP)


def test_old_run_folders_keep_the_awake_physics():
    """A run folder written before the key existed loads with sleeping off (its episodes replay)."""
    run = ROOT / "docs/scratch-study/round6/runs/mirror-nj-fhrm-seed0"
    assert "sleep" not in (run / "config.yaml").read_text()
    assert config_from_dict(yaml.safe_load((run / "config.yaml").read_text())).task.episode.sleep is False
    assert load_config([]).task.episode.sleep is False  # the shipped default


def test_objects_fall_asleep_at_reset_and_the_arm_never_does():
    runner = _runner(True)
    data = runner.physics.data.ptr
    arm, objects = _trees(runner)
    assert data.tree_awake[arm] == 1 and all(data.tree_awake[t] == 0 for t in objects)
    for _ in range(20):  # zero commands, the arm at rest: it stays awake and still obeys
        runner.step_only(np.zeros(6))
    assert data.tree_awake[arm] == 1
    q = runner.task.arm_state(runner.physics)[0].copy()
    for _ in range(4):
        runner.step_only(np.full(6, 0.2))
    moved = runner.task.arm_state(runner.physics)[0] - q
    assert np.all(np.abs(moved) > 0.02)  # 0.2 rad/s for 0.2 s, less the actuators' lag


def test_a_state_written_into_a_sleeping_object_takes_effect():
    runner = _runner(True)
    data, task = runner.physics.data.ptr, runner.task
    _, objects = _trees(runner)
    assert all(data.tree_awake[t] == 0 for t in objects)
    before = np.array(data.xpos[task._cube_body])
    adr = runner.physics.model.ptr.jnt_qposadr[runner.physics.model.ptr.body_jntadr[task._cube_body]]
    data.qpos[adr] += 0.1
    mujoco.mj_forward(runner.physics.model.ptr, data)
    np.testing.assert_allclose(np.array(data.xpos[task._cube_body]) - before, [0.1, 0.0, 0.0], atol=1e-12)


def _arm_in_an_obstacle(runner: TaskRunner, rng: np.random.Generator):
    """Arm joint vectors (within limits) at which, with every body awake, an arm geom touches an
    obstacle of ``runner``'s current scene: found by sampling on a copy without sleeping."""
    model = runner.physics.model.ptr
    reference = mujoco.MjData(model)
    mujoco.mj_copyData(reference, model, runner.physics.data.ptr)
    flags = model.opt.enableflags
    model.opt.enableflags = flags & ~SLEEP
    task, robot = runner.task, runner.task.robot
    lower = np.maximum(robot.position_lower, -np.pi)  # continuous joints: one turn
    upper = np.minimum(robot.position_upper, np.pi)
    try:
        mujoco.mj_resetData(model, reference)  # every tree awake
        reference.qpos[:] = runner.physics.data.ptr.qpos
        for _ in range(20000):
            reference.qpos[task._arm_qpos] = rng.uniform(lower, upper)
            mujoco.mj_forward(model, reference)
            pairs = np.array(reference.contact.geom)
            hits = task._is_obstacle[pairs].any(axis=1) & task._is_toucher[pairs].any(axis=1)
            if hits.any():
                yield np.array(reference.qpos[task._arm_qpos])
    finally:
        model.opt.enableflags = flags


@pytest.mark.parametrize("seed", [3, 11])
def test_a_touch_of_a_sleeping_obstacle_is_seen(seed):
    """The arm placed into a sleeping obstacle: the contact is there (the task reports the touch,
    as it does with every body awake) and the obstacle wakes at the next step."""
    rng = np.random.default_rng(seed)
    runner = _runner(True, seed=seed)
    model, data, task = runner.physics.model.ptr, runner.physics.data.ptr, runner.task
    _, objects = _trees(runner)
    assert all(data.tree_awake[t] == 0 for t in objects)
    state = np.array(data.qpos)
    q = next(_arm_in_an_obstacle(runner, rng))
    data.qpos[:] = state
    data.qpos[task._arm_qpos] = q
    mujoco.mj_forward(model, data)
    assert task._measure(runner.physics, phase_time=0.05).touched
    mujoco.mj_step(model, data)
    touched = {int(model.body_treeid[model.geom_bodyid[g]]) for g in np.array(data.contact.geom).ravel()
               if task._is_obstacle[g]}
    assert touched and all(data.tree_awake[t] == 1 for t in touched)


def test_the_scripted_controller_still_pushes_the_cube_off():
    """The teacher on random layouts with sleeping: every episode a success without touching, as
    without it (README: 20/20 clean on the same seeds)."""
    config = load_config(["task.layout.mode=random", "task.episode.sleep=true"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    pusher = ScriptedPusher(task, config.scripted)
    for seed in range(6):
        runner.seed(seed)
        runner.reset()
        pusher.reset(runner.physics)
        touched = terminated = truncated = False
        while not (terminated or truncated):
            info, terminated, truncated = runner.step_only(pusher(runner.physics))
            touched |= info.touched
        assert terminated and not touched, seed
