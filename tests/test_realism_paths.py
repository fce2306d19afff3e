"""One imperfection model (issue 57, item 1; ahrm_stack/realism/): training's runner and the sim
backend's arm compose the same objects, so one command sequence through both gives the same
actuator output and the same measurements.

* The command path: the same joint-velocity commands, each sent at a control tick, through a
  :class:`TaskRunner` with ``task.realism`` (training) and through a :class:`SimArm` with
  ``deploy.sim.realism`` (the robustness evaluation's arm), from the same seeded episode: the
  physics state is bit for bit the same after every tick, under latency, lag and both.
* The measurement path: the perceived cube one perception latency old in both (training's
  observation, the sim arm's perception), and the joint sensing's noise the same draws.
* :meth:`ActuatorModel.run` (runs of one output) gives :meth:`ActuatorModel.step`'s outputs.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm
from ahrm_stack.realism import ActuatorModel, JointSensing, RealismConfig, realism_profiles

JACO2 = realism_profiles()["jaco2"]


def _commands(robot, ticks: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.3, 0.3, (ticks, robot.num_joints)) * robot.velocity_limit


@pytest.mark.parametrize("group", ["command latency", "actuator lag", "both"])
def test_one_command_sequence_moves_both_arms_alike(task_config, group):
    realism = (dataclasses.replace(JACO2.only("command latency"), actuator_lag=JACO2.actuator_lag)
               if group == "both" else JACO2.only(group))
    assert realism.actuates
    config = dataclasses.replace(task_config, realism=realism)
    period = config.episode.control_period
    runner = TaskRunner(PushOffTask(config), seed=7, safety=None)
    runner.reset()
    arm = SimArm(task_config, seed=7, clock=FastClock(), realism=realism)
    arm.connect()
    np.testing.assert_array_equal(arm.physics.data.qpos, runner.physics.data.qpos)  # one episode
    start = arm.clock.now()
    for k, command in enumerate(_commands(runner.task.robot, 12)):
        arm.clock.sleep_until(start + k * period)
        arm.send_joint_speeds(command)
        arm.clock.sleep_until(start + (k + 1) * period)
        runner.step_only(command)
        np.testing.assert_array_equal(arm.physics.data.qpos, runner.physics.data.qpos, err_msg=f"tick {k}")
        np.testing.assert_array_equal(arm.physics.data.ctrl, runner.physics.data.ctrl, err_msg=f"tick {k}")
    arm.disconnect()


def test_the_perceived_cube_is_one_latency_old_in_both(task_config):
    realism = dataclasses.replace(RealismConfig.ideal(), perception_latency=JACO2.perception_latency)
    config = dataclasses.replace(task_config, realism=realism)
    period = config.episode.control_period
    assert realism.perception_latency == pytest.approx(period)  # the comparison's premise
    runner = TaskRunner(PushOffTask(config), seed=11, safety=None)
    runner.reset()
    layout = runner._sensing.layout
    arm = SimArm(task_config, seed=11, clock=FastClock(), realism=realism)
    arm.connect()
    start = arm.clock.now()
    truth = []
    for k, command in enumerate(_commands(runner.task.robot, 30, seed=5)):
        observed = runner.flat_observation()[layout["cube"]][:3]
        arm.clock.sleep_until(start + k * period)
        perceived = arm.perception().cube_position
        truth.append(arm.physics.data.qpos[arm.task.addresses.cube_qpos[:3]].copy())
        np.testing.assert_allclose(perceived, observed, atol=1e-12, err_msg=f"tick {k}")
        np.testing.assert_allclose(perceived, truth[max(0, k - 1)], atol=1e-12)  # one period old
        arm.send_joint_speeds(command)
        runner.step_only(command)
    arm.disconnect()


def test_joint_sensing_draws_alike_and_run_matches_step():
    sensing = JointSensing(JACO2)
    q = np.linspace(-1.0, 1.0, 6)
    a = sensing.angles(q, np.random.default_rng(1))
    b = sensing.angles(q, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert 0 < np.abs(a - q).max() < 5 * np.radians(JACO2.angle_noise_deg)
    for realism in (RealismConfig.ideal(), JACO2.only("command latency"), JACO2):
        one, runs = ActuatorModel(realism, 0.002, 3), ActuatorModel(realism, 0.002, 3)
        per_step, per_run = [], []
        for k in range(6):
            command = np.full(3, float(k + 1))
            one.command(command)
            runs.command(command)
            per_step += [one.step().copy() for _ in range(25)]
            for count, output in runs.run(25):
                per_run += [output.copy()] * count
        np.testing.assert_array_equal(np.array(per_step), np.array(per_run))
