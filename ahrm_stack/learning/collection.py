"""Training's batched collection in one process: N environments, one policy call per step.

:class:`LeanCollector` gives, batch after batch, the TensorDict a TorchRL ``Collector`` gives for
the same environments (a ``SerialEnv`` of them, or the one environment) and the same
:class:`~ahrm_stack.learning.ppo.LeanCollectionActor` under ``ExplorationType.RANDOM``: the same
keys, shapes, dtypes and values, the same random draws, the same episode ends in the same order
(``tests/test_collection.py`` holds it to the Collector key for key). What it leaves out is the
per-step work around the environments: each step it stacks the N observations into one tensor,
calls the actor once, steps the environments in index order through
:meth:`PushOffEnv.advance <ahrm_stack.env.torchrl_env.PushOffEnv.advance>` and writes the values
into preallocated arrays; the TensorDict is built once per batch. Semantics kept from
``step_and_maybe_reset``: all environments step, then those that ended are reset in index order;
the "next" entry of an ended step holds its last observation, the next step's root the reset's.
Trajectory ids: environment i starts with id i; a reset takes the next unused id.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict

from ahrm_stack.env.task import StepInfo
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.ppo import LeanCollectionActor

# the per-step entries of the environment (root and "next")
_STEP_KEYS = ("observation", "f", "g", "phase", "x", "distances", "success", "touched")


class LeanCollector:
    """Collects ``frames_per_batch`` frames per :meth:`next` from in-process environments."""

    def __init__(self, envs: list[PushOffEnv], actor: LeanCollectionActor, frames_per_batch: int) -> None:
        if not envs or frames_per_batch % len(envs):
            raise ValueError(f"frames_per_batch={frames_per_batch} is not a multiple of {len(envs)} environments")
        self.envs, self.actor = envs, actor
        self.steps = frames_per_batch // len(envs)
        self.batched = len(envs) > 1  # one environment: batch [T], as the Collector gives it
        self._current: list[dict] | None = None  # each environment's current step values
        self._traj = np.arange(len(envs), dtype=np.int64)
        self._next_traj = len(envs)
        first = envs[0]
        self._widths = {key: int(np.prod(spec.shape)) for key, spec in first.observation_spec.items()}
        self._dtypes = {key: spec.dtype for key, spec in first.observation_spec.items()}

    @staticmethod
    def _values(env: PushOffEnv, info: StepInfo) -> dict[str, np.ndarray | float | bool | int]:
        return {"observation": env.runner.flat_observation(), "f": info.f, "g": info.g, "phase": info.phase,
                "x": info.x, "distances": info.distances, "success": info.success, "touched": info.touched}

    def _buffers(self, n: int, t: int) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for key in _STEP_KEYS:
            dtype = {torch.float32: np.float32, torch.int64: np.int64, torch.bool: np.bool_}[self._dtypes[key]]
            out[key] = np.empty((n, t, self._widths[key]), dtype=dtype)
        return out

    def next(self) -> TensorDict:
        """The next batch: shape [N, T] (N environments, T = frames_per_batch / N), or [T] with one
        environment."""
        envs, n, t = self.envs, len(self.envs), self.steps
        if self._current is None:  # the first batch: every environment starts an episode
            self._current = [self._values(env, env.begin()) for env in envs]
        root, nxt = self._buffers(n, t), self._buffers(n, t)
        reward = np.empty((n, t, 1), dtype=np.float32)
        terminated = np.zeros((n, t, 1), dtype=bool)
        truncated = np.zeros((n, t, 1), dtype=bool)
        root_done = np.zeros((n, t, 1), dtype=bool)  # a reset's done flags are False
        traj = np.empty((n, t), dtype=np.int64)
        actor_out: dict[str, list[torch.Tensor]] = {key: [] for key in self.actor.out_keys}
        current = self._current
        for step in range(t):
            for i, values in enumerate(current):
                for key in _STEP_KEYS:
                    root[key][i, step] = values[key]
            traj[:, step] = self._traj
            observation = torch.from_numpy(root["observation"][:, step].copy())  # (N, obs_dim)
            # one environment: the Collector calls the actor on one (obs_dim,) observation
            if self.batched:
                sampled = self.actor.sample(observation)
            else:
                sampled = tuple(v.unsqueeze(0) for v in self.actor.sample(observation[0]))
            for key, value in zip(actor_out, sampled):
                actor_out[key].append(value)
            actions = sampled[3].numpy()
            ended = []
            for i, env in enumerate(envs):
                info, r, term, trunc = env.advance(actions[i])
                values = self._values(env, info)
                for key in _STEP_KEYS:
                    nxt[key][i, step] = values[key]
                reward[i, step, 0] = r
                terminated[i, step, 0], truncated[i, step, 0] = term, trunc
                current[i] = values
                if term or trunc:
                    ended.append(i)
            for i in ended:  # step_and_maybe_reset: the ended environments reset, in index order
                current[i] = self._values(envs[i], envs[i].begin())
                self._traj[i] = self._next_traj
                self._next_traj += 1
        done = terminated | truncated
        batch: dict[str, torch.Tensor | dict[str, torch.Tensor]] = {
            key: torch.from_numpy(value) for key, value in root.items()}
        batch.update(done=torch.from_numpy(root_done), terminated=torch.from_numpy(root_done.copy()),
                     truncated=torch.from_numpy(root_done.copy()))
        for key, sampled_values in actor_out.items():
            batch[key] = torch.stack(sampled_values, dim=1)  # (N, T, ...)
        batch["next"] = {**{key: torch.from_numpy(value) for key, value in nxt.items()},
                         "reward": torch.from_numpy(reward), "done": torch.from_numpy(done),
                         "terminated": torch.from_numpy(terminated), "truncated": torch.from_numpy(truncated)}
        batch["collector"] = {"traj_ids": torch.from_numpy(traj)}
        data = TensorDict(batch, batch_size=[n, t])
        return data if self.batched else data[0]
