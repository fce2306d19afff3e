"""The oracle control's staged dense reward (``task.rewards.learning: staged``, issue 56)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.env.rewards import staged_push_reward
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.torchrl_env import PushOffEnv

HALF, TABLE = 0.025, 0.5
KW = dict(cube_half=HALF, table_half_x=TABLE, tanh_scale=5.0, push_offset=0.03, reached_distance=0.03)


def test_closed_forms():
    cube = np.array([0.1, 0.2, 0.8])
    pose = cube - np.array([HALF + 0.03, 0.0, 0.0])
    at_pose = staged_push_reward(pose, cube, 1.0, touched=False, success=False, **KW)
    assert at_pose == pytest.approx(0.5 * (1.0 + 1.0 - math.tanh(5.0 * (TABLE - 0.1))))
    # toward -x the pose is on the other side, and the way to the edge is 0.5 + 0.1
    mirrored = cube + np.array([HALF + 0.03, 0.0, 0.0])
    assert staged_push_reward(mirrored, cube, -1.0, touched=False, success=False, **KW) == pytest.approx(
        0.5 * (2.0 - math.tanh(5.0 * (TABLE + 0.1))))
    far = pose + np.array([0.0, 0.1, 0.0])  # 10 cm off: reach only
    assert staged_push_reward(far, cube, 1.0, touched=False, success=False, **KW) == pytest.approx(
        0.5 * (1.0 - math.tanh(0.5)))
    assert staged_push_reward(far, cube, 1.0, touched=False, success=True, **KW) == 1.0
    assert staged_push_reward(far, cube, 1.0, touched=True, success=True, **KW) == 0.0
    assert -1.0 <= staged_push_reward(far, cube, 1.0, touched=True, success=False, **KW) < 0.0


def test_the_environment_pays_it_and_an_expert_earns_more_than_standing_still():
    config = load_config(["profile=paper", "task.rewards.learning=staged"])
    returns = {}
    for who in ("scripted", "still"):
        env = PushOffEnv(config.task, config.safety, seed=7, time_limit=6.0)
        env.begin()
        pusher = ScriptedPusher(env.task, config.scripted)
        pusher.reset(env.runner.physics)
        total, steps = 0.0, 0
        while True:
            if who == "scripted":
                action = env.runner.control.action(pusher(env.runner.physics))
            else:
                action = np.zeros(env.action_spec.shape[-1])
            info, reward, terminated, truncated = env.advance(action)
            planned = 1.0 if env._planned == "+x" else -1.0
            assert reward == pytest.approx(staged_push_reward(
                info.tip, info.target, planned, config.task.cube.size / 2, config.task.table.half_extent[0],
                info.touched, info.success, 5.0, 0.03, 0.03))
            total += reward
            steps += 1
            if terminated or truncated:
                break
        returns[who] = total / steps
    assert returns["scripted"] > returns["still"] + 0.1
