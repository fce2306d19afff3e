"""Training's batched collection: N environments, one policy call per step.

:class:`LeanCollector` gives, batch after batch, the TensorDict a TorchRL ``Collector`` gives for
the same environments (a ``SerialEnv`` of them, the one environment, or a ``ParallelEnv`` of worker
processes) and the same :class:`~ahrm_stack.learning.ppo.LeanCollectionActor` under
``ExplorationType.RANDOM``: the same keys, shapes, dtypes and values, the same random draws, the
same episode ends in the same order (``tests/test_collection.py`` holds it to the Collector key for
key). What it leaves out is the per-step work around the environments: each step it calls the actor
once on the N stacked observations, hands the N actions to a *stepper* and writes what comes back
into preallocated arrays; the TensorDict is built once per batch.

Steppers: :class:`LocalEnvs` steps in-process environments in index order through
:meth:`PushOffEnv.advance <ahrm_stack.env.torchrl_env.PushOffEnv.advance>`;
:class:`~ahrm_stack.learning.pool.EnvPool` (``train.env_workers`` > 1) sends each worker process its
share of the actions, and each worker runs a :class:`LocalEnvs` of its environments. Semantics kept
from ``step_and_maybe_reset``: all environments step, then those that ended are reset in index
order; the "next" entry of an ended step holds its last observation, the next step's root the
reset's. Trajectory ids: environment i starts with id i; a reset takes the next unused id.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch
from tensordict import TensorDict

from ahrm_stack.env.task import StepInfo
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.ppo import LeanCollectionActor

# the per-step entries of the environment (root and "next")
STEP_KEYS = ("observation", "f", "g", "phase", "x", "distances", "success", "touched", "privileged")
NUMPY_DTYPES = {torch.float32: np.float32, torch.int64: np.int64, torch.bool: np.bool_}

Values = dict[str, np.ndarray]
"""One array per key of :data:`STEP_KEYS`, a row per environment: shape (n, width), the dtype of
the environment's observation spec."""

StepOutput = tuple[Values, np.ndarray, np.ndarray, np.ndarray, Values]
"""What a stepper's ``step`` returns: the step's values (the "next" entries), reward (n,) float32,
terminated (n,) bool, truncated (n,) bool, and the reset's values of the environments that ended,
one row each in index order (zero rows when none ended)."""


class Stepper(Protocol):
    """N environments stepped together (see :class:`LocalEnvs`)."""

    count: int
    widths: dict[str, int]
    dtypes: dict[str, type]

    def begin(self) -> Values: ...

    def step(self, actions: np.ndarray) -> StepOutput: ...


def empty_values(widths: dict[str, int], dtypes: dict[str, type], *lead: int) -> Values:
    """Uninitialised arrays for :data:`STEP_KEYS`: shape ``(*lead, width)`` each, in its dtype."""
    return {key: np.empty((*lead, widths[key]), dtype=dtypes[key]) for key in STEP_KEYS}


def spec_layout(env: PushOffEnv) -> tuple[dict[str, int], dict[str, type]]:
    """Width and numpy dtype of each key of :data:`STEP_KEYS` in ``env``'s observation spec."""
    spec = env.observation_spec
    return ({key: int(np.prod(spec[key].shape)) for key in STEP_KEYS},
            {key: NUMPY_DTYPES[spec[key].dtype] for key in STEP_KEYS})


class LocalEnvs:
    """In-process environments, stepped in index order (a worker process runs one of these for its
    share). Writes each value into arrays of the spec's dtypes, as the Collector's TensorDicts hold
    them."""

    def __init__(self, envs: list[PushOffEnv]) -> None:
        if not envs:
            raise ValueError("no environments")
        self.envs = envs
        self.count = len(envs)
        self.widths, self.dtypes = spec_layout(envs[0])

    def values(self, rows: int) -> Values:
        return empty_values(self.widths, self.dtypes, rows)

    @staticmethod
    def _write(out: Values, row: int, env: PushOffEnv, info: StepInfo) -> None:
        out["observation"][row] = env.runner.flat_observation()
        out["f"][row], out["g"][row], out["phase"][row] = info.f, info.g, info.phase
        out["x"][row], out["distances"][row] = info.x, info.distances
        out["success"][row], out["touched"][row] = info.success, info.touched
        out["privileged"][row] = env.privileged

    def begin(self) -> Values:
        """Every environment starts an episode: its first values."""
        out = self.values(self.count)
        for i, env in enumerate(self.envs):
            self._write(out, i, env, env.begin())
        return out

    def step(self, actions: np.ndarray) -> StepOutput:
        """Environment i takes ``actions[i]`` (normalised); then the ended ones reset, in index order."""
        out = self.values(self.count)
        reward = np.empty(self.count, dtype=np.float32)
        terminated = np.empty(self.count, dtype=bool)
        truncated = np.empty(self.count, dtype=bool)
        for i, env in enumerate(self.envs):
            info, reward[i], terminated[i], truncated[i] = env.advance(actions[i])
            self._write(out, i, env, info)
        ended = np.flatnonzero(terminated | truncated).tolist()
        resets = self.values(len(ended))
        for row, i in enumerate(ended):
            self._write(resets, row, self.envs[i], self.envs[i].begin())
        return out, reward, terminated, truncated, resets


