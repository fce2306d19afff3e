"""Training's collection: the lean collection actor in the Collector, and ``train.env_workers``.

* The trainer collects with :class:`~ahrm_stack.learning.ppo.LeanCollectionActor`; the batch it
  collects equals, key for key, the batch the TorchRL actor collects from the same seeds.
* ``train.env_workers: 2`` puts the environments in two worker processes (other process ids than
  the trainer's) and gives the same first batch (observations, actions, rewards) as the same
  environments stepped in the trainer's process; the episodes' ends reach the trainer's mechanism
  and the checkpoint holds every environment's state.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.learning import trainer as trainer_module
from ahrm_stack.learning.ppo import LeanCollectionActor
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


def test_collector_runs_the_lean_actor_and_collects_what_the_torchrl_actor_does(monkeypatch):
    lean = Trainer(load_config(TINY))
    batch = _first_batch(lean)
    assert isinstance(lean._collector.policy, LeanCollectionActor) or any(
        isinstance(m, LeanCollectionActor) for m in lean._collector.policy.modules())
    lean.close()
    monkeypatch.setattr(trainer_module, "lean_collection_actor", lambda actor: None)
    reference = Trainer(load_config(TINY))
    want = _first_batch(reference)
    assert not any(isinstance(m, LeanCollectionActor) for m in reference._collector.policy.modules())
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
