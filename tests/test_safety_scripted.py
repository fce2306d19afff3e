"""The scripted controller through the safety filter wired in the runner: a full 1200-step episode
with no joint-limit, velocity or table violation in the simulator's own trajectory."""

import dataclasses

import numpy as np
import pytest

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask


@pytest.mark.parametrize("obstacle_rows", [False, True])
def test_scripted_episode_through_the_filter_has_no_violation(config, obstacle_rows):
    safety = dataclasses.replace(config.safety, obstacle_rows=obstacle_rows)
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=2, safety=safety)
    runner.reset()
    pusher = ScriptedPusher(task, config.scripted)
    pusher.reset(runner.physics)
    physics = runner.physics
    joints = physics.bind(task.arm.joints)
    sites = [physics.bind(task.pusher.tip_site), physics.bind(task.arm.wrist_site)]
    robot = task.robot
    half = np.asarray(config.task.table.half_extent)
    success_step = None
    worst_limit = worst_speed = np.inf
    lowest = np.inf
    for step in range(config.task.max_steps):  # the whole 60 s, also after the cube has fallen
        info, terminated, _ = runner.step_only(pusher(physics))
        if terminated and success_step is None:
            success_step = step
        q, dq = np.array(joints.qpos), np.array(joints.qvel)
        limited = robot.limited
        worst_limit = min(worst_limit, np.min(q[limited] - robot.position_lower[limited]),
                          np.min(robot.position_upper[limited] - q[limited]))
        worst_speed = min(worst_speed, np.min(robot.velocity_limit - np.abs(dq)))
        for site in sites:
            if np.all(np.abs(site.xpos[:2]) <= half):
                lowest = min(lowest, site.xpos[2] - config.task.table.height)
    stats = runner.safety_stats
    print(f"\nscripted, obstacle rows {obstacle_rows}: success at step {success_step}, "
          f"{stats.interventions}/{stats.steps} interventions, {stats.fallbacks} fallbacks; "
          f"joint-limit clearance {worst_limit:.3f} rad, speed headroom {worst_speed:.3f} rad/s, "
          f"lowest tip/wrist over the table {lowest * 1000:.1f} mm")
    assert success_step is not None
    assert stats.steps == config.task.max_steps and stats.fallbacks == 0
    assert worst_limit >= 0.0  # joint limits
    assert worst_speed >= 0.0  # velocity limits, in the simulated trajectory
    assert lowest >= 0.0  # never below the table top
