"""A real arm's imperfections (ahrm_stack/env/realism.py): the sim backend's and training's, each
checked against its model (a closed form or the noise's own statistics), and the normaliser's floor
(issue 40: a feature that never varied in training turned 0.05 deg/s of noise into a saturated
input)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.realism import (GROUPS, ActuatorModel, RealismConfig, nominal, realism_profiles,
                                resolve_realism)
from ahrm_stack.learning.ppo import RunningNorm
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm


def _realism(**values) -> RealismConfig:
    return dataclasses.replace(RealismConfig.ideal(), **values)


# ------------------------------------------------------------------ the normaliser's floor
def test_a_feature_constant_in_training_does_not_saturate_on_small_noise():
    """The cause of issue 40's collapse: joint 6's velocity was exactly 0 in every demonstration,
    so its std was 1e-4 and 0.05 deg/s of noise became ~9 standard deviations (near the clip of
    10). With the default floor the same noise is a small input."""
    config = load_config()
    data = torch.randn(500, 3, dtype=torch.float64) * torch.tensor([0.3, 0.1, 0.0])  # feature 2 constant
    noise = math.radians(0.05)  # rad/s
    probe = torch.tensor([[0.0, 0.0, noise]], dtype=torch.float32)
    old = RunningNorm(3, config.ppo.normalizer_clip, True, min_std=0.0)  # before the fix
    old.update(data)
    assert abs(float(old(probe)[0, 2])) > 8.0
    fixed = RunningNorm(3, config.ppo.normalizer_clip, True, min_std=config.ppo.normalizer_min_std)
    fixed.update(data)
    assert abs(float(fixed(probe)[0, 2])) <= noise / config.ppo.normalizer_min_std + 1e-6 < 0.05
    # a feature that does vary is scaled as before
    assert torch.allclose(fixed(probe)[:, :2], old(probe)[:, :2])


def test_old_runs_keep_their_normaliser():
    from ahrm_stack.config import config_from_dict

    data = load_config().to_dict()
    del data["ppo"]["normalizer_min_std"]
    assert config_from_dict(data).ppo.normalizer_min_std == 0.0


# ------------------------------------------------------------------ configuration
def test_profiles_load_and_ideal_is_ideal():
    profiles = realism_profiles()
    assert profiles["ideal"].is_ideal and profiles["ideal"] == RealismConfig.ideal()
    jaco2 = profiles["jaco2"]
    assert jaco2.senses and jaco2.actuates and jaco2.varies_dynamics
    for group, names in GROUPS.items():
        only = jaco2.only(group)
        assert {n for n in names} >= {f.name for f in dataclasses.fields(only)
                                       if getattr(only, f.name) != getattr(RealismConfig.ideal(), f.name)}


def test_bad_realism_is_one_line():
    with pytest.raises(ConfigError, match="task.realism: no realism profile 'nope'"):
        load_config(["task.realism=nope"])
    with pytest.raises(ConfigError, match=r"task.realism.cube_mass_scale must be \[low, high\]"):
        load_config(["task.realism.cube_mass_scale=[2.0,1.0]"])
    with pytest.raises(ConfigError, match="task.realism.velocity_noise_deg_s"):
        load_config(["task.realism.velocity_noise_deg_s=-1"])
    assert resolve_realism({"a": 1}, "k") == {"a": 1}


def test_old_runs_read_as_ideal():
    from ahrm_stack.config import config_from_dict

    data = load_config().to_dict()
    del data["task"]["realism"]
    assert config_from_dict(data).task.realism.is_ideal


# ------------------------------------------------------------------ the actuators
def test_actuator_model_latency_and_lag_closed_form():
    dt, tau, latency = 0.002, 0.05, 0.02
    model = ActuatorModel(_realism(command_latency=latency, actuator_lag=tau), dt, 1)
    model.command(np.array([1.0]))
    outputs = np.array([model.step()[0] for _ in range(200)])
    delay = int(round(latency / dt))
    assert np.all(outputs[:delay] == 0.0)
    k = np.arange(1, 200 - delay + 1)
    np.testing.assert_allclose(outputs[delay:], 1.0 - np.exp(-dt / tau) ** 0 * np.exp(-k * dt / tau), rtol=1e-12)


def _arm(realism: RealismConfig, seed: int = 0) -> SimArm:
    config = load_config(["task.realism=ideal"])
    arm = SimArm(config.task, seed=seed, clock=FastClock(), realism=realism)
    arm.connect()
    return arm


def test_sim_command_latency_holds_the_old_command():
    """A joint commanded at t moves only from t + command_latency (the servo then takes over)."""
    latency = 0.02
    arm = _arm(_realism(command_latency=latency))
    joint = 0
    speed = np.zeros(arm.task.robot.num_joints)
    speed[joint] = 0.3
    start = arm.physics.data.time
    arm.send_joint_speeds(speed)
    arm.clock.sleep_until(arm.clock.now() + latency - 0.004)
    early = arm.physics.data.qvel[arm.task.addresses.arm_dof][joint]
    assert arm.physics.data.time - start == pytest.approx(latency - 0.004, abs=0.0021)
    arm.clock.sleep_until(arm.clock.now() + 0.05)
    late = arm.physics.data.qvel[arm.task.addresses.arm_dof][joint]
    assert abs(early) < 0.01 and late > 0.1


def test_sim_feedback_noise_has_the_configured_statistics():
    """Feedback noise against its model: zero mean, the configured std (1,000 reads at rest)."""
    arm = _arm(_realism(angle_noise_deg=0.1, velocity_noise_deg_s=2.0))
    reads = [arm.refresh_feedback() for _ in range(1000)]
    q = np.array([r.position for r in reads])
    dq = np.array([r.velocity for r in reads])
    assert np.std(q, axis=0) == pytest.approx(np.full(q.shape[1], math.radians(0.1)), rel=0.12)
    assert np.std(dq, axis=0) == pytest.approx(np.full(q.shape[1], math.radians(2.0)), rel=0.12)
    assert abs(float(np.mean(dq))) < 4 * math.radians(2.0) / math.sqrt(dq.size)


def test_sim_quantisation():
    arm = _arm(_realism(angle_resolution_deg=0.5))
    q = arm.refresh_feedback().position
    steps = q / math.radians(0.5)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)


def test_sim_perception_latency_and_noise():
    """Perceived poses are ``perception_latency`` old; their noise has the configured std."""
    arm = _arm(_realism(perception_latency=0.05))
    speed = np.zeros(arm.task.robot.num_joints)
    speed[0] = 0.5
    arm.send_joint_speeds(speed)
    for _ in range(10):  # the arm sweeps; objects rest unless hit: compare to recorded truth
        arm.clock.sleep_until(arm.clock.now() + 0.05)
        seen = arm.perception()
    assert seen.timestamp == arm.clock.now()
    noisy = _arm(_realism(perception_noise=0.004))
    cubes = np.array([noisy.perception().cube_position for _ in range(1000)])
    assert np.std(cubes, axis=0) == pytest.approx(np.full(3, 0.004), rel=0.12)


def test_sim_perception_delay_is_the_state_that_long_ago():
    arm = _arm(_realism(perception_latency=0.1))
    arm.physics.data.qvel[arm.task.addresses.cube_dof] = [0.0, 0.0, 0.0]
    history = []
    for _ in range(8):
        arm.clock.sleep_until(arm.clock.now() + 0.05)
        history.append((arm.physics.data.time, arm.physics.data.qpos[arm.task.addresses.cube_qpos[:3]].copy()))
        seen = arm.perception()
    wanted = history[-1][0] - 0.1
    expected = [p for t, p in history if t <= wanted + 1e-9][-1]
    np.testing.assert_allclose(seen.cube_position, expected, atol=1e-12)


def test_sim_dynamics_are_drawn_in_range_and_never_compound():
    realism = _realism(cube_mass_scale=(2.0, 2.0), obstacle_friction_scale=(0.5, 1.5))
    arm = _arm(realism)
    cube = arm.task._cube_body
    nominal_mass = load_config().task.cube.mass
    for seed in range(3):
        arm.disconnect()
        arm.reset_scene(seed)
        arm.connect()
        assert arm.physics.model.body_mass[cube] == pytest.approx(2.0 * nominal_mass, rel=1e-9)
        factors = arm.task.dynamics_factors["obstacle_friction"]
        assert np.all((factors >= 0.5) & (factors <= 1.5))


def test_ideal_realism_draws_nothing():
    """The ideal set leaves training's episodes as they were: same layout stream, no noise."""
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask

    config = load_config()
    ideal = TaskRunner(PushOffTask(nominal(config.task)), seed=3, safety=None)
    ideal.reset()
    state = ideal.random_state.get_state()[1].copy()
    observation = ideal.flat_observation()
    np.testing.assert_array_equal(observation, ideal.task.flat_observation(ideal.physics))
    again = TaskRunner(PushOffTask(nominal(config.task)), seed=3, safety=None)
    again.reset()
    np.testing.assert_array_equal(again.random_state.get_state()[1], state)