class LeanCollector:
    """Collects ``frames_per_batch`` frames per :meth:`next` from ``envs`` (in-process environments,
    or a stepper such as :class:`~ahrm_stack.learning.pool.EnvPool`) with ``actor``: its
    ``sample(observations)`` returns one tensor per entry of its ``out_keys``, one of them
    ``"action"`` (see :class:`RandomActor`)."""

    def __init__(self, envs: list[PushOffEnv] | Stepper, actor: LeanCollectionActor, frames_per_batch: int) -> None:
        self.stepper: Stepper = LocalEnvs(envs) if isinstance(envs, list) else envs
        n = self.stepper.count
        if frames_per_batch % n:
            raise ValueError(f"frames_per_batch={frames_per_batch} is not a multiple of {n} environments")
        self.actor = actor
        self._action = list(actor.out_keys).index("action")  # which of sample()'s outputs is the action
        self.steps = frames_per_batch // n
        self.batched = n > 1  # one environment: batch [T], as the Collector gives it
        self._current: Values | None = None  # each environment's current step values
        self._traj = np.arange(n, dtype=np.int64)
        self._next_traj = n

    def _buffers(self, n: int, t: int) -> Values:
        return empty_values(self.stepper.widths, self.stepper.dtypes, n, t)

    def next(self) -> TensorDict:
        """The next batch: shape [N, T] (N environments, T = frames_per_batch / N), or [T] with one
        environment."""
        stepper, n, t = self.stepper, self.stepper.count, self.steps
        if self._current is None:  # the first batch: every environment starts an episode
            self._current = stepper.begin()
        root, nxt = self._buffers(n, t), self._buffers(n, t)
        reward = np.empty((n, t, 1), dtype=np.float32)
        terminated = np.zeros((n, t, 1), dtype=bool)
        truncated = np.zeros((n, t, 1), dtype=bool)
        root_done = np.zeros((n, t, 1), dtype=bool)  # a reset's done flags are False
        traj = np.empty((n, t), dtype=np.int64)
        actor_out: dict[str, list[torch.Tensor]] = {key: [] for key in self.actor.out_keys}
        current = self._current
        for step in range(t):
            for key in STEP_KEYS:
                root[key][:, step] = current[key]
            traj[:, step] = self._traj
            observation = torch.from_numpy(root["observation"][:, step].copy())  # (N, obs_dim)
            # one environment: the Collector calls the actor on one (obs_dim,) observation
            if self.batched:
                sampled = self.actor.sample(observation)
            else:
                sampled = tuple(v.unsqueeze(0) for v in self.actor.sample(observation[0]))
            for key, value in zip(actor_out, sampled):
                actor_out[key].append(value)
            values, r, term, trunc, resets = stepper.step(sampled[self._action].numpy())
            for key in STEP_KEYS:
                nxt[key][:, step] = values[key]
            reward[:, step, 0], terminated[:, step, 0], truncated[:, step, 0] = r, term, trunc
            ended = np.flatnonzero(term | trunc)
            if len(ended):  # step_and_maybe_reset: the ended environments reset, in index order
                for key in STEP_KEYS:
                    values[key][ended] = resets[key]
                self._traj[ended] = np.arange(self._next_traj, self._next_traj + len(ended))
                self._next_traj += len(ended)
            current = values
        self._current = current
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


class RandomActor:
    """Random actions in [-1, 1] for :class:`LeanCollector` (env-only collection in the benchmarks),
    drawn from torch's global random stream; ``sample`` returns the action alone. ``std`` None:
    uniform; else tanh of a zero-mean normal with that standard deviation (pre-tanh), the noise of a
    policy that starts at ``ppo.init_std`` with a centred mean."""

    out_keys = ["action"]

    def __init__(self, action_dim: int, std: float | None = None) -> None:
        self.action_dim, self.std = action_dim, std

    def sample(self, observation: torch.Tensor) -> tuple[torch.Tensor]:
        shape = (*observation.shape[:-1], self.action_dim)
        if self.std is None:
            return (torch.rand(*shape) * 2.0 - 1.0,)
        return (torch.tanh(torch.randn(*shape) * self.std),)
