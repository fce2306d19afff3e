"""The deploy loop's fast paths give exactly what the slow ones gave: the world model's
preallocated observation is the task's ``flat_observation`` bit for bit (every observation
switch), its lane clearance is :func:`~ahrm_stack.env.layout.lane_clearance` bit for bit
(hypothesis), the NumPy policy is ``LeanActor.act`` to float32 rounding and keeps NaN, the policy
controller's request is ``ControlStep.request_keeping_faults`` bit for bit. The sim backend steps
its physics outside the loop's latency window with the same trajectory as before (a command
applied at its stamp), and the loop collects garbage between ticks and restores the collector."""

from __future__ import annotations

import dataclasses
import functools
import gc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from ahrm_stack.config import load_config
from ahrm_stack.deploy import (DeployFault, DeployLoop, PolicyController, ScriptedController,
                               WorldModel, load_deploy_settings)
from ahrm_stack.deploy.policy import NumpyPolicy
from ahrm_stack.env.layout import lane_clearance
from ahrm_stack.learning.ppo import GaussianHead, LeanActor, RunningNorm, lean_actor, make_modules
from ahrm_stack.hardware.protocol import FastClock, WallClock, check_joint_speeds
from ahrm_stack.sim_arm import SimArm


# --------------------------------------------------------------------------- the policy
def _lean(overrides=(), obs_dim=40, act_dim=3, statistics=True) -> LeanActor:
    torch.manual_seed(0)
    modules = make_modules(load_config(list(overrides)).ppo, obs_dim, act_dim)
    for p in modules.actor.parameters():  # non-trivial weights, a large mean to reach tanh's tails
        p.data.normal_(0.0, 0.5)
    if statistics:
        modules.normalizer.update(torch.randn(500, obs_dim) * 3.0 + 1.0)
    return lean_actor(modules.actor)


@pytest.mark.parametrize("overrides, statistics", [
    ((), True), (("ppo.activation=relu", "ppo.hidden_sizes=[64,32]"), True),
    (("ppo.activation=elu",), True), (("ppo.normalize_observations=false",), True), ((), False)])
def test_numpy_policy_gives_the_lean_actors_action(overrides, statistics):
    lean = _lean(overrides, statistics=statistics)
    policy = NumpyPolicy.from_actor(lean)
    assert policy is not None and policy.observation_dim == 40 and policy.action_dim == 3
    rng = np.random.default_rng(1)
    observations = rng.normal(size=(300, 40)) * 4.0  # float64, as the world model's
    observations[:10] *= 100.0  # beyond the normaliser's clip
    first = policy(observations[0])
    kept = first.copy()
    wants = lean.act(torch.as_tensor(observations, dtype=torch.float32)).numpy()  # one batch
    for observation, want in zip(observations, wants):
        got = policy(observation)
        assert got.dtype == np.float32 and got.shape == want.shape
        # float32 sums of 256 terms in another order (BLAS): these weights (N(0, 0.5)) make
        # pre-activations of ~10, so rounding reaches 1e-5; a trained policy's is ~1e-6 (below)
        np.testing.assert_allclose(got, want, atol=1e-4, rtol=0)
        assert np.abs(got).max() < 1.0
    np.testing.assert_array_equal(first, kept)  # each call returns a new array
    broken = observations[0].copy()
    broken[7] = np.nan  # a NaN observation is a NaN action (the loop stops on it), never a number
    assert np.isnan(policy(broken)).all()
    assert np.isnan(lean.act(torch.as_tensor(broken, dtype=torch.float32)).numpy()).all()


TRAINED = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0"


def test_numpy_policy_gives_the_trained_policys_action():
    from ahrm_stack.deploy import load_controller_config

    _, actor = load_controller_config(TRAINED)
    lean, policy = lean_actor(actor), NumpyPolicy.from_actor(actor)
    assert policy is not None
    rng = np.random.default_rng(6)
    # observations around the normaliser's statistics, some far out
    observations = (lean.normalizer.mean.numpy() + rng.normal(size=(300, policy.observation_dim))
                    * np.sqrt(lean.normalizer.var.numpy()) * rng.choice([0.5, 1.0, 3.0], (300, 1)))
    wants = lean.act(torch.as_tensor(observations, dtype=torch.float32)).numpy()
    worst = max(float(np.abs(policy(o) - w).max()) for o, w in zip(observations, wants))
    assert worst <= 1e-5, worst


def test_numpy_policy_refuses_a_structure_it_does_not_know():
    assert NumpyPolicy.from_actor(lambda td: td) is None
    odd = LeanActor(RunningNorm(4, 10.0), nn.Sequential(
        nn.Sequential(nn.Linear(4, 8), nn.Dropout(0.1), nn.Linear(8, 2)), GaussianHead(2, 0.5, True)))
    assert NumpyPolicy.from_actor(odd) is None
    no_bias = LeanActor(RunningNorm(4, 10.0), nn.Sequential(
        nn.Sequential(nn.Linear(4, 2, bias=False)), GaussianHead(2, 0.5, True)))
    assert NumpyPolicy.from_actor(no_bias) is None


