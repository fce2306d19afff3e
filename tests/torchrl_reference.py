"""The oracle the trainer's collection is held to: TorchRL's own ``Collector`` and ``ParallelEnv``.

Production collects with :class:`~ahrm_stack.learning.collection.LeanCollector` (in process, or
through the :class:`~ahrm_stack.learning.pool.EnvPool`'s workers) and the actor's lean path.
:class:`ReferenceTrainer` is the same trainer with TorchRL's pieces in their place: a ``Collector``
(over the trainer's ``SerialEnv`` or over a ``ParallelEnv`` of the same worker environments, one per
process) running the lean actor or the TorchRL actor itself. ``tests/test_collection.py`` holds the
batches of the two equal, key for key; ``benchmarks/bench_collection.py`` times them.
"""

from __future__ import annotations

import functools

import torch
from torchrl.collectors import Collector
from torchrl.envs import ParallelEnv
from torchrl.envs.utils import ExplorationType

from ahrm_stack.config import Config
from ahrm_stack.env.torchrl_env import touch_penalty
from ahrm_stack.learning.trainer import Trainer
from ahrm_stack.learning.workers import WorkerEnv


def make_worker_envs(config: Config, seeds: list[int]) -> ParallelEnv:
    """``train.env_workers`` processes, one environment each. The parent waits on the pipes
    (``use_buffers=False``): TorchRL's shared-buffer mode spin-polls in the parent, which takes a
    core from the workers on a small machine."""
    workers = config.train.env_workers
    per = len(seeds) // workers  # num_envs is a multiple of env_workers (ahrm_stack/config)
    if per > 1:  # the WorkerEnv calls (drain, load_mechanism, ...) do not pass through a SerialEnv
        raise ValueError(f"the ParallelEnv reference runs one environment per worker: train.num_envs "
                         f"({len(seeds)}) must equal train.env_workers ({workers}); the EnvPool takes any split")
    groups = [functools.partial(WorkerEnv, config.task, config.safety, config.mechanism, seeds[w], w,
                                config.train.time_limit, touch_penalty(config.train.touch_end, config.ppo.gamma))
              for w in range(workers)]
    # num_threads is what TorchRL sets in this process: keep its count; each worker gets one
    env = ParallelEnv(workers, groups, use_buffers=False, num_threads=torch.get_num_threads(),
                      num_sub_threads=1)
    env.start()
    return env


class _Batches:
    """A TorchRL ``Collector`` behind the trainer's ``next()``."""

    def __init__(self, collector: Collector) -> None:
        self.collector = collector
        self._iterator = iter(collector)

    def next(self):
        return next(self._iterator)


class ReferenceTrainer(Trainer):
    """The trainer collecting through TorchRL: ``actor="lean"`` runs the actor's lean path in the
    Collector, ``actor="torchrl"`` the TorchRL actor itself."""

    def __init__(self, config: Config, actor: str = "lean", **kwargs) -> None:
        if actor not in ("lean", "torchrl"):
            raise ValueError(f"actor must be 'lean' or 'torchrl', got {actor!r}")
        self.reference_actor = actor
        super().__init__(config, **kwargs)

    def _worker_envs(self, config: Config, seeds: list[int]) -> ParallelEnv:  # type: ignore[override]
        return make_worker_envs(config, seeds)

    def _make_collector(self, lean) -> _Batches:  # type: ignore[override]
        policy = lean if self.reference_actor == "lean" else self.modules.actor
        return _Batches(Collector(self.env, policy, frames_per_batch=self.config.ppo.frames_per_batch,
                                  total_frames=-1, exploration_type=ExplorationType.RANDOM,
                                  auto_register_policy_transforms=False))

    def close(self) -> None:
        threads = torch.get_num_threads()  # shutting a ParallelEnv down raises this process's count
        if isinstance(self._collector, _Batches):
            self._collector.collector.shutdown()
        super().close()
        torch.set_num_threads(threads)
