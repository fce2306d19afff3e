"""A training run's interim evaluations, in its own process or beside it in a worker process.

An interim evaluation (``train.eval_every`` / ``train.eval_every_frames``) runs the policy of that
moment, deterministically, on ``train.eval_episodes`` validation episodes of the run's nominal task
(:data:`~ahrm_stack.learning.rollouts.VALIDATION_SEED_OFFSET` onwards) and logs one row of
``evaluations.csv``. The policy is saved first (``policies/episode-N.pt``: what the row evaluated).

With ``train.eval_beside`` the evaluation runs in one worker process (spawned, one torch thread)
while training goes on: it loads the saved policy file and runs the same episodes on its own
environment, built once like the in-process one, so the rows are the ones an in-process
evaluation gives (``tests/test_interim.py``). Rows are logged in the order the evaluations were
asked for, with the episode and frame counts of that moment; :meth:`InterimEvaluations.drain`
with ``wait`` blocks until every pending row is logged (at the end of the run). A checkpoint does
not wait: it records the evaluations still pending (:meth:`InterimEvaluations.pending`, their
saved policy files), and a run resumed from it asks for them again
(:meth:`InterimEvaluations.ask_saved`), so no row is lost and none is written twice.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import os
import threading
import time
from pathlib import Path

import torch

from ahrm_stack.config import Config
from ahrm_stack.realism import nominal
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, EvaluationTable, load_policy, run_episodes

_WORKER_ENV: PushOffEnv | None = None  # the worker's evaluation environment, built once


@dataclasses.dataclass(frozen=True)
class Evaluated:
    """One interim evaluation's result: the table, its wall seconds and control steps."""

    table: EvaluationTable
    seconds: float
    steps: int


def evaluation_env(config: Config) -> PushOffEnv:
    """The environment every interim evaluation of a run replays its episodes on."""
    return PushOffEnv(nominal(config.task), config.safety, seed=VALIDATION_SEED_OFFSET)


def evaluate(env: PushOffEnv, policy, episodes: int) -> Evaluated:
    started = time.perf_counter()
    summaries = run_episodes(env, policy, episodes)
    return Evaluated(EvaluationTable.from_summaries(summaries), time.perf_counter() - started,
                     sum(s.steps for s in summaries))


def _exit_with_parent(parent: int, period: float = 1.0) -> None:
    """End this worker process when its parent (the training) is gone, whatever killed it: the
    executor's own shutdown never runs then, and an evaluation would run on for minutes."""
    while True:
        time.sleep(period)
        if os.getppid() != parent:
            os._exit(0)


def _start_worker(config: Config, parent: int) -> None:
    global _WORKER_ENV
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    torch.set_num_threads(1)
    from ahrm_stack.seeds import sealed

    sealed().__enter__()  # the worker belongs to a training: no test seed, as in its parent
    _WORKER_ENV = evaluation_env(config)


def _evaluate_file(run_dir: str, policy_file: str, episodes: int) -> Evaluated:
    assert _WORKER_ENV is not None
    _, policy = load_policy(Path(run_dir), Path(policy_file))
    return evaluate(_WORKER_ENV, policy, episodes)


class InterimEvaluations:
    """The run's interim evaluations; ``beside``: in a worker process (see the module's text).
    ``log(episode, frames, evaluated)`` records one; it is called in the order of :meth:`ask`."""

    def __init__(self, config: Config, run_dir: Path, beside: bool, log) -> None:
        self.config, self.run_dir, self.log = config, Path(run_dir), log
        self._pending: list[tuple[int, int, str, concurrent.futures.Future]] = []
        self._env: PushOffEnv | None = None
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        if beside:
            self._pool = concurrent.futures.ProcessPoolExecutor(
                1, mp_context=multiprocessing.get_context("spawn"), initializer=_start_worker,
                initargs=(config, os.getpid()))
            self._pool.submit(int)  # start the worker (imports, environment) while training sets up
        else:
            self._env = evaluation_env(config)

    def ask(self, actor, policy_file: Path, episodes: int, frames: int) -> None:
        """Evaluate the policy saved in ``policy_file`` (``actor``: the same policy, in memory) at
        the run's ``episodes`` training episodes and ``frames`` frames."""
        if self._pool is None:
            assert self._env is not None
            self.log(episodes, frames, evaluate(self._env, actor, self.config.train.eval_episodes))
            return
        future = self._pool.submit(_evaluate_file, str(self.run_dir), str(policy_file),
                                   self.config.train.eval_episodes)
        self._pending.append((episodes, frames, str(policy_file), future))

    def ask_saved(self, policy_file: Path, episodes: int, frames: int) -> None:
        """Evaluate the policy saved in ``policy_file`` (a resumed run's pending evaluation)."""
        if self._pool is None:
            _, policy = load_policy(self.run_dir, Path(policy_file))
            self.ask(policy, Path(policy_file), episodes, frames)
        else:
            self.ask(None, Path(policy_file), episodes, frames)

    def pending(self) -> list[dict]:
        """The evaluations asked for and not logged yet: what a checkpoint records."""
        return [{"episodes": episodes, "frames": frames, "policy_file": file}
                for episodes, frames, file, _ in self._pending]

    def drain(self, wait: bool = False) -> None:
        """Log the finished evaluations, in order; ``wait``: every pending one."""
        while self._pending and (wait or self._pending[0][3].done()):
            episodes, frames, _, future = self._pending.pop(0)
            self.log(episodes, frames, future.result())

    def close(self) -> None:
        """Stop the worker. Pending evaluations (only on an error path: the run drains them before
        it ends) are dropped, and a running one is not waited for: its process is terminated."""
        if self._pool is not None:
            running = bool(self._pending)
            processes = list(getattr(self._pool, "_processes", {}).values())  # the executor's own
            self._pool.shutdown(wait=not running, cancel_futures=True)
            if running:
                for process in processes:
                    process.terminate()
            self._pool = None
            self._pending.clear()