@pytest.mark.parametrize("mode", ["cartesian", "joint"])
def test_policy_request_is_control_steps_bit_for_bit(mode):
    config = load_config([f"task.action.mode={mode}"])
    robot = SimpleNamespace(velocity_limit=np.linspace(0.5, 1.0, 6), commanded_joints=(0, 1, 2, 3, 4),
                            num_joints=6)
    world = SimpleNamespace(robot=robot, observation=lambda copy=True: None)
    size = 3 if mode == "cartesian" else 5
    actor = LeanActor(RunningNorm(4, 10.0), nn.Sequential(nn.Sequential(nn.Linear(4, size)),
                                                          GaussianHead(size, 0.5, True)))
    controller = PolicyController(world, actor, config)
    assert controller.control.action_size == size
    rng = np.random.default_rng(2)
    for k in range(200):
        action = (rng.normal(size=size) * 1.5).astype(np.float32)  # some beyond [-1, 1]
        if k % 7 == 0:
            action[rng.integers(size)] = rng.choice([np.nan, np.inf, -np.inf])
        got = controller._request(action)
        want = controller.control.request_keeping_faults(action)
        assert got.dtype == want.dtype == np.float64
        np.testing.assert_array_equal(got, want)  # NaN where want has NaN
        assert np.isnan(got).any() == (not np.isfinite(action).all())


# --------------------------------------------------------------------------- the observation
@functools.lru_cache(maxsize=None)
def _world(*overrides: str) -> WorldModel:
    return WorldModel(load_config(list(overrides)).task, seed=5)


_COORD = st.one_of(st.floats(-0.7, 0.7), st.sampled_from(np.round(np.arange(-0.6, 0.61, 0.01), 2).tolist()))


@settings(max_examples=300, deadline=None)
@given(cube=st.tuples(_COORD, _COORD), obstacles=st.lists(st.tuples(_COORD, _COORD), max_size=6))
def test_lane_clearance_is_the_layout_functions_bit_for_bit(cube, obstacles):
    """Grid coordinates make exact ties (an obstacle touching the strip, equal gaps) likely."""
    world = _world()
    builder, cfg = world._builder, world.task.config
    cube_xy, obstacle_xy = np.array(cube), np.array(obstacles, dtype=float).reshape(-1, 2)
    want = lane_clearance(cube_xy, obstacle_xy, cfg.cube.size / 2,
                          np.asarray(cfg.obstacles.size[:2], dtype=float) / 2, cfg.table, cfg.layout,
                          cfg.observation.lane_clip)
    got = builder.lane_clearance(cube_xy, obstacle_xy)
    assert np.array_equal(np.array(got), want), (got, want)


@pytest.mark.parametrize("overrides", [
    (), ("task.observation.relative=false",),
    ("task.observation.lanes=false", "task.observation.lane_choice=false"),
    ("task.observation.relative=false", "task.observation.lanes=false",
     "task.observation.lane_choice=false")])
def test_world_observation_is_the_tasks_bit_for_bit(overrides):
    world = _world(*overrides)
    assert world._builder is not None  # the preallocated path, not the fallback
    config = load_config(list(overrides))
    arm = SimArm(config.task, seed=2, clock=FastClock())
    arm.connect()
    rng = np.random.default_rng(3)
    limit = arm.velocity_limit
    tip_planned = False
    for step in range(40):
        command = rng.uniform(-0.5, 0.5, len(limit)) * limit
        arm.send_joint_speeds(command)
        arm.clock.sleep(0.05)
        poses = arm.perception()
        if step % 2:  # objects anywhere on the table: blocked and free lanes, every relative sign
            poses = dataclasses.replace(
                poses, cube_position=poses.cube_position + [*rng.uniform(-0.2, 0.2, 2), 0.0],
                obstacle_positions=poses.obstacle_positions
                + np.c_[rng.uniform(-0.2, 0.2, (len(poses.obstacle_positions), 2)),
                        np.zeros(len(poses.obstacle_positions))])
        world.update(arm.refresh_feedback(), poses, 0.05 * step)
        world.record_command(command)  # the previous action
        got = world.observation()
        want = world.task.flat_observation(world.physics)
        assert got.shape == want.shape and np.array_equal(got, want), np.abs(got - want).max()
        tip_planned = True
    assert tip_planned
    view = world.observation(copy=False)
    assert world.observation(copy=False) is view and world.observation() is not view
    arm.disconnect()


# --------------------------------------------------------------------------- the sim backend
class _ManualClock(WallClock):
    """A clock the test moves: the loop's computation takes the time the test says."""

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)

    def sleep_until(self, deadline: float) -> None:
        self.t = max(self.t, deadline)


class _ImmediateSimArm(SimArm):
    """The sim as it was: a command steps the physics up to its time and applies at once."""

    def send_joint_speeds(self, speeds):
        command = check_joint_speeds(speeds, self._robot.velocity_limit)
        self._advance()
        self._set_command(command)
        return command.copy()