def test_training_sensing_noise_and_consistent_relative_entries():
    from ahrm_stack.env.observation_layout import observation_layout
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask

    config = load_config(["task.realism=ideal", "task.realism.velocity_noise_deg_s=2.0",
                          "task.realism.perception_noise=0.004"])
    runner = TaskRunner(PushOffTask(config.task), seed=1, safety=None)
    runner.reset()
    robot = runner.task.robot
    layout = observation_layout(config.task, robot.num_joints, len(robot.commanded_joints))
    exact = runner.task.flat_observation(runner.physics)
    samples = np.array([runner.flat_observation() for _ in range(800)])
    velocity_error = samples[:, layout["joints_vel"]] - exact[layout["joints_vel"]]
    assert np.std(velocity_error) == pytest.approx(math.radians(2.0), rel=0.1)
    cube = samples[:, layout["cube"]][:, :3]
    assert np.std(cube - exact[layout["cube"]][:3]) == pytest.approx(0.004, rel=0.1)
    relative = samples[:, layout["relative_to_cube"]]
    tip = samples[:, layout["pusher_tip"]]
    np.testing.assert_allclose(relative[:, :3], tip - cube, atol=1e-12)


# ------------------------------------------------------------------ joint velocities from angles
def test_velocity_estimator_closed_form():
    """Constant velocity v through the +-pi wrap: the smoothed estimate is v (1 - s^k) after k
    updates (s the smoothing; 0 at the first update, where the arm is at rest)."""
    from ahrm_stack.env.realism import VelocityEstimator

    v, dt, s = np.array([0.4, -1.2]), 0.05, 0.5
    estimator = VelocityEstimator(s)
    q0 = np.array([np.pi - 0.05, -np.pi + 0.1])
    estimates = [estimator(np.remainder(q0 + v * dt * k + np.pi, 2 * np.pi) - np.pi, dt) for k in range(8)]
    for k, estimate in enumerate(estimates):
        np.testing.assert_allclose(estimate, v * (1 - s**k), atol=1e-9)
    estimator.reset()
    np.testing.assert_array_equal(estimator(q0, dt), np.zeros(2))


