"""The EnvPool's worker processes: where the environments live, and what a failing worker does.

(That its batches are TorchRL's ``ParallelEnv``'s, key for key, is in ``tests/test_collection.py``.)
"""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.learning.pool import EnvPool, WorkerError

TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=80", "ppo.mini_batch_size=40",
        "task.episode.duration=1.0", "train.warm_start=none", "ppo.bc_coeff=0", "train.seed=3",
        "train.num_envs=4", "train.env_workers=2"]


@pytest.fixture
def pool():
    pool = EnvPool(load_config(TINY), [10, 11, 12, 13])
    yield pool
    pool.close()


def test_the_pool_steps_its_environments_in_two_other_processes(pool):
    pids = pool.process_id()
    assert len(pids) == 4 and pids[0] == pids[1] != pids[2] == pids[3] and os.getpid() not in pids
    first = pool.begin()
    assert first["observation"].shape == (4, pool.widths["observation"])
    assert first["observation"].dtype == np.float32 and first["phase"].dtype == np.int64
    action = np.zeros((4, pool.action_spec.shape[-1]), dtype=np.float32)
    values, reward, terminated, truncated, resets = pool.step(action)
    assert values["observation"].shape == (4, pool.widths["observation"])
    assert reward.shape == terminated.shape == truncated.shape == (4,)
    assert not (terminated | truncated).any() and len(resets["observation"]) == 0
    for _ in range(19):  # 1 s episodes of 20 control steps: all four end at the 20th step
        values, reward, terminated, truncated, resets = pool.step(action)
    assert truncated.all() and len(resets["observation"]) == 4
    assert [len(ended) for ended in pool.drain()] == [1, 1, 1, 1]


def test_a_worker_that_raises_names_itself_and_the_error(pool):
    pool.begin()
    with pytest.raises(WorkerError, match=r"environment worker 0 \(environments 0\.\.1\) raised ValueError: "
                                          r"action.mode cartesian: the action must have shape \(3,\)"):
        pool.step(np.zeros((4, 99), dtype=np.float32))  # the wrong action size
    # both workers' replies were read: the pipes are in step for the next call
    assert len(pool.process_id()) == 4
    with pytest.raises(ValueError, match="unknown environment call 'reset_everything'"):
        pool.call("reset_everything")


def test_a_dead_worker_is_reported_and_close_ends_the_rest(pool):
    pool.begin()
    os.kill(pool._processes[0].pid, signal.SIGKILL)  # (no join: the pool reads the exit status itself)
    with pytest.raises(WorkerError, match=r"environment worker 0 \(environments 0\.\.1\) died"):
        pool.step(np.zeros((4, pool.action_spec.shape[-1]), dtype=np.float32))
    pool.close()
    assert not any(process.is_alive() for process in pool._processes)
    with pytest.raises(WorkerError, match="closed"):
        pool.begin()


