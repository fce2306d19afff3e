"""The interim and final evaluations' lean episode loop (``rollouts._lean_episode``) against
TorchRL's ``env.rollout`` on the same environment, policy and seeds: equal episode summaries."""

from __future__ import annotations

import dataclasses

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ahrm_stack.config import load_config
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.ppo import lean_actor, make_modules
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, run_episodes


def _rollout_summaries(env: PushOffEnv, policy, episodes: int) -> list:
    out = []
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for i in range(episodes):
            env.set_seed(VALIDATION_SEED_OFFSET + i)
            env.completed.clear()
            env.rollout(max_steps=env.task.config.max_steps, policy=policy, break_when_any_done=True)
            out += env.completed
    return out


def _comparable(summary) -> str:
    row = dataclasses.asdict(summary)
    row.pop("end_order", None)  # a process-wide counter of ended episodes
    return repr(row)  # NaN (no success time) compares equal as text


def test_the_lean_evaluation_loop_gives_the_rollouts_summaries():
    config = load_config(["task.episode.duration=3", "task.realism=jaco2",
                          "task.observation.joint_velocity=position_difference"])
    env = PushOffEnv(config.task, config.safety, seed=VALIDATION_SEED_OFFSET)
    torch.manual_seed(3)
    obs_dim = env.observation_spec["observation"].shape[0]
    modules = make_modules(config.ppo, obs_dim, env.action_spec.shape[0])
    modules.actor.eval()
    policy = lean_actor(modules.actor)
    assert policy is not None
    twin = PushOffEnv(config.task, config.safety, seed=VALIDATION_SEED_OFFSET)  # the same history (f3's
    # budgets carry over from episode to episode)
    lean = run_episodes(env, modules.actor, 3)
    reference = _rollout_summaries(twin, policy, 3)
    assert [_comparable(s) for s in lean] == [_comparable(s) for s in reference]
    assert all(s.steps > 1 for s in lean)
