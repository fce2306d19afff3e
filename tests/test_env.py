"""The simulated task end to end: determinism, success, contacts, observation layout, TorchRL specs."""

import numpy as np
import pytest
import torch
from dm_control import composer
from torchrl.envs.utils import check_env_specs

from ahrm_stack.config import load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.env.torchrl_env import PushOffEnv, action_to_command


@pytest.fixture()
def runner(task_config):
    runner = TaskRunner(PushOffTask(task_config), seed=3)
    runner.reset()
    return runner


def _free_joint_qpos(runner, entity):
    model, physics = runner.physics.model, runner.physics
    body = int(physics.bind(entity.geom).bodyid)
    return model.jnt_qposadr[model.body_jntadr[body]]


def test_same_seed_same_rollout(task_config):
    rng = np.random.default_rng(0)
    commands = rng.uniform(-0.5, 0.5, (60, 6))
    trajectories = []
    for _ in range(2):
        runner = TaskRunner(PushOffTask(task_config), seed=11)
        obs = [runner.reset().observation["pusher_tip"]]
        for command in commands:
            runner.step_only(command)
            obs.append(runner.flat_observation())
        trajectories.append(np.concatenate([np.ravel(o) for o in obs]))
    np.testing.assert_array_equal(trajectories[0], trajectories[1])


def test_reset_state_is_at_rest_and_untouched(runner):
    for _ in range(3):
        runner.reset()
        info, _, _ = runner.step_only(np.zeros(6))
        assert not info.touched
        assert info.f[0] == 1.0


def test_cube_off_the_table_ends_the_episode_as_success(runner):
    adr = _free_joint_qpos(runner, runner.task.cube)
    runner.physics.data.qpos[adr:adr + 3] = [0.55, 0.0, 0.3]  # beyond the +x edge (0.45), below the top
    runner.physics.forward()
    info, terminated, truncated = runner.step_only(np.zeros(6))
    assert info.success and terminated and not truncated
    assert runner.task.get_discount(runner.physics) == 0.0


def test_contact_with_an_obstacle_makes_f1_minus_one():
    # speed test off, so only the contact itself can trigger f1
    cfg = load_config(["task.rewards.obstacle_speed_threshold=1000.0"])
    runner = TaskRunner(PushOffTask(cfg.task), seed=0)
    runner.reset()
    task = runner.task
    obstacle = task.obstacles[0]
    adr = _free_joint_qpos(runner, obstacle)
    cube_xy = runner.physics.data.xpos[int(runner.physics.bind(task.cube.geom).bodyid)][:2]
    # place the obstacle flush against the cube's +x face, overlapping by 1 mm
    gap = task.config.cube.size / 2 + task.config.obstacles.size[0] / 2 - 0.001
    runner.physics.data.qpos[adr:adr + 2] = [cube_xy[0] + gap, cube_xy[1]]
    runner.physics.forward()
    info, _, _ = runner.step_only(np.zeros(6))
    assert info.touched and info.f[0] == -1.0 and info.g[0] == -1.0


def test_time_limit_is_a_truncation(task_config):
    cfg = load_config(["task.episode.duration=0.5"])
    runner = TaskRunner(PushOffTask(cfg.task), seed=0)
    runner.reset()
    flags = [runner.step_only(np.zeros(6))[1:] for _ in range(10)]
    assert flags[-1] == (False, True) and all(f == (False, False) for f in flags[:-1])


def test_moving_toward_the_cube_earns_manipulate(runner):
    """Driving the tip straight at the cube raises P = d - l: f2 = +1 on most steps."""
    task = runner.task
    kin = task.kinematics
    tip = kin.element_frame_id(task.pusher.tip_site)
    f2 = []
    for _ in range(20):
        q = runner.physics.data.qpos[runner.physics.bind(task.arm.joints).qposadr]
        kin.update(q)
        jac = kin.frame_jacobian(tip)[:3]
        direction = task.step_info.target - task.step_info.tip
        velocity = 0.1 * direction / np.linalg.norm(direction)
        command = np.linalg.lstsq(jac, velocity, rcond=None)[0]
        command = np.clip(command, -task.robot.velocity_limit, task.robot.velocity_limit)
        info, _, _ = runner.step_only(command)
        f2.append(info.f[1])
    assert np.mean(np.array(f2) == 1.0) > 0.8