def test_sim_applies_a_command_at_its_stamp_with_the_same_trajectory(task_config):
    """The command is applied by the next call (the clock's sleep here), at the time it was
    sent: the physics is not stepped inside send_joint_speeds, and the trajectory is the one of
    applying it at once, bit for bit."""
    deferred, immediate = _ManualClock(), _ManualClock()
    arm = SimArm(task_config, seed=4, clock=deferred)
    reference = _ImmediateSimArm(task_config, seed=4, clock=immediate)
    arm.connect()
    reference.connect()
    rng = np.random.default_rng(5)
    limit = arm.velocity_limit
    period = 0.05
    for tick in range(1, 30):
        compute = rng.uniform(0.0005, 0.02)  # feedback -> command, s
        command = rng.uniform(-0.6, 0.6, len(limit)) * limit
        for a, clock in ((arm, deferred), (reference, immediate)):
            a.clock.sleep_until(tick * period)
            a.refresh_feedback()
            clock.t += compute
        stepped = arm.physics.data.time
        arm.send_joint_speeds(command)
        assert arm.physics.data.time == stepped  # no physics inside the latency window
        reference.send_joint_speeds(command)
        for a in (arm, reference):
            a.clock.sleep_until((tick + 1) * period - 1e-4)  # while the loop waits
        np.testing.assert_array_equal(arm.physics.data.qpos, reference.physics.data.qpos)
        np.testing.assert_array_equal(arm.physics.data.qvel, reference.physics.data.qvel)
    np.testing.assert_array_equal(arm.command, reference.command)
    assert arm.violations == reference.violations == 0


def test_sim_clock_steps_the_physics_while_the_caller_sleeps(task_config):
    clock = _ManualClock()
    arm = SimArm(task_config, seed=0, clock=clock)
    arm.connect()
    start = arm.physics.data.time
    arm.clock.sleep_until(0.1)
    assert arm.physics.data.time == pytest.approx(start + 0.1, abs=1e-9)
    arm.send_joint_speeds(arm.velocity_limit * 0.1)
    np.testing.assert_allclose(arm.command, arm.velocity_limit * 0.1)  # a read applies it
    arm.disconnect()
    time_then = arm.physics.data.time
    arm.clock.sleep_until(0.5)  # not connected: the sim does not move
    assert arm.physics.data.time == time_then
    np.testing.assert_array_equal(arm.command, 0.0)


# --------------------------------------------------------------------------- garbage collection
def _scripted_loop(task_config_overrides=()):
    config = load_config(list(task_config_overrides))
    settings_ = load_deploy_settings(realtime=False, telemetry="")
    arm = SimArm(config.task, seed=0, clock=FastClock())
    arm.connect()
    world = WorldModel(config.task)
    return arm, world, config, settings_


def test_run_collects_garbage_between_ticks_and_restores_the_collector():
    arm, world, config, settings_ = _scripted_loop()
    controller = ScriptedController(world, config)
    inside, between, enabled = [], [], []
    ticking = [False]

    def record(phase, info):
        if phase == "start":
            (inside if ticking[0] else between).append(info["generation"])

    loop = DeployLoop(arm, world, controller, config.safety, settings_)
    tick = loop.tick

    def flagged():
        ticking[0] = True
        enabled.append(gc.isenabled())
        try:
            return tick()
        finally:
            ticking[0] = False

    loop.tick = flagged
    thresholds = gc.get_threshold()
    gc.set_threshold(50, *thresholds[1:])  # a collection every few ticks
    gc.callbacks.append(record)
    try:
        summary = loop.run(1.0)
    finally:
        gc.callbacks.remove(record)
        gc.set_threshold(*thresholds)
    assert summary.ticks > 0 and not any(enabled)  # no automatic collection inside a tick
    assert not inside and between  # the collections came between ticks
    assert gc.isenabled() and gc.get_freeze_count() == 0  # restored
    np.testing.assert_array_equal(arm.command, 0.0)


class _FailingController:
    """The scripted controller until its sixth call (warm-up and a few ticks), then a crash."""

    cartesian = False
    stage = "scripted"

    def __init__(self, inner: ScriptedController) -> None:
        self.inner, self.calls = inner, 0

    def reset(self) -> None:
        self.inner.reset()

    def __call__(self) -> np.ndarray:
        self.calls += 1
        if self.calls > 5:
            raise RuntimeError("boom")
        return self.inner()


def test_a_fault_still_stops_the_arm_and_restores_the_collector():
    arm, world, config, settings_ = _scripted_loop()
    loop = DeployLoop(arm, world, _FailingController(ScriptedController(world, config)),
                      config.safety, settings_)
    with pytest.raises(DeployFault, match="boom"):
        loop.run(2.0)
    assert loop.stop_reason.startswith("controller fault: RuntimeError")
    assert gc.isenabled() and gc.get_freeze_count() == 0
    np.testing.assert_array_equal(arm.command, 0.0)
