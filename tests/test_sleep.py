"""``task.episode.sleep``: MuJoCo's body sleeping in the stepped physics (TaskRunner).

Sleeping obstacles leave the physics step; what must not change is what the task sees: a touch of
a sleeping obstacle, a cube resting against one, a state written into a sleeping object, the arm's
response to commands. The touch checks compare with the same physics with sleeping off.
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
    config = load_config(["task.layout.mode=random", f"task.episode.sleep={str(sleep).lower()}",
                          "task.realism=ideal"])
    runner = TaskRunner(PushOffTask(config.task), seed=seed, safety=config.safety)
    runner.reset()
    return runner


def _trees(runner: TaskRunner) -> tuple[int, int, list[int]]:
    """(the arm's kinematic tree, the cube's, the obstacles') of the runner's model."""
    model, task = runner.physics.model.ptr, runner.task
    arm = int(model.body_treeid[model.jnt_bodyid[runner.physics.bind(task._arm.joints[0]).element_id]])
    obstacles = sorted({int(model.body_treeid[b]) for b in task._obstacle_bodies})
    return arm, int(model.body_treeid[task._cube_body]), obstacles


def _sleeping(runner: TaskRunner) -> bool:
    """Whether the runner's model has body sleeping on."""
    return bool(runner.physics.model.ptr.opt.enableflags & SLEEP)


def test_the_flag_follows_the_config():
    assert _sleeping(_runner(True)) and not _sleeping(_runner(False))


def test_old_run_folders_keep_the_awake_physics():
    """A run folder written before the key existed loads with sleeping off (its episodes replay)."""
    run = ROOT / "tests/data/legacy_run_configs/scratch-study/round6/runs/mirror-nj-fhrm-seed0"  # as written
    assert "sleep" not in (run / "config.yaml").read_text()
    assert config_from_dict(yaml.safe_load((run / "config.yaml").read_text())).task.episode.sleep is False
    assert load_config([]).task.episode.sleep is False  # the shipped default


def test_obstacles_fall_asleep_at_reset_and_the_arm_and_cube_never_do():
    runner = _runner(True)
    data = runner.physics.data.ptr
    arm, cube, obstacles = _trees(runner)
    assert all(data.tree_awake[t] == 0 for t in obstacles)
    for _ in range(20):  # zero commands, everything at rest: the arm and the cube stay awake
        runner.step_only(np.zeros(6))
    assert data.tree_awake[arm] == 1 and data.tree_awake[cube] == 1
    q = runner.task.arm_state(runner.physics)[0].copy()
    for _ in range(4):
        runner.step_only(np.full(6, 0.2))
    moved = runner.task.arm_state(runner.physics)[0] - q
    assert np.all(np.abs(moved) > 0.02)  # 0.2 rad/s for 0.2 s, less the actuators' lag


def test_a_state_written_into_a_sleeping_object_takes_effect():
    runner = _runner(True)
    model, data, task = runner.physics.model.ptr, runner.physics.data.ptr, runner.task
    _, _, obstacles = _trees(runner)
    assert all(data.tree_awake[t] == 0 for t in obstacles)
    body = int(task._obstacle_bodies[0])
    before = np.array(data.xpos[body])
    data.qpos[model.jnt_qposadr[model.body_jntadr[body]]] += 0.1
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(np.array(data.xpos[body]) - before, [0.1, 0.0, 0.0], atol=1e-12)


def _arm_in_an_obstacle(runner: TaskRunner, rng: np.random.Generator) -> np.ndarray:
    """Arm joint vectors (within limits) at which, with every body awake, an arm geom touches an
    obstacle of ``runner``'s current scene: found by sampling on a copy without sleeping."""
    model = runner.physics.model.ptr
    reference = mujoco.MjData(model)
    flags = model.opt.enableflags
    model.opt.enableflags = flags & ~SLEEP
    task, robot = runner.task, runner.task.robot
    lower = np.maximum(robot.position_lower, -np.pi)  # continuous joints: one turn
    upper = np.minimum(robot.position_upper, np.pi)
    try:
        reference.qpos[:] = runner.physics.data.ptr.qpos
        for _ in range(20000):
            reference.qpos[task._arm_qpos] = rng.uniform(lower, upper)
            mujoco.mj_forward(model, reference)
            pairs = np.array(reference.contact.geom)
            hits = task._is_obstacle[pairs].any(axis=1) & task._is_toucher[pairs].any(axis=1)
            if hits.any():
                return np.array(reference.qpos[task._arm_qpos])
    finally:
        model.opt.enableflags = flags
    raise AssertionError("no arm posture in an obstacle found")


@pytest.mark.parametrize("seed", [3, 11])
def test_a_touch_of_a_sleeping_obstacle_is_seen(seed):
    """The arm placed into a sleeping obstacle: the contact is there and the task reports the
    touch, as it does with every body awake (a sleeping obstacle does not move, so the touch can
    come only from the contact), and the obstacle is woken."""
    rng = np.random.default_rng(seed)
    runner = _runner(True, seed=seed)
    model, data, task = runner.physics.model.ptr, runner.physics.data.ptr, runner.task
    _, _, obstacles = _trees(runner)
    assert all(data.tree_awake[t] == 0 for t in obstacles)
    state = np.array(data.qpos)
    q = _arm_in_an_obstacle(runner, rng)
    assert _sleeping(runner) and all(data.tree_awake[t] == 0 for t in obstacles)
    data.qpos[:] = state
    data.qpos[task._arm_qpos] = q
    mujoco.mj_forward(model, data)
    assert task._measure(runner.physics, phase_time=0.05).touched
    touched = {int(model.body_treeid[model.geom_bodyid[g]]) for g in np.array(data.contact.geom).ravel()
               if task._is_obstacle[g]}
    assert touched and all(data.tree_awake[t] == 1 for t in touched)


def _cube_against_an_obstacle(sleep: bool, gap: float) -> list[bool]:
    """The task's touch flag over 40 control steps (zero commands) with the cube placed on the
    table ``gap`` m from obstacle 0's -x face (negative: overlapping; positive and the cube
    slides into it: given a push toward it)."""
    runner = _runner(sleep)
    model, data, task = runner.physics.model.ptr, runner.physics.data.ptr, runner.task
    config = task.config
    obstacle = np.array(data.xpos[task._obstacle_bodies[0]])
    half = config.cube.size / 2
    adr = model.jnt_qposadr[model.body_jntadr[task._cube_body]]
    dof = model.jnt_dofadr[model.body_jntadr[task._cube_body]]
    data.qpos[adr:adr + 7] = [obstacle[0] - task._obstacle_half_sizes[0][0] - half - gap, obstacle[1],
                              config.table.height + half, 1, 0, 0, 0]
    data.qvel[dof:dof + 6] = [0.3 if gap > 0 else 0.0, 0, 0, 0, 0, 0]
    mujoco.mj_forward(model, data)
    return [runner.step_only(np.zeros(6))[0].touched for _ in range(40)]


@pytest.mark.parametrize("gap", [-1e-4, 0.002])
def test_a_cube_resting_against_an_obstacle_stays_a_touch(gap):
    """MuJoCo makes no contact between two sleeping bodies: were the cube allowed to sleep, a
    cube come to rest against a sleeping obstacle would stop counting as a touch. The flags must
    be those of the awake physics, step for step."""
    awake = _cube_against_an_obstacle(False, gap)
    assert sum(awake) >= 30  # the reference: the resting contact is a touch
    assert _cube_against_an_obstacle(True, gap) == awake


def test_the_scripted_controller_still_pushes_the_cube_off():
    """The teacher on random layouts with sleeping: every episode a success without touching, as
    without it (README: 20/20 clean on the same seeds)."""
    config = load_config(["task.layout.mode=random", "task.episode.sleep=true", "task.realism=ideal"])
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


def test_an_old_run_folder_takes_an_override_of_the_new_key(tmp_path):
    """Keys added after a run was written are filled before overrides apply, so that evaluating
    an old run with ``task.episode.sleep=...`` works (it was an 'unknown config key' before)."""
    from ahrm_stack.config import apply_overrides, fill_missing
    from ahrm_stack.evaluation import evaluate

    run = ROOT / "tests/data/legacy_run_configs/scratch-study/round6/runs/mirror-nj-fhrm-seed0"  # as written
    raw = yaml.safe_load((run / "config.yaml").read_text())
    filled = fill_missing(raw)
    assert "sleep" not in raw["task"]["episode"]  # the file's own data is left as it was
    apply_overrides(filled, ["task.episode.sleep=true"])
    assert config_from_dict(filled).task.episode.sleep is True
    result = evaluate(run, episodes=1, scripted=True, out=tmp_path / "eval", quiet=True,
                      overrides=["task.episode.sleep=true", "task.episode.duration=6"])
    assert result["episodes"] == 1 and result["successes"] == 1