def test_flat_observation_equals_the_declared_observables(runner):
    runner.step_only(np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.0]))
    observation = runner.observe()
    expected = np.concatenate([np.ravel(observation[k]) for k in runner.observation_order])
    np.testing.assert_array_equal(runner.flat_observation(), expected)
    n_obstacles = len(runner.task.obstacles)
    assert expected.shape == (12 + 6 + 3 + 6 * (1 + n_obstacles) + 5 + 3 + 1  # spec §1
                              + 3 + 2 * n_obstacles + 2 + 2,)  # relative to the cube, lane
    # clearance, lane choice (one-hot over the two lanes)


def test_composer_environment_runs_the_same_task(task_config):
    task = PushOffTask(task_config)
    env = composer.Environment(task, time_limit=1.0, random_state=0, strip_singleton_obs_buffer_dim=True)
    timestep = env.reset()
    assert timestep.observation["phase"].shape == (3,)
    timestep = env.step(np.zeros(6))
    assert timestep.reward.shape == (3,)


def test_action_to_command_scales_clips_and_drops_nan():
    limits = np.array([1.0, 2.0, 3.0])
    command = action_to_command(np.array([0.5, np.nan]), limits, (0, 2))
    np.testing.assert_array_equal(command, [0.5, 0.0, 0.0])
    np.testing.assert_array_equal(action_to_command(np.array([-7.0, 1.0]), limits, (0, 2)), [-1.0, 0.0, 3.0])


def test_torchrl_env_specs_and_seeded_rollouts(config, task_config):
    env = PushOffEnv(task_config, config.safety, seed=5)
    check_env_specs(env)
    rollouts = []
    for _ in range(2):
        env.set_seed(5)
        torch.manual_seed(0)
        rollouts.append(env.rollout(40))
    assert torch.equal(rollouts[0]["next", "observation"], rollouts[1]["next", "observation"])
    assert rollouts[0]["next", "observation"].dtype == torch.float32
    assert set(rollouts[0]["next"].keys()) >= {"f", "g", "phase", "x", "success", "touched", "reward"}


def test_cartesian_action_mode_moves_the_tip_through_the_filter(config):
    """action.mode: cartesian — a tip velocity goes through the filter's differential IK."""
    cfg = load_config(["task.action.mode=cartesian"])
    env = PushOffEnv(cfg.task, cfg.safety, seed=0)
    assert env.action_spec.shape == (3,)
    td = env.reset()
    start = env.task.step_info.tip.copy()
    for _ in range(10):
        td["action"] = torch.tensor([0.0, 0.0, -1.0])  # straight down
        td = env.step(td)["next"]
    moved = env.task.step_info.tip - start
    assert moved[2] < -0.02 and abs(moved[0]) < 0.5 * abs(moved[2]) and abs(moved[1]) < 0.5 * abs(moved[2])
    assert env.runner.last_filter_result is not None


def test_joint_limit_violations_are_counted_from_the_simulator(task_config):
    runner = TaskRunner(PushOffTask(task_config), seed=0)  # raw: no filter, to force a violation
    runner.reset()
    adr = runner.physics.bind(runner.task.arm.joints).qposadr
    runner.physics.data.qpos[adr[1]] = runner.task.robot.position_lower[1] - 0.2  # joint 2 below its range
    runner.physics.forward()
    runner.step_only(np.zeros(6))
    assert runner.limit_violations == 1
    runner.reset()
    assert runner.limit_violations == 0
