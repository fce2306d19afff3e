"""The hierarchy's priority constraint against an expert (issue 56: why the start curriculum of the
planner-free runs never left level 0).

The scripted controller wins every near-cube training start (behind a free lane, 5 s) it is given.
Run through the training environment with the reward mechanism in the state the planner-free
runs reached (AHRM, every phase at level 3 with the order manipulate > avoid > time), the online
check (``mechanism.constraint_check: running``, the spec's choice) compares the running per-step
average of manipulate + avoid over an episode's first 20 phase-3 steps — mostly approach, where
manipulate is -1 until the cube moves — with the last ten episodes' whole-episode averages, and
ends most of those winning episodes at their 20th step. A curriculum that rises at 50 % training
success cannot rise then, whatever the policy. Checked at the episode's end (the paper's
Algorithm 1, ``episode``) or not at all (``none``), the expert's episodes run to their win.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ahrm_stack.config import load_config
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.mechanisms import ConstraintMonitor, RewardMechanism

EPISODES = 24  # after the constraint's window of 10 (tau needs 10 episodes of history)
OVERRIDES = ["profile=scratch-own-lane", "task.arm.near_cube.bearing=behind_free",
             "task.rewards.avoid_margin=0.02", "mechanism.method=ahrm"]


def expert_episodes(check: str | None, overrides: list[str] = OVERRIDES) -> list:
    """The scripted controller's episodes from near-cube starts through a training environment
    (``train.time_limit``) whose mechanism sits at level 3, order M > A > T, in every phase
    (``check``: ``mechanism.constraint_check``, None: the profile's)."""
    config = load_config([*overrides, *([] if check is None else [f"mechanism.constraint_check={check}"])])
    mechanism = RewardMechanism(config.mechanism)
    mechanism.orders = [(1, 0, 2)] * 3  # manipulate > avoid > time
    mechanism.levels = [3, 3, 3]
    env = PushOffEnv(config.task, config.safety, mechanism=mechanism, seed=4_000_000,
                     time_limit=config.train.time_limit)
    env.task.near_cube_share = 1.0
    pusher = ScriptedPusher(env.task, config.scripted)
    speed = config.task.action.cartesian_max_speed
    for _ in range(EPISODES):
        env.begin()
        pusher.reset(env.runner.physics)
        while True:
            action = np.clip(pusher.tip_velocity(env.runner.physics) / speed, -1.0, 1.0)
            _, _, terminated, truncated = env.advance(action)
            if terminated or truncated:
                break
    return env.completed[10:]


@pytest.mark.parametrize("check", ["episode", "none"])
def test_an_expert_keeps_its_wins(check):
    episodes = expert_episodes(check)
    assert not any(e.constraint_terminated for e in episodes)
    assert np.mean([e.success for e in episodes]) >= 0.9  # the curriculum's 0.5 is reachable


def test_the_planner_free_profile_lets_an_expert_raise_the_curriculum():
    """The fix, on the profile: under ``profile=planner-free`` the expert's near-cube episodes win
    often enough for the start curriculum (train.curriculum_threshold) to rise; under the lane
    study's ``profile=scratch-own-lane`` (the check online) they did not."""
    config = load_config(["profile=planner-free", "mechanism.method=ahrm"])
    episodes = expert_episodes(None, ["profile=planner-free", "mechanism.method=ahrm"])
    assert np.mean([e.success for e in episodes]) >= max(0.9, config.train.curriculum_threshold)
    before = expert_episodes(None, OVERRIDES)  # scratch-own-lane + behind_free, the check online
    assert np.mean([e.success for e in before]) < config.train.curriculum_threshold


def test_the_online_check_ends_most_of_an_experts_wins():
    """The finding, kept as a measurement: at least half of the expert's episodes are cut, and
    they would have won (issue 56: 11 of these 14 cut, 3 won; 69 % cut in a first measurement
    of 40 episodes with a longer history)."""
    episodes = expert_episodes("running")
    cut = [e for e in episodes if e.constraint_terminated]
    assert len(cut) >= len(episodes) / 2
    assert np.mean([e.success for e in episodes]) < 0.5
    # at the check's first steps: the 20th to 25th of phase 3 (constraint_min_steps 20)
    assert all(e.constraint_phase == 3 and 20 <= e.phase_steps[2] <= 25 for e in cut)


def test_episode_check_flags_below_threshold_at_the_end_only():
    tau = np.array([np.nan, np.nan, 1.0])
    monitor = ConstraintMonitor(tau, [[], [], [1, 0]], min_steps=2, margin=0.1, at_end=True)
    for _ in range(5):  # manipulate -1, avoid +1: per-step average 0 < 1 - 0.1
        assert not monitor.step(np.array([1.0, -1.0, 1.0]), 3)
    assert monitor.violated_at_end() and monitor.violated_phase == 3
    fine = ConstraintMonitor(tau, [[], [], [1, 0]], min_steps=2, margin=0.1, at_end=True)
    for _ in range(5):
        fine.step(np.array([1.0, 1.0, 1.0]), 3)
    assert not fine.violated_at_end()
    online = ConstraintMonitor(tau, [[], [], [1, 0]], min_steps=2, margin=0.1)
    assert not online.step(np.array([1.0, -1.0, 1.0]), 3)
    assert online.step(np.array([1.0, -1.0, 1.0]), 3)  # ends at the second step
    assert not online.violated_at_end()


def test_off_never_sets_a_threshold():
    config = load_config([*OVERRIDES, "mechanism.constraint_check=none"])
    mechanism = RewardMechanism(config.mechanism)
    mechanism.levels = [3, 3, 3]
    for _ in range(12):
        mechanism.end_episode(np.ones((30, 3)), np.full(30, 3))
    assert np.isnan(mechanism.constraint_monitor().thresholds).all()
    running = RewardMechanism(load_config(OVERRIDES).mechanism)
    running.levels = [3, 3, 3]
    for _ in range(12):
        running.end_episode(np.ones((30, 3)), np.full(30, 3))
    assert not np.isnan(running.constraint_monitor().thresholds[2])


def test_excluded_episodes_are_left_out_of_the_update():
    """``episode``: the steps of an episode that ended violating the constraint in this batch get
    no gradient; the others do (a trainer on the real task, two short batches)."""
    from ahrm_stack.learning.trainer import Trainer

    config = load_config(["profile=scratch", "mechanism.method=ahrm", "mechanism.constraint_check=episode",
                          "ppo.frames_per_batch=64", "ppo.mini_batch_size=16", "train.num_envs=2",
                          "train.time_limit=1.0", "mechanism.constraint_min_steps=5", "ppo.hidden_sizes=[16,16]",
                          "train.frames=128"])
    trainer = Trainer(config)
    trainer.mechanism.levels = [3, 3, 3]
    for _ in range(10):  # a history whose tau no random episode reaches
        trainer.mechanism.end_episode(np.ones((20, 3)), np.full(20, 3))
        trainer.mechanism.end_episode(np.ones((20, 3)), np.full(20, 1))
        trainer.mechanism.end_episode(np.ones((20, 3)), np.full(20, 2))
    seen = {}
    original = trainer._update

    def spy(data, keep=None):
        seen["keep"], seen["done"] = keep, data.get(("next", "done")).reshape(keep.shape)
        return original(data, keep)

    trainer._update = spy
    result = trainer.iteration()
    keep, done = seen["keep"], seen["done"]
    excluded = [row for row in result.episodes if row["constraint_excluded"]]
    assert excluded, "no episode violated a threshold of 1 per step"
    assert keep.shape == done.shape and not keep.all()
    assert result.batch["updates"] == (int(keep.sum()) // 16) * config.ppo.epochs
    # every dropped step belongs to an episode that ended in the batch
    for i in range(keep.shape[0]):
        ends = torch.nonzero(done[i]).flatten().tolist()
        last = ends[-1] if ends else -1
        assert keep[i, last + 1:].all()


def test_a_batch_whose_every_step_is_excluded_makes_no_update():
    """``episode``: when every step of a batch belongs to an excluded episode (the paper-row grid's
    episode-constraint run met one at 219k frames and crashed: TensorDict's numel() is 1 for an empty
    batch), the update makes no optimiser step and the run goes on."""
    from ahrm_stack.learning.trainer import Trainer

    config = load_config(["profile=scratch", "ppo.frames_per_batch=32", "ppo.mini_batch_size=16",
                          "train.num_envs=1", "train.time_limit=0.5", "ppo.hidden_sizes=[16,16]",
                          "train.frames=64"])
    trainer = Trainer(config)
    data = trainer._collect()
    parameters = [p for group in trainer._groups for p in group]
    before = [p.detach().clone() for p in parameters]
    totals, grad_norms, updates = trainer._update(data, torch.zeros(data.shape, dtype=torch.bool))
    assert updates == 0 and grad_norms == [] and totals == {}
    assert all(torch.equal(a, b) for a, b in zip(before, parameters))


def test_separate_optimisers_clip_and_step_each_network_on_its_own():
    """``ppo.optimizer: separate``: two Adams, each network's gradient clipped by itself; a
    checkpoint carries both and a shared-optimiser checkpoint is refused with a message."""
    from ahrm_stack.learning.trainer import Trainer

    base = ["profile=scratch", "ppo.frames_per_batch=32", "ppo.mini_batch_size=16", "train.num_envs=1",
            "train.time_limit=0.5", "ppo.hidden_sizes=[16,16]", "train.frames=32"]
    trainer = Trainer(load_config([*base, "ppo.optimizer=separate"]))
    actor, critic = trainer._groups
    assert len(trainer.optimizers) == 2
    assert {id(p) for p in trainer.optimizers[0].param_groups[0]["params"]} == {id(p) for p in actor}
    assert {id(p) for p in trainer.optimizers[1].param_groups[0]["params"]} == {id(p) for p in critic}
    before = [p.detach().clone() for p in critic]
    trainer.iteration()
    assert any(not torch.equal(a, b) for a, b in zip(before, critic))
    state = trainer.state_dict()
    assert isinstance(state["optimizer"], list) and len(state["optimizer"]) == 2
    shared = Trainer(load_config(base))
    assert len(shared.optimizers) == 1
    with pytest.raises(ValueError, match="ppo.optimizer"):
        shared.load_state_dict(state)
