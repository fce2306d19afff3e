"""Training's collection: the lean collection actor in the Collector, and ``train.env_workers``.

* The trainer collects with :class:`~ahrm_stack.learning.ppo.LeanCollectionActor`; the batch it
  collects equals, key for key, the batch the TorchRL actor collects from the same seeds.
* :class:`~ahrm_stack.learning.collection.LeanCollector` (the trainer's for in-process
  environments) gives, batch after batch, TorchRL's Collector's TensorDict: every key, value,
  dtype and shape, trajectory ids, episode ends and the mechanism's state.
* ``train.env_workers: 2`` puts the environments in two worker processes (other process ids than
  the trainer's) and gives the same first batch (observations, actions, rewards) as the same
  environments stepped in the trainer's process; the episodes' ends reach the trainer's mechanism
  and the checkpoint holds every environment's state.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
import torch

from torchrl_reference import ReferenceTrainer

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.learning.ppo import LeanCollectionActor
from ahrm_stack.learning.collection import LeanCollector
from ahrm_stack.learning.pool import EnvPool
from ahrm_stack.learning.trainer import Trainer

TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=80", "ppo.mini_batch_size=40",
        "task.episode.duration=1.0", "train.warm_start=none", "ppo.bc_coeff=0", "train.seed=3"]
KEYS = ("observation", "action", "action_log_prob", "loc", "scale", ("next", "reward"),
        ("next", "observation"), ("next", "done"))


def _first_batch(trainer: Trainer):
    trainer.warm_start()
    return trainer._collect().clone()


def _assert_same(got, want):
    assert got.shape == want.shape
    for key in KEYS:
        np.testing.assert_array_equal(got[key].numpy(), want[key].numpy(), err_msg=str(key))


def test_collector_runs_the_lean_actor_and_collects_what_the_torchrl_actor_does():
    lean = ReferenceTrainer(load_config(TINY), actor="lean")  # TorchRL's Collector, both actors
    batch = _first_batch(lean)
    policy = lean._collector.collector.policy
    assert isinstance(policy, LeanCollectionActor) or any(isinstance(m, LeanCollectionActor) for m in policy.modules())
    lean.close()
    reference = ReferenceTrainer(load_config(TINY), actor="torchrl")
    want = _first_batch(reference)
    assert not any(isinstance(m, LeanCollectionActor) for m in reference._collector.collector.policy.modules())
    reference.close()
    _assert_same(batch, want)  # sampled actions included: the same random draws


def test_env_workers_run_the_environments_in_other_processes():
    serial = Trainer(load_config([*TINY, "train.num_envs=2"]))
    want = _first_batch(serial)
    serial_episodes = serial.iteration().episodes  # a second batch: the episodes' summaries
    serial.close()

    threads = torch.get_num_threads()
    parallel = Trainer(load_config([*TINY, "train.num_envs=2", "train.env_workers=2"]))
    try:
        assert torch.get_num_threads() == threads  # the trainer's process keeps its thread count
        assert parallel.workers and parallel.envs == []
        pids = parallel.env.process_id()
        assert len(set(pids)) == 2 and os.getpid() not in pids
        got = _first_batch(parallel)
        _assert_same(got, want)  # the same environments, stepped elsewhere
        result = parallel.iteration()
        # the episodes of both batches reached the trainer's mechanism, in the order they ended
        assert parallel.episodes == parallel.mechanism.episodes > 0
        assert [e["steps"] for e in result.episodes] == [e["steps"] for e in serial_episodes]
        state = parallel.state_dict()
        assert len(state["env_rng"]) == 2 and state["env_rng"][0] != state["env_rng"][1]
        np.testing.assert_equal(state["time_objective"], serial.state_dict()["time_objective"])
        parallel.load_state_dict(state)  # back into the workers
        assert parallel.state_dict()["env_rng"] == state["env_rng"]
    finally:
        parallel.close()
    assert torch.get_num_threads() == threads


def test_env_workers_must_divide_num_envs():
    with pytest.raises(ConfigError, match="train.num_envs .3. must be a multiple of train.env_workers .2."):
        load_config([*TINY, "train.num_envs=3", "train.env_workers=2"])
    with pytest.raises(ConfigError, match="train.env_workers"):
        load_config([*TINY, "train.env_workers=0"])


def _batches(trainer: Trainer, count: int) -> tuple[list, list]:
    """``count`` batches, draining the ended episodes after each as ``iteration`` does (with worker
    processes that applies them to the trainer's mechanism and sends its new state to the workers,
    so the next batch's rewards depend on it arriving)."""
    trainer.warm_start()
    batches, episodes, states = [], [], []
    for _ in range(count):
        batches.append(trainer._collect().clone())
        # end_order counts every episode ended in this process: two trainers' differ
        episodes += [dataclasses.asdict(s) | {"end_order": None} for s in trainer._completed()]
        states.append(trainer.mechanism.state_dict())
        if isinstance(trainer.env, EnvPool):  # every worker rewards with the trainer's new state
            for copy in trainer.env.mechanism_state():
                np.testing.assert_equal(copy, states[-1])
    with pytest.raises(AssertionError):  # the state did change between the batches
        np.testing.assert_equal(states[0], states[-1])
    return batches, episodes


@pytest.mark.parametrize("envs,workers", [(1, 1), (2, 1), (2, 2), (4, 2)])
def test_lean_collector_gives_the_torchrl_collectors_batches(envs, workers):
    """In process (LocalEnvs) against a SerialEnv, and through the EnvPool's worker processes (one
    or two environments each) against a ParallelEnv of the same workers."""
    # 1 s episodes (20 steps) and 40-step batches per environment: episodes end inside batches,
    # the mechanism's adaptive state changes between them (AHRM levels and orders, P = 2)
    config = load_config([*TINY, f"train.num_envs={envs}", f"train.env_workers={workers}",
                          "mechanism.priority_period=2", "mechanism.convergence_window=1",
                          "mechanism.constraint_window=1"])
    lean = Trainer(config)
    try:
        got, got_episodes = _batches(lean, 3)
        assert isinstance(lean._collector, LeanCollector)
        assert isinstance(lean.env, EnvPool) == (workers > 1)
        lean_mechanism = lean.mechanism.state_dict()
        lean_envs = lean.state_dict()["env_rng"]
    finally:
        lean.close()
    if workers > 1:  # the reference: a ParallelEnv of one environment per worker (TorchRL's workers
        # do not reach the WorkerEnv methods through a SerialEnv); with the ends deferred to the
        # batch's end the environments are independent, so the split over workers changes nothing
        config = dataclasses.replace(config, train=dataclasses.replace(config.train, env_workers=envs))
    reference = ReferenceTrainer(config)
    try:
        want, want_episodes = _batches(reference, 3)
        assert not isinstance(reference._collector, LeanCollector)
        assert not isinstance(reference.env, EnvPool)
        reference_mechanism = reference.mechanism.state_dict()
        reference_envs = reference.state_dict()["env_rng"]
    finally:
        reference.close()
    for a, b in zip(got, want):
        assert a.batch_size == b.batch_size
        assert set(a.keys(True, True)) == set(b.keys(True, True))
        for key in b.keys(True, True):
            assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
            np.testing.assert_array_equal(a[key].numpy(), b[key].numpy(), err_msg=str(key))
    assert sum(int(b["next", "done"].sum()) for b in want) >= 2 * envs  # episodes did end
    assert len(want_episodes) == sum(int(b["next", "done"].sum()) for b in want)
    np.testing.assert_equal(got_episodes, want_episodes)
    np.testing.assert_equal(lean_mechanism, reference_mechanism)
    assert lean_envs == reference_envs  # every environment's random state after the batches


def test_episodes_are_logged_in_the_order_the_mechanism_saw_them():
    """With several environments in one process the trainer numbers the episodes (episodes.csv,
    the events' episode) in the order they ended — the order the mechanism applied them — not
    environment by environment: each logged row's component sums and each event's number match
    the mechanism's own sequence of end_episode calls."""
    # 4 environments, episodes of 5-20 steps ending at different steps (the priority constraint
    # ends some early); the mechanism's levels advance between episodes (W = 1)
    config = load_config([*TINY, "train.num_envs=4", "ppo.frames_per_batch=160",
                          "mechanism.convergence_window=1", "mechanism.constraint_window=1",
                          "mechanism.constraint_min_steps=2", "mechanism.priority_period=2"])
    trainer = Trainer(config)
    trainer.warm_start()
    seen, end_episode = [], trainer.mechanism.end_episode

    def recording(f, phase, **kwargs):
        events = end_episode(f, phase, **kwargs)
        seen.append((float(np.asarray(f).sum()), [(e.kind, e.phase, e.detail) for e in events]))
        return events

    trainer.mechanism.end_episode = recording
    rows, events = [], []
    for _ in range(3):
        result = trainer.iteration()
        rows += result.episodes
        events += result.events
    trainer.close()
    assert len(rows) == len(seen) >= 8
    ends = [row["episode"] for row in rows]
    assert ends == list(range(1, len(rows) + 1))
    # the order matters here: episodes of different lengths end interleaved across environments
    assert [float(np.sum(row["component_sums"])) for row in rows] == [total for total, _ in seen]
    want = [(i + 1, kind, phase, detail) for i, (_, made) in enumerate(seen) for kind, phase, detail in made]
    assert [(e.episode, e.kind, e.phase, e.detail) for e in events] == want and want
