"""Interim evaluations beside training (``train.eval_beside``) give the rows the training's own
process gives, and the run folder says where its wall time went (``timing.json``)."""

from __future__ import annotations

import csv
import json

import torch

from ahrm_stack.config import load_config
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.interim import InterimEvaluations
from ahrm_stack.learning.ppo import make_modules
from ahrm_stack.learning.training import train
from ahrm_stack.run_config import run_config_text

QUICK = ["profile=scratch", "ppo.frames_per_batch=128", "ppo.mini_batch_size=64", "ppo.epochs=1",
         "train.num_envs=2", "train.frames=512", "train.eval_every_frames=256", "train.eval_episodes=2",
         "task.episode.duration=3", "train.checkpoint_every=2"]


def _rows(run_dir) -> list[dict]:
    with open(run_dir / "evaluations.csv") as handle:
        return list(csv.DictReader(handle))


def test_evaluations_beside_training_give_the_in_process_rows(tmp_path):
    runs = {}
    for beside in (False, True):
        config = load_config([*QUICK, f"train.eval_beside={str(beside).lower()}"])
        runs[beside] = train(config, tmp_path / str(beside), resume=False, progress=False)
    inline, beside_rows = _rows(runs[False]), _rows(runs[True])
    assert len(inline) == 3  # frames 0, 256, 512
    assert inline == beside_rows
    for run in runs.values():
        timing = json.loads((run / "timing.json").read_text())
        assert timing["evaluations"] == 3 and timing["frames"] == 512
        assert timing["evaluation_steps"] == 3 * 2 * 60  # 3 s episodes, no success
        assert 0 < timing["evaluation_share"] < 1
        assert timing["evaluation_wait_seconds"] <= timing["loop_seconds"]
        assert timing["batch_seconds"] <= timing["loop_seconds"]
        assert timing["frames_per_second"] == timing["frames"] / timing["loop_seconds"]
    # in the training's process, the loop waits for every evaluation
    inline_t = json.loads((runs[False] / "timing.json").read_text())
    assert inline_t["evaluation_wait_seconds"] >= 0.9 * inline_t["evaluation_seconds"]



def test_closing_with_an_evaluation_running_stops_the_worker(tmp_path):
    """An error path (Ctrl-C, a failed batch) closes the evaluations while one runs: the worker is
    terminated, not waited for (200 episodes would take minutes), and no row is logged."""
    config = load_config(["train.eval_episodes=200"])
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.yaml").write_text(run_config_text(config))
    env = PushOffEnv(config.task, config.safety, seed=0)
    dims = int(env.observation_spec["observation"].shape[-1]), int(env.action_spec.shape[-1])
    modules = make_modules(config.ppo, *dims)
    policy_file = run_dir / "policy.pt"
    torch.save({"actor": modules.actor.state_dict(), "observation_dim": dims[0], "action_dim": dims[1]},
               policy_file)
    logged: list = []
    evaluations = InterimEvaluations(config, run_dir, True, lambda *row: logged.append(row))
    evaluations.ask(modules.actor, policy_file, 0, 0)
    assert evaluations._pool is not None
    processes = list(evaluations._pool._processes.values())
    evaluations.close()
    for process in processes:
        process.join(timeout=30)
        assert not process.is_alive()
    assert logged == []