def test_training_and_deploy_estimate_the_same_velocities():
    """task.observation.joint_velocity: position_difference: the training observation's joint
    velocities and the deploy world model's are the same estimator over the same angles."""
    from ahrm_stack.deploy.world import WorldModel
    from ahrm_stack.env.observation_layout import observation_layout
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.hardware.protocol import ArmState, Fault, Feedback, ObjectPoses

    config = load_config(["task.realism=ideal", "task.observation.joint_velocity=position_difference"])
    runner = TaskRunner(PushOffTask(config.task), seed=2, safety=config.safety)
    runner.reset()
    world = WorldModel(config.task)
    robot = runner.task.robot
    at = observation_layout(config.task, robot.num_joints, len(robot.commanded_joints))
    addresses = runner.task.addresses
    period = config.task.episode.control_period
    for step in range(6):
        trained = runner.flat_observation()
        data = runner.physics.data
        q = data.qpos[addresses.arm_qpos].copy()
        feedback = Feedback(timestamp=0.0, frame_id=step, position=q, velocity=np.zeros_like(q),
                            torque=np.zeros_like(q), arm_state=ArmState.SERVOING_READY, faults=Fault.NONE)
        poses = ObjectPoses(timestamp=0.0, cube_position=data.qpos[addresses.cube_qpos[:3]].copy(),
                            cube_quaternion=data.qpos[addresses.cube_qpos[3:]].copy(),
                            cube_velocity=data.qvel[addresses.cube_dof].copy(),
                            obstacle_positions=data.qpos[addresses.obstacle_qpos[:, :3]].copy(),
                            obstacle_quaternions=data.qpos[addresses.obstacle_qpos[:, 3:]].copy(),
                            obstacle_velocities=data.qvel[addresses.obstacle_dof].copy())
        world.update(feedback, poses, step * period)
        deployed = world.observation()
        np.testing.assert_allclose(deployed[at["joints_vel"]], trained[at["joints_vel"]], atol=1e-9)
        if step:
            assert np.abs(trained[at["joints_vel"]]).max() > 1e-3  # the arm moves
        runner.step_action(np.array([0.5, -0.3, 0.0]))


def test_a_world_model_reused_for_a_new_run_plans_its_lane_again():
    """A deploy world model that runs a second episode (a loop's start: ``begin_run``) plans that
    episode's lane anew, as training's reset does (it kept the first episode's plan)."""
    from ahrm_stack.deploy.world import WorldModel
    from ahrm_stack.hardware.protocol import FastClock

    config = load_config(["task.realism=ideal"])
    world = WorldModel(config.task)
    lanes = []
    for seed in (4200003, 4200000):
        arm = SimArm(config.task, seed=seed, clock=FastClock())
        arm.connect()
        world.begin_run()
        world.update(arm.refresh_feedback(), arm.perception(), 0.0)
        lanes.append(world.task.lane_choice(world.physics).copy())
        world.update(arm.refresh_feedback(), arm.perception(), 0.05)
        fresh = WorldModel(config.task)
        fresh.update(arm.refresh_feedback(), arm.perception(), 0.0)
        np.testing.assert_array_equal(lanes[-1], fresh.task.lane_choice(fresh.physics))
    assert not np.array_equal(lanes[0], lanes[1])  # these two layouts have different lanes
