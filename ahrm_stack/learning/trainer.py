"""The PPO trainer: one object that owns the environment, the networks, the optimiser and the reward
mechanism's adaptive state, and can save and restore all of it.

One :meth:`Trainer.iteration` is: collect ``frames_per_batch`` frames → GAE → ``epochs`` passes of
mini-batches through the clipped PPO loss (stopped early once the approximate KL passes
1.5 × ``ppo.target_kl``, when set) → update the observation normaliser → summarise the episodes
that ended in the batch.

With ``train.num_envs`` > 1 the environments are stepped together by a TorchRL ``SerialEnv`` in
this process: they share the one reward mechanism (its adaptive state sees every episode, as in
the single-environment case); each keeps its own seed stream and its own f3 phase budgets. With
``train.env_workers`` > 1 they are split over that many worker processes (an
:class:`~ahrm_stack.learning.pool.EnvPool`; environments as in :mod:`ahrm_stack.learning.workers`):
the policy still runs once per step for all of them, here, and the mechanism's state reaches the
workers at the end of each batch.

Collection runs the actor's lean path (:class:`~ahrm_stack.learning.ppo.LeanCollectionActor`:
the same keys, values and random draws as the TorchRL actor, as plain torch ops); the PPO loss
evaluates the TorchRL actor. The environments, in process or in the pool's workers, are collected
by :class:`~ahrm_stack.learning.collection.LeanCollector`: TorchRL's Collector's batches (over a
``SerialEnv``, or a ``ParallelEnv`` of the same workers), built once per batch instead of through
per-step TensorDicts. This is the one production path. TorchRL's Collector and ``ParallelEnv`` are
the oracle it is held to, in the tests (``tests/torchrl_reference.py``: a trainer whose
:meth:`Trainer._worker_envs` and :meth:`Trainer._make_collector` build them), key for key and batch
for batch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs import SerialEnv

from ahrm_stack.atomic import replacing
from ahrm_stack.config import Config, ConfigError
from ahrm_stack.env.torchrl_env import PushOffEnv, touch_penalty
from ahrm_stack.learning.diagnostics import episode_shares
from ahrm_stack.learning.demonstrations import (bc_loss, collect_corrections, collect_demonstrations,
                                                warm_start)
from ahrm_stack.learning.mechanisms import RewardMechanism
from ahrm_stack.learning import workers
from ahrm_stack.learning.collection import LeanCollector
from ahrm_stack.learning.lane_frame import MIRRORED_LANE, lane_mirror_for
from ahrm_stack.learning.lean_loss import lean_loss_for
from ahrm_stack.learning.pool import EnvPool
from ahrm_stack.learning.ppo import (anchor_coeff, lean_collection_actor, make_buffer, make_loss,
                                     make_modules, scheduled_std)
from ahrm_stack.learning.start_states import ScriptedStartStates, record_trajectories
from ahrm_stack.names import OBJECTIVE_NAMES
from ahrm_stack.seeds import training_seeds



@contextlib.contextmanager
def update_threads(threads: int) -> Iterator[int]:
    """torch's intra-op threads set to ``threads`` (at most this machine's CPU count) inside, the
    previous count restored on the way out (also on an error). Yields the count used.

    For the update (GAE and the PPO epochs): the environments wait for it, in this process or in
    the workers, so a core that steps environments during collection is free then. On this machine
    (2 vCPUs, torch 2.13 CPU) the update's values with 2 threads were bitwise those with 1 (the 3x256
    networks, profile=scratch: the policy after 5 batches identical); torch does not promise that
    for every BLAS build and size. Two runs at once with 2 update threads each collided (OpenMP's
    threads of one took the core the other stepped on: ~3x slower), hence ``train.update_threads: 1``."""
    before = torch.get_num_threads()
    used = max(1, min(int(threads), os.cpu_count() or 1))
    if used != before:
        torch.set_num_threads(used)
    try:
        yield used
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


class TrainingDiverged(RuntimeError):
    """A loss became NaN or infinite."""


class DemonstrationsFailed(RuntimeError):
    """The scripted controller succeeded in none of the demonstration episodes."""


@dataclasses.dataclass
class IterationResult:
    episodes: list[dict]
    events: list
    batch: dict


def _random_state_to_list(state: tuple) -> list:
    return [state[0], state[1].tolist(), int(state[2]), int(state[3]), float(state[4])]


def _random_state_from_list(state: list) -> tuple:
    return (state[0], np.asarray(state[1], dtype=np.uint32), state[2], state[3], state[4])


class Trainer:
    def __init__(self, config: Config, collect_demos: bool = True) -> None:
        """Build the environments (which checks what the configuration alone cannot: the layout
        on the table, the arm's joint count), the networks and the optimiser. ``collect_demos``
        false: the scripted demonstrations (slow) wait for :meth:`collect_demos`."""
        self.config = config
        torch.manual_seed(config.train.seed)
        np.random.seed(config.train.seed)
        self.mechanism = RewardMechanism(config.mechanism)
        count = config.train.num_envs  # ppo.frames_per_batch is a multiple of it (config.py)
        seeds = training_seeds(config.train.seed, count)  # configs/seeds.yaml
        self.workers = config.train.env_workers > 1
        if self.workers:  # the environments live in the worker processes
            self.envs: list[PushOffEnv] = []
            self.env = self._worker_envs(config, seeds)
        else:
            self.envs = [PushOffEnv(config.task, config.safety, mechanism=self.mechanism, seed=seed,
                                    time_limit=config.train.time_limit)
                         for seed in seeds]
            self.env = self.envs[0] if count == 1 else SerialEnv(
                count, [lambda env=env: env for env in self.envs])
        # the start curriculum (train.start_curriculum): its level rises from 0 to 1 with success
        # (worker processes get the near_cube level; config.py refuses scripted_states with them)
        self.curriculum_level = 0.0 if config.train.start_curriculum != "none" else 1.0
        self._curriculum_window: list[bool] = []
        self.start_states = None
        if config.train.start_curriculum == "scripted_states":
            self.start_states = ScriptedStartStates(
                record_trajectories(config, config.train.curriculum_states))
            for env in self.envs:
                env.task.start_states = self.start_states
        self._apply_curriculum()
        observation_dim = self.env.observation_spec["observation"].shape[-1]
        action_dim = self.env.action_spec.shape[-1]
        robot = self.envs[0].task.robot if self.envs else None  # (workers: read from the config)
        joints = {} if robot is None else {"num_joints": robot.num_joints,
                                           "num_commanded": len(robot.commanded_joints)}
        mirror = lane_mirror_for(config, observation_dim, action_dim, **joints)  # ppo.lane_frame
        swap = None
        if config.ppo.critic_privileged:  # the planner's lane per lane_directions; mirrored: +x <-> -x
            directions = list(config.task.layout.lane_directions)
            swap = [directions.index(MIRRORED_LANE.get(d, d)) for d in directions]
        self.modules = make_modules(config.ppo, observation_dim, action_dim, mirror, swap)
        self.loss, self.advantage = make_loss(config.ppo, self.modules)
        # the same loss as plain torch ops where it applies (lean_loss.py; the same parameters)
        self.compute_loss = lean_loss_for(config.ppo, self.modules) or self.loss
        # ppo.optimizer: one Adam (and one gradient clip) over all parameters, or one per network
        if config.ppo.optimizer == "separate":
            self._groups = [list(self.modules.actor.parameters()), list(self.modules.critic.parameters())]
            assert ({id(p) for g in self._groups for p in g} == {id(p) for p in self.loss.parameters()}
                    and not {id(p) for p in self._groups[0]} & {id(p) for p in self._groups[1]})
        else:
            self._groups = [list(self.loss.parameters())]
        self.optimizers = [torch.optim.Adam(group, lr=config.ppo.learning_rate) for group in self._groups]
        self.buffer = make_buffer(config.ppo)
        # per environment, the constraint_excluded flags of the episodes drained since the last
        # update, in the order each ended (mechanism.constraint_check: episode)
        self._excluded_ends: dict[int, list[bool]] = {}
        self.episodes = 0
        self.frames = 0
        self.batches = 0
        self._collector: LeanCollector | None = None
        self.warm_start_report: dict[str, float] | None = None
        self.demos = None
        self._demo_generator = torch.Generator().manual_seed(config.train.seed)
        if collect_demos:
            self.collect_demos()

    def collect_demos(self) -> None:
        """Record the scripted demonstrations when warm start or the BC anchor needs them (once).
        Raises ``RuntimeError`` with a one-line message when none of them succeeds."""
        config = self.config
        if self.demos is not None or not (config.train.warm_start == "bc" or config.ppo.bc_coeff > 0):
            return
        try:
            self.demos = collect_demonstrations(config, config.train.demo_episodes)
        except RuntimeError as error:
            raise DemonstrationsFailed(
                f"{error} in train.demo_episodes={config.train.demo_episodes} episodes of "
                f"task.episode.duration={config.task.episode.duration} s; give more or longer "
                "episodes, or train.warm_start=none ppo.bc_coeff=0") from None

    def warm_start(self) -> None:
        """Behaviour cloning and critic refit (``train.warm_start: bc``), once, before the first
        batch of a new run; nothing otherwise. :meth:`iteration` calls it when needed."""
        if self.batches or self.config.train.warm_start != "bc" or self.warm_start_report is not None:
            return
        train = self.config.train
        if self.config.ppo.reward_scale != 1.0 and self.demos is not None:  # the critic refit learns the returns PPO will see
            self.demos.set("return", self.demos.get("return") * self.config.ppo.reward_scale)
        report = warm_start(self.modules, self.demos, train.bc_epochs, train.bc_learning_rate,
                            self.config.ppo.mini_batch_size, self._demo_generator)
        first = train.demo_episodes  # DAgger rounds use the demonstration seeds after the demos'
        for round_ in range(train.dagger_rounds):
            new = collect_corrections(self.config, self.modules.actor, train.dagger_episodes, first)
            first += train.dagger_episodes
            self.demos = torch.cat([self.demos, new])  # the anchor holds the corrections too
            report = warm_start(self.modules, self.demos, train.bc_epochs, train.bc_learning_rate,
                                self.config.ppo.mini_batch_size, self._demo_generator, normalizer_data=new)
            report[f"dagger_{round_ + 1}_steps"] = float(new.shape[0])
        self.warm_start_report = report

    # ------------------------------------------------------------------ one iteration
    def _worker_envs(self, config: Config, seeds: list[int]) -> EnvPool:
        """The environments in ``train.env_workers`` processes (the tests' reference: a ParallelEnv)."""
        return EnvPool(config, seeds)

    def _make_collector(self, lean):
        """The batches' collector: :class:`LeanCollector` with the actor's lean path (the tests'
        reference: TorchRL's Collector); anything with ``next()`` returning a batch."""
        return LeanCollector(self.env if self.workers else self.envs, lean, self.config.ppo.frames_per_batch)

    def _collect(self):
        if self._collector is None:
            if self.workers:
                self.env.load_mechanism(self.mechanism.state_dict())
            lean = lean_collection_actor(self.modules.actor)
            if lean is None:
                raise RuntimeError("training collects with the actor's lean path (make_modules builds it): "
                                   "this actor has none")
            self._collector = self._make_collector(lean)
        return self._collector.next()

    def _set_touch_end(self) -> None:
        """``train.touch_end``: the in-process environments end episodes on a touch, with
        :func:`touch_penalty`, once ``train.touch_end_after`` frames are collected (a whole batch
        either way; worker processes are built with it, or get it before each batch when delayed);
        likewise ``task.rewards.touch_cost`` from ``train.touch_cost_after`` frames."""
        train = self.config.train
        penalty = touch_penalty(train.touch_end and self.frames >= train.touch_end_after, self.config.ppo.gamma)
        for env in self.envs:
            env.touch_penalty = penalty
        if self.workers and train.touch_end_after > 0:  # (otherwise they were built with it)
            self.env.set_touch_penalty(penalty)
        if train.touch_cost_after > 0:  # task.rewards.touch_cost, charged from touch_cost_after frames
            cost = self.config.task.rewards.touch_cost if self.frames >= train.touch_cost_after else 0.0
            for env in self.envs:
                env.touch_cost = cost
            if self.workers:
                self.env.set_touch_cost(cost)

    def iteration(self) -> IterationResult:
        started = time.perf_counter()
        ppo = self.config.ppo
        self.warm_start()
        if ppo.std_mode == "scheduled":
            self.modules.head.set_std(scheduled_std(ppo, self.frames))
        self._set_touch_end()
        data = self._collect()
        self.frames += data.numel()
        self.batches += 1
        if ppo.reward_scale != 1.0:
            data.set(("next", "reward"), data.get(("next", "reward")) * ppo.reward_scale)
        # the episodes that ended in this batch (the update does not read them: drained first so
        # that mechanism.constraint_check: episode can leave the violating ones out of it)
        episodes, events = self._drain_episodes()
        with update_threads(self.config.train.update_threads):
            totals, grad_norms, updates = self._update(data, self._learned_steps(data))
        if ppo.update_normalizer or self.modules.normalizer.count == 0:
            self.modules.normalizer.update(self.modules.framed(data["observation"]))
        self._update_curriculum(episodes)
        batch = {k: float(np.mean(v)) for k, v in totals.items()}
        batch.update(episode_shares(episodes))
        batch.update(batch=self.batches, frames=self.frames, episodes=self.episodes,
                     std=float(self._std().detach()), updates=updates,
                     grad_norm=float(np.mean(grad_norms)) if grad_norms else float("nan"),
                     curriculum_level=self.curriculum_level,
                     seconds=time.perf_counter() - started)
        return IterationResult(episodes, events, batch)

    def _learned_steps(self, data: TensorDict) -> torch.Tensor | None:
        """``mechanism.constraint_check: episode``: a (N, T) mask of the batch's steps to learn from,
        False on the steps of each episode that ended in this batch with the priority constraint
        violated (the paper's "restart episode" without an update; steps of it collected in an
        earlier batch were learned from then). None (learn from all) otherwise."""
        excluded = self._excluded_ends
        self._excluded_ends = {}
        if self.config.mechanism.constraint_check != "episode":
            return None
        done = data.get(("next", "done")).reshape(self.config.train.num_envs, -1).numpy()
        keep = np.ones(done.shape, dtype=bool)
        for i in range(done.shape[0]):
            ends = np.flatnonzero(done[i])
            flags = excluded.get(i, [])
            if len(flags) != len(ends):
                raise RuntimeError(f"environment {i}: {len(ends)} episode ends in the batch, "
                                   f"{len(flags)} episodes drained")
            start = 0
            for end, flag in zip(ends, flags):
                if flag:
                    keep[i, start:end + 1] = False
                start = end + 1
        return torch.as_tensor(keep).reshape(data.shape)

    def _update(self, data: TensorDict, keep: torch.Tensor | None = None
                ) -> tuple[dict[str, list[float]], list[float], int]:
        """GAE on the collected ``data``, then the PPO epochs (with the BC anchor) on its steps
        where ``keep`` (N, T) is True (all without it): the mini-batches' loss terms, their
        gradient norms, and the number of optimiser steps."""
        ppo = self.config.ppo
        with torch.no_grad():
            self.advantage(data)
        self.buffer.empty()
        learned = data.reshape(-1) if keep is None else data[keep]
        steps = learned.batch_size.numel()  # (TensorDict's numel() is 1, not 0, when it is empty)
        if steps:
            self.buffer.extend(learned)
        totals: dict[str, list[float]] = {}
        grad_norms = []
        updates = 0
        kl_stopped = False
        for _ in range(ppo.epochs):
            if kl_stopped:
                break
            for _ in range(steps // ppo.mini_batch_size):
                batch = self.buffer.sample()
                losses = self.compute_loss(batch)
                if ppo.target_kl > 0 and float(losses["kl_approx"]) > 1.5 * ppo.target_kl:
                    kl_stopped = True  # this mini-batch already moved too far: no step
                    break
                loss = losses["loss_objective"] + losses["loss_critic"] + losses.get("loss_entropy", 0.0)
                coeff = anchor_coeff(ppo, self.frames)
                if coeff > 0 and self.demos is not None:  # the anchor toward the demonstrations
                    index = torch.randint(self.demos.shape[0], (ppo.mini_batch_size,),
                                          generator=self._demo_generator)
                    anchor = bc_loss(self.modules.actor, self.demos[index])
                    loss = loss + coeff * anchor
                    totals.setdefault("bc_loss", []).append(float(anchor.detach()))
                if not torch.isfinite(loss):
                    raise TrainingDiverged(
                        f"non-finite loss at batch {self.batches} (objective "
                        f"{float(losses['loss_objective'].detach()):.4g}, critic {float(losses['loss_critic'].detach()):.4g})")
                for optimizer in self.optimizers:
                    optimizer.zero_grad()
                loss.backward()
                norms = [float(torch.nn.utils.clip_grad_norm_(group, ppo.max_grad_norm)) for group in self._groups]
                grad_norms.append(norms[0] if len(norms) == 1 else float(np.sqrt(np.sum(np.square(norms)))))
                for optimizer in self.optimizers:
                    optimizer.step()
                updates += 1
                for key in ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx"):
                    if key in losses.keys():
                        totals.setdefault(key, []).append(float(losses[key].detach()))
        return totals, grad_norms, updates

    def finished(self) -> bool:
        """Whether the budget is spent: ``train.frames`` frames when set, else ``train.episodes``."""
        train = self.config.train
        return self.frames >= train.frames if train.frames else self.episodes >= train.episodes

    def _apply_curriculum(self) -> None:
        """The level reaches the environments: near_cube starts a share 1 - level of episodes near
        the cube; scripted_states starts at the fraction 1 - level of a recorded trajectory."""
        if self.config.train.start_curriculum == "near_cube":
            for env in self.envs:
                env.task.near_cube_share = 1.0 - self.curriculum_level
            if self.workers:  # before the next batch, as in process
                self.env.set_near_cube_share(1.0 - self.curriculum_level)
        elif self.start_states is not None:
            self.start_states.level = self.curriculum_level

    def _update_curriculum(self, rows: list[dict]) -> None:
        """Raise the level by ``train.curriculum_step`` each time the training success rate over
        ``train.curriculum_window`` episodes reaches ``train.curriculum_threshold``."""
        train = self.config.train
        if train.start_curriculum == "none" or self.curriculum_level >= 1.0:
            return
        for row in rows:
            self._curriculum_window.append(bool(row["success"]))
            if len(self._curriculum_window) >= train.curriculum_window:
                raised = np.mean(self._curriculum_window) >= train.curriculum_threshold
                self._curriculum_window = []
                if raised:  # the batch's later episodes started at the old level: not counted
                    self.curriculum_level = min(1.0, self.curriculum_level + train.curriculum_step)
                    self._apply_curriculum()
                    return

    def _std(self) -> torch.Tensor:
        return self.modules.head.log_std.exp().mean()

    def _completed(self) -> list:
        """The episodes completed since the last call, in this process or the workers' (whose
        ends are applied to the mechanism here, in the order they ended, and the new state sent)."""
        if not self.workers:  # in the order they ended (the order the mechanism saw them)
            for i, env in enumerate(self.envs):
                self._excluded_ends.setdefault(i, []).extend(s.constraint_excluded for s in env.completed)
            summaries = sorted((summary for env in self.envs for summary in env.completed),
                               key=lambda summary: -1 if summary.end_order is None else summary.end_order)
            for env in self.envs:
                env.completed.clear()
            return summaries
        summaries = []
        for pending in workers.drain(self.env):
            pending.summary.events = self.mechanism.end_episode(
                pending.f, pending.phase, constraint_terminated=pending.constraint_terminated,
                terminated_phase=pending.terminated_phase, constraint_excluded=pending.constraint_excluded)
            self._excluded_ends.setdefault(pending.index, []).append(pending.constraint_excluded)
            summaries.append(pending.summary)
        self.env.load_mechanism(self.mechanism.state_dict())
        return summaries

    def _drain_episodes(self) -> tuple[list[dict], list]:
        rows, events = [], []
        for summary in self._completed():
            self.episodes += 1
            for event in summary.events:
                event.episode = self.episodes
            events += summary.events
            row = dataclasses.asdict(summary)
            row.pop("events")
            row.pop("end_order")
            row.update(episode=self.episodes, frames=self.frames, failure_mode=summary.failure_mode(),
                       orders=self.mechanism_orders(), levels=list(self.mechanism.levels))
            rows.append(row)
        return rows, events

    def mechanism_orders(self) -> str:
        short = {name: name[0].upper() for name in OBJECTIVE_NAMES}
        return " ".join("".join(short[OBJECTIVE_NAMES[i]] for i in order) for order in self.mechanism.orders)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {
            "actor": self.modules.actor.state_dict(),
            "critic": self.modules.critic.state_dict(),
            "optimizer": (self.optimizers[0].state_dict() if len(self.optimizers) == 1
                          else [optimizer.state_dict() for optimizer in self.optimizers]),
            "mechanism": self.mechanism.state_dict(),
            "time_objective": [budget for _, budget, _ in self._env_states()],
            "counters": {"episodes": self.episodes, "frames": self.frames, "batches": self.batches},
            "curriculum": {"level": self.curriculum_level, "window": list(self._curriculum_window)},
            "torch_rng": torch.get_rng_state(),
            "env_rng": [_random_state_to_list(rng) for _, _, rng in self._env_states()],
            # the anchor's data: with DAgger it holds the corrections, which a resume cannot redo
            "demos": None if self.demos is None else {k: v for k, v in self.demos.items()},
        }

    def _env_states(self) -> list[tuple[int, dict, Any]]:
        """(index, f3's phase budgets, random state) of every environment, in index order."""
        if self.workers:
            return sorted(workers.per_environment(self.env, "worker_state"), key=lambda s: s[0])
        return [(i, env.task.time_objective.state_dict(), env.runner.random_state.get_state())
                for i, env in enumerate(self.envs)]

    def load_state_dict(self, state: dict) -> None:
        self.modules.actor.load_state_dict(state["actor"])
        self.modules.critic.load_state_dict(state["critic"])
        saved = state["optimizer"]
        saved = saved if isinstance(saved, list) else [saved]
        if len(saved) != len(self.optimizers):
            raise ValueError(f"the checkpoint has {len(saved)} optimiser state(s), ppo.optimizer: "
                             f"{self.config.ppo.optimizer} needs {len(self.optimizers)}")
        for optimizer, optimizer_state in zip(self.optimizers, saved):
            optimizer.load_state_dict(optimizer_state)
        self.mechanism.load_state_dict(state["mechanism"])
        budgets, rngs = state["time_objective"], state["env_rng"]
        if isinstance(budgets, dict):  # checkpoints of single-environment runs before num_envs
            budgets, rngs = [budgets], [rngs]
        if len(budgets) != self.config.train.num_envs:
            raise ConfigError(f"the checkpoint has {len(budgets)} environments, train.num_envs is "
                              f"{self.config.train.num_envs}")
        if self.workers:
            self.env.load_worker_state(budgets, [_random_state_from_list(rng) for rng in rngs])
        for env, budget, rng in zip(self.envs, budgets, rngs):
            env.task.time_objective.load_state_dict(budget)
            env.runner.random_state.set_state(_random_state_from_list(rng))
        counters = state["counters"]
        self.episodes, self.frames, self.batches = (counters["episodes"], counters["frames"],
                                                    counters["batches"])
        torch.set_rng_state(state["torch_rng"])
        curriculum = state.get("curriculum")  # absent in checkpoints before the start curriculum
        if curriculum is not None:
            self.curriculum_level = float(curriculum["level"])
            self._curriculum_window = [bool(s) for s in curriculum["window"]]
            self._apply_curriculum()
        if state.get("demos") is not None:
            saved = state["demos"]
            self.demos = TensorDict(saved, batch_size=[saved["observation"].shape[0]])

    def save_policy(self, path: Path) -> None:
        """The final policy: actor weights (normaliser included) and what is needed to rebuild it."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with replacing(path) as tmp:  # written whole, then renamed: never torn
            torch.save({"actor": self.modules.actor.state_dict(),
                        "observation_dim": int(self.env.observation_spec["observation"].shape[-1]),
                        "action_dim": int(self.env.action_spec.shape[-1]),
                        "episodes": self.episodes, "frames": self.frames}, tmp)

    def close(self) -> None:
        threads = torch.get_num_threads()  # closing worker processes may change this process's count
        if self.workers and not self.env.is_closed:
            self.env.close()
        torch.set_num_threads(threads)
