"""The environments of training's worker processes (``train.env_workers`` > 1).

The ``train.num_envs`` environments are split evenly over ``train.env_workers`` processes, so the
physics of different environments runs on different cores while the trainer's process runs the
policy once per step for all of them (one batched call). The trainer's processes are an
:class:`~ahrm_stack.learning.pool.EnvPool` (``env`` below: the pool, or in the tests the same workers
as a TorchRL ``ParallelEnv``, one environment per worker: the reference the pool's batches are held
to, ``tests/torchrl_reference.py``).

The reward mechanism's adaptive state stays the trainer's. Each worker holds a copy of it for the
per-step reward and the priority constraint, and defers every episode end to the trainer: at the end
of each collected batch the trainer drains the completed episodes, applies them to its mechanism in
the order they ended (by step, then environment index: the order a ``SerialEnv`` would apply them
in), and sends the new state back to every worker. So within one batch the workers reward with
the state of the batch's start; with one process (``env_workers: 1``) an episode's end changes the
reward of the very next step. Everything else (seeds, f3's budgets, the environments' dynamics) is
as in one process.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np

from ahrm_stack.config import MechanismConfig, SafetyConfig, TaskConfig
from ahrm_stack.env.episode import EpisodeSummary
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.mechanisms import RewardMechanism


@dataclasses.dataclass
class PendingEpisode:
    """An episode that ended in a worker, waiting for the trainer's mechanism."""

    step: int  # the environment's step count when it ended (all environments step together)
    index: int  # the environment's index in 0..num_envs-1
    summary: EpisodeSummary
    f: np.ndarray  # (steps, 3) the ±1 components
    phase: np.ndarray  # (steps,)
    constraint_terminated: bool
    terminated_phase: int | None
    constraint_excluded: bool = False


class _DeferredMechanism:
    """A worker's copy of the mechanism: rewards and constraint monitors from the state last sent
    by the trainer; episode ends are recorded, not applied (the trainer applies them)."""

    def __init__(self, config: MechanismConfig) -> None:
        self.local = RewardMechanism(config)
        self.pending: list[dict] = []

    def reward(self, g, distances):
        return self.local.reward(g, distances)

    def constraint_monitor(self):
        return self.local.constraint_monitor()

    def end_episode(self, f, phase, constraint_terminated: bool = False,
                    terminated_phase: int | None = None, constraint_excluded: bool = False) -> list:
        self.pending.append(dict(f=np.asarray(f, dtype=float).reshape(-1, 3),
                                 phase=np.asarray(phase, dtype=int).reshape(-1),
                                 constraint_terminated=bool(constraint_terminated),
                                 terminated_phase=terminated_phase,
                                 constraint_excluded=bool(constraint_excluded)))
        return []  # the trainer's end_episode makes the events


class WorkerEnv(PushOffEnv):
    """A :class:`PushOffEnv` living in a worker process (environment ``index`` of the trainer's)."""

    def __init__(self, task: TaskConfig, safety: SafetyConfig, mechanism: MechanismConfig,
                 seed: int, index: int, time_limit: float = 0.0, touch_penalty: float = 0.0) -> None:
        super().__init__(task, safety, seed=seed, mechanism=_DeferredMechanism(mechanism),
                         time_limit=time_limit, touch_penalty=touch_penalty)
        self.index = index
        self.steps_taken = 0
        self._ends: list[tuple[int, EpisodeSummary]] = []

    def advance(self, action):
        self.steps_taken += 1  # (the ParallelEnv's _step and the pool's LocalEnvs both come here)
        return super().advance(action)

    # Called by the trainer through the ParallelEnv (same arguments for every environment).
    def drain(self) -> list[PendingEpisode]:
        """The episodes completed since the last call (and forget them here)."""
        out = [PendingEpisode(step, self.index, summary, **pending)
               for (step, summary), pending in zip(self._ends, self.mechanism.pending)]
        self.completed.clear()
        self.mechanism.pending.clear()
        self._ends.clear()
        return out

    def _finish_episode(self, constrained: bool) -> None:
        super()._finish_episode(constrained)
        self._ends.append((self.steps_taken, self.completed[-1]))

    def load_mechanism(self, state: dict) -> None:
        self.mechanism.local.load_state_dict(state)

    def worker_state(self) -> tuple[int, dict, Any]:
        """(index, f3's phase budgets, the environment's random state)."""
        return self.index, self.task.time_objective.state_dict(), self.runner.random_state.get_state()

    def load_worker_state(self, budgets: list, rngs: list) -> None:
        """Take this environment's entries of the trainer's per-environment lists."""
        self.task.time_objective.load_state_dict(budgets[self.index])
        self.runner.random_state.set_state(rngs[self.index])

    def process_id(self) -> int:
        return os.getpid()

    def set_near_cube_share(self, share: float) -> None:
        """The start curriculum's level (``train.start_curriculum: near_cube``), from the trainer."""
        self.task.near_cube_share = float(share)

    def set_touch_penalty(self, penalty: float) -> None:
        """``train.touch_end`` switched on after ``train.touch_end_after`` frames, from the trainer."""
        self.touch_penalty = float(penalty)

    def set_touch_cost(self, cost: float) -> None:
        """``task.rewards.touch_cost`` charged from ``train.touch_cost_after`` frames, from the trainer."""
        self.touch_cost = float(cost)

    def mechanism_state(self) -> dict:
        """The state this environment rewards with (the trainer's, as last sent)."""
        return self.mechanism.local.state_dict()

    def worker_settings(self) -> tuple[float, float, float]:
        """(near-cube share, touch penalty, touch cost) as this environment holds them."""
        return self.task.near_cube_share, self.touch_penalty, self.touch_cost


def _flat(results: list) -> list:
    """A dispatched call's results, one per environment (flattened where a worker returned a list)."""
    out = []
    for result in results:
        out.extend(result if isinstance(result, list) else [result])
    return out


def drain(env: Any) -> list[PendingEpisode]:
    """Every worker's completed episodes, in the order they ended (step, then environment)."""
    return sorted(_flat(env.drain()), key=lambda p: (p.step, p.index))


def per_environment(env: Any, method: str, *args) -> list:
    """``method`` called on every environment; results in environment order."""
    results = _flat(getattr(env, method)(*args))
    return results


__all__ = ["PendingEpisode", "WorkerEnv", "drain", "per_environment"]
