"""Interim evaluations beside training (``train.eval_beside``) give the rows the training's own
process gives, and the run folder says where its wall time went (``timing.json``)."""

from __future__ import annotations

import csv
import json
from multiprocessing.connection import wait

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



def _saved_policy(config, tmp_path):
    """A run folder with ``config`` and an initial policy saved as training saves one."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.yaml").write_text(run_config_text(config))
    env = PushOffEnv(config.task, config.safety, seed=0)
    dims = int(env.observation_spec["observation"].shape[-1]), int(env.action_spec.shape[-1])
    modules = make_modules(config.ppo, *dims)
    policy_file = run_dir / "policy.pt"
    torch.save({"actor": modules.actor.state_dict(), "observation_dim": dims[0], "action_dim": dims[1]},
               policy_file)
    return run_dir, modules, policy_file


def test_closing_with_an_evaluation_running_stops_the_worker(tmp_path):
    """An error path (Ctrl-C, a failed batch) closes the evaluations while one runs: the worker is
    terminated, not waited for (200 episodes would take minutes), and no row is logged."""
    config = load_config(["train.eval_episodes=200"])
    run_dir, modules, policy_file = _saved_policy(config, tmp_path)
    logged: list = []
    evaluations = InterimEvaluations(config, run_dir, True, lambda *row: logged.append(row))
    evaluations.ask(modules.actor, policy_file, 0, 0)
    assert evaluations._pool is not None
    processes = list(evaluations._pool._processes.values())
    evaluations.close()
    # the executor's management thread reaps its workers too, so ``is_alive`` can race with it
    # (CPython's poll sees ECHILD and answers None); a process's sentinel is ready once it has exited
    for process in processes:
        assert wait([process.sentinel], timeout=30) == [process.sentinel]
    assert logged == []


def test_a_checkpoint_records_the_pending_evaluations_and_a_resumed_run_logs_each_once(tmp_path):
    """Beside training, a checkpoint does not wait for an evaluation: it records it, and a run
    resumed from that checkpoint asks for it again unless its row was written meanwhile."""
    overrides = [*QUICK, "train.eval_beside=true", "train.checkpoint_every=1"]
    run = train(load_config(overrides), tmp_path / "run", resume=False, progress=False)
    state = torch.load(sorted((run / "checkpoints").glob("ckpt-*.pt"))[-1], weights_only=True)
    assert state["pending_evaluations"] == []  # the end waits for every row
    longer = load_config([*overrides, "train.frames=1024"])
    train(longer, run, resume=True, progress=False, rewrite_config=True)
    episodes = [int(row["episode"]) for row in _rows(run)]
    assert episodes == sorted(set(episodes)) and len(episodes) == 5  # frames 0, 256, ..., 1024


def test_pending_evaluations_are_listed_until_logged(tmp_path):
    config = load_config(["train.eval_episodes=1", "task.episode.duration=1"])
    run_dir, modules, policy_file = _saved_policy(config, tmp_path)
    logged: list = []
    evaluations = InterimEvaluations(config, run_dir, True, lambda *row: logged.append(row[:2]))
    try:
        evaluations.ask_saved(policy_file, 7, 700)
        assert evaluations.pending() == [{"episodes": 7, "frames": 700, "policy_file": str(policy_file)}]
        evaluations.drain(wait=True)
        assert evaluations.pending() == [] and logged == [(7, 700)]
    finally:
        evaluations.close()


_ORPHAN_PARENT = """
import sys, time
from pathlib import Path
from ahrm_stack.config import load_config
from ahrm_stack.learning.interim import InterimEvaluations
config = load_config(["train.eval_episodes=200"])
evaluations = InterimEvaluations(config, Path(sys.argv[1]), True, lambda *row: None)
evaluations.ask_saved(Path(sys.argv[2]), 0, 0)
print(*[p.pid for p in evaluations._pool._processes.values()], flush=True)
time.sleep(600)
"""


def test_the_worker_ends_when_the_training_process_is_killed(tmp_path):
    """A training killed outright (SIGKILL: no finally, no executor shutdown) leaves no evaluation
    worker running on."""
    import os
    import signal
    import subprocess
    import sys
    import time

    config = load_config(["train.eval_episodes=200"])
    run_dir, _, policy_file = _saved_policy(config, tmp_path)
    parent = subprocess.Popen([sys.executable, "-c", _ORPHAN_PARENT, str(run_dir), str(policy_file)],
                              stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    workers = [int(pid) for pid in parent.stdout.readline().split()]
    assert workers
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 60
    alive = workers
    while alive and time.monotonic() < deadline:
        time.sleep(0.5)
        alive = []
        for pid in workers:
            try:
                os.kill(pid, 0)
                with open(f"/proc/{pid}/stat") as handle:  # a zombie awaiting its reaper is gone
                    if handle.read().split()[2] != "Z":
                        alive.append(pid)
            except (ProcessLookupError, FileNotFoundError):
                pass
    assert alive == [], f"evaluation workers {alive} outlived their killed parent"