def test_training_stops_on_a_dead_worker_keeps_its_checkpoint_and_resumes(tmp_path, monkeypatch):
    """End to end with ``train.env_workers=2``: a worker killed after the second batch's checkpoint
    stops the run with one line naming the worker and the checkpoint; ``--resume`` finishes it with
    every episode logged once, numbered 1..N."""
    import csv

    from ahrm_stack.learning.trainer import Trainer
    from ahrm_stack.train import main

    run = tmp_path / "run"
    small = ["ppo.hidden_sizes=[32,32]", "ppo.frames_per_batch=128", "task.episode.duration=1",
             "train.eval_episodes=0", "train.checkpoint_every=1", "train.warm_start=none", "ppo.bc_coeff=0",
             "train.num_envs=2", "train.env_workers=2"]
    iteration = Trainer.iteration

    def killing(self):
        if self.batches == 2:
            os.kill(self.env._processes[1].pid, signal.SIGKILL)
        return iteration(self)

    monkeypatch.setattr(Trainer, "iteration", killing)
    with pytest.raises(SystemExit, match=r"training stopped: environment worker 1 \(environments 1\.\.1\) died "
                                         r"\(exit code -9\)\. The last checkpoint is kept in .*--resume"):
        main([*small, "train.episodes=30", "--run-dir", str(run), "--no-progress"])
    with open(run / "episodes.csv") as handle:
        before = list(csv.DictReader(handle))
    assert len(before) >= 2  # two batches of 64-step rounds with 20-step episodes
    monkeypatch.setattr(Trainer, "iteration", iteration)
    assert main(["--resume", str(run), "--no-progress"]) == 0
    with open(run / "episodes.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["episode"]) for r in rows] == list(range(1, len(rows) + 1)) and len(rows) >= 30


@pytest.mark.parametrize("overrides,key", [
    (["safety.position_margin=3.0"], "safety"),
    (["task.layout.mode=fixed", "task.obstacles.fixed_layout=[[0.0,0.0]]"], "task.obstacles.fixed_layout"),
])
def test_what_only_building_the_environments_finds_is_one_line_with_workers(overrides, key, tmp_path, monkeypatch,
                                                                           capsys):
    """Checks made when the environments are built (in the workers) fail as they do in process: one
    line naming the key, exit code 2, nothing written."""
    from ahrm_stack.train import main

    monkeypatch.chdir(tmp_path)
    rc = main([*TINY, *overrides, "--run-dir", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: ") and key in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_call_leaves_the_pool_refusing_calls(pool, monkeypatch):
    """A call interrupted between its send and its replies (Ctrl-C) would leave replies in the pipes:
    the pool refuses every later call instead of reading them as the next call's."""
    pool.begin()
    conn = pool._conns[1]

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(conn, "recv", interrupted)
    with pytest.raises(KeyboardInterrupt):
        pool.process_id()
    monkeypatch.undo()
    with pytest.raises(WorkerError, match="interrupted mid-call"):
        pool.process_id()


def test_the_shared_step_gives_what_concatenating_the_workers_replies_gives():
    """Two workers' step outputs written into their rows of one SharedStep read back as the
    concatenation of the replies (the reset values of the ended environments in index order)."""
    from ahrm_stack.learning.collection import STEP_KEYS
    from ahrm_stack.learning.pool import SharedStep

    widths = {key: 3 + k for k, key in enumerate(STEP_KEYS)}
    dtypes = {key: (np.float32, np.int64, np.bool_)[k % 3] for k, key in enumerate(STEP_KEYS)}
    rng = np.random.default_rng(0)

    def reply(n, ended):
        values = {key: (rng.uniform(-5, 5, (n, widths[key])) * 10).astype(dtypes[key]) for key in STEP_KEYS}
        terminated, truncated = np.zeros(n, bool), np.zeros(n, bool)
        terminated[ended[:1]], truncated[ended[1:]] = True, True
        resets = {key: (rng.uniform(-5, 5, (len(ended), widths[key])) * 10).astype(dtypes[key]) for key in STEP_KEYS}
        return values, rng.standard_normal(n).astype(np.float32), terminated, truncated, resets

    buffer = bytearray(SharedStep.size(5, widths, dtypes, 6, np.float32))
    shared = SharedStep(memoryview(buffer), 5, widths, dtypes, 6, np.float32)
    for first, second in (([1], [0, 2]), ([], [])):  # ends in both workers; none
        parts = [reply(2, first), reply(3, second)]
        shared.write(0, parts[0])
        shared.write(2, parts[1])
        values, reward, terminated, truncated, resets = shared.read()
        for key in STEP_KEYS:
            np.testing.assert_array_equal(values[key], np.concatenate([p[0][key] for p in parts]))
            np.testing.assert_array_equal(resets[key], np.concatenate([p[4][key] for p in parts]))
            assert values[key].dtype == resets[key].dtype == dtypes[key]
        for k, got in ((1, reward), (2, terminated), (3, truncated)):
            np.testing.assert_array_equal(got, np.concatenate([p[k] for p in parts]))
    assert len(buffer) % SharedStep.ALIGN == 0

