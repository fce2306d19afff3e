"""ahrm_stack/env/episode_loop.py: the one episode generator against the loop it replaced, written
out by hand on a second runner (the same seeds give the same states, requests and outcome)."""

import numpy as np

from ahrm_stack.config import load_config
from ahrm_stack.env.episode_loop import episode, scripted_episode
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask


def _runner_and_pusher():
    config = load_config([])
    task = PushOffTask(config.task)
    return TaskRunner(task, seed=0, safety=config.safety), ScriptedPusher(task, config.scripted)


def test_a_scripted_episode_is_the_hand_written_loop():
    runner, pusher = _runner_and_pusher()
    steps = list(scripted_episode(runner, pusher, seed=7))
    by_hand, hand_pusher = _runner_and_pusher()
    by_hand.seed(7)
    start = by_hand.reset()
    hand_pusher.reset(by_hand.physics)
    assert steps[0].sent is None and not steps[0].done
    assert steps[0].info.phase == start.info.phase
    for step in steps[1:]:
        request = hand_pusher(by_hand.physics)
        info, terminated, truncated = by_hand.step_only(request)
        np.testing.assert_array_equal(step.sent, request)
        assert (step.terminated, step.truncated, step.info.elapsed) == (terminated, truncated, info.elapsed)
    assert steps[-1].done and not any(s.done for s in steps[:-1])
    np.testing.assert_array_equal(runner.physics.data.qpos, by_hand.physics.data.qpos)


def test_the_consumer_sees_each_state_before_the_next_step_and_may_stop():
    runner, _ = _runner_and_pusher()
    calls = []

    def act():
        calls.append(runner.physics.data.time)
        request = np.zeros(runner.task.robot.num_joints)  # rad/s: held still
        return (request, *runner.step_only(request))

    steps = episode(runner, 3, act)
    first = next(steps)
    assert first.sent is None and calls == []  # reset only: no step taken before it is asked for
    next(steps)
    next(steps)
    steps.close()  # a consumer that stops early (a replay looking for the first touch)
    assert len(calls) == 2
