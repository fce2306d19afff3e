"""TorchRL ``EnvBase`` around the push-off task.

Keys (all float32 unless noted):

* ``observation`` — the flat observation of spec §1 (layout: :attr:`PushOffTask.observation_order`);
* ``action`` — ``action.mode: joint``: normalised joint velocities of the commanded joints, in
  [-1, 1]; ``cartesian``: the pusher tip's linear velocity normalised by
  ``action.cartesian_max_speed``. Either way the safety filter makes the joint command
  (:mod:`ahrm_stack.env.control_step` maps the action to the filter's request);
* ``reward`` — the reward mechanism's scalar (without one: the linear sum of g);
* ``f`` / ``g`` — the component vectors (avoid, manipulate, time): +-1 form and penalty form;
* ``phase`` (int64, 1..3), ``x`` (boundary distance, m), ``distances`` (signed distances of the
  pusher to B_obstacles and B_target, m), ``success`` and ``touched`` (bool);
* ``done`` / ``terminated`` (success; in training with ``touch_penalty``, also a touch) /
  ``truncated`` (time limit, priority constraint).

torchrl's ``DMControlWrapper`` cannot wrap composer tasks, hence this class.
"""

from __future__ import annotations

import itertools

import numpy as np

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from ahrm_stack.config import SafetyConfig, TaskConfig
from ahrm_stack.env.control_step import action_to_command, check_action_shape  # noqa: F401 (re-exported)
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.lane_agreement import taken_lane
from ahrm_stack.env.episode import EpisodeRecorder, EpisodeSummary
from ahrm_stack.env.rewards import staged_push_reward
from ahrm_stack.names import NUM_OBJECTIVES
from ahrm_stack.env.task import PushOffTask, StepInfo

_END_ORDER = itertools.count()  # episodes ended in this process, in order (EpisodeSummary.end_order)


def touch_penalty(touch_end: bool, gamma: float, objectives: int = NUM_OBJECTIVES) -> float:
    """The reward lost by a touch that ends a training episode (``train.touch_end``):
    ``objectives / (1 - gamma)``, the discounted value of every objective's penalty (-1 each per
    step) forever. No continuation is worth less, so ending an episode by a touch is never an
    escape from the penalties still to come. 0 when ``touch_end`` is false."""
    return objectives / (1.0 - gamma) if touch_end else 0.0


class PushOffEnv(EnvBase):
    """One push-off task as a TorchRL environment (batch size ``[]``, CPU).

    With a ``mechanism`` (an object with ``reward(g, distances)``, ``constraint_monitor()`` and
    ``end_episode(f, phase, ...)``, see :mod:`ahrm_stack.learning.mechanisms`), the reward is the
    mechanism's, the priority constraint can end an episode early (as a truncation), and every
    completed episode updates the mechanism. Completed episodes are summarised in
    :attr:`completed` (the trainer drains it).
    """

    def __init__(self, config: TaskConfig, safety: SafetyConfig | None, seed: int | None = None,
                 device: str = "cpu", mechanism=None, time_limit: float = 0.0,
                 touch_penalty: float = 0.0) -> None:
        """``time_limit`` (s, > 0): episodes are truncated here instead of at
        ``task.episode.duration`` (training's ``train.time_limit``). ``touch_penalty`` (> 0;
        training's ``train.touch_end``, :func:`touch_penalty`): a step that touches an obstacle
        ends the episode as a terminal state and its reward is lowered by this much (the
        learner's reward units, before ``ppo.reward_scale``)."""
        if touch_penalty < 0:
            raise ValueError(f"touch_penalty must be >= 0, got {touch_penalty}")
        super().__init__(device=device, batch_size=torch.Size([]))
        self.mechanism = mechanism
        self.completed: list[EpisodeSummary] = []
        self._monitor = None
        self._touch_charged = False
        self.touch_penalty = float(touch_penalty)
        # task.rewards.touch_cost, charged once per episode (the trainer sets 0 until
        # train.touch_cost_after frames)
        self.touch_cost = float(config.rewards.touch_cost)
        self.touched_success_cost = float(config.rewards.touched_success_cost)
        self._touched = False  # an obstacle touched in this episode (task.rewards.touched_success_cost)
        self.task = PushOffTask(config)
        self.runner = TaskRunner(self.task, seed, safety)
        if time_limit > 0:
            self.runner.max_steps = max(1, int(round(time_limit / config.episode.control_period)))
        self.robot = self.task.robot
        action_dim = self.runner.control.action_size
        self.runner.reset()
        self.privileged = np.zeros(len(config.layout.lane_directions), dtype=np.float32)
        obs_dim = self.runner.flat_observation().shape[0]
        self.observation_spec = Composite(
            observation=Unbounded(shape=(obs_dim,), dtype=torch.float32),
            f=Bounded(low=-1.0, high=1.0, shape=(3,), dtype=torch.float32),
            g=Bounded(low=-1.0, high=0.0, shape=(3,), dtype=torch.float32),
            phase=Bounded(low=1, high=3, shape=(1,), dtype=torch.int64),
            x=Unbounded(shape=(1,), dtype=torch.float32),
            distances=Unbounded(shape=(2,), dtype=torch.float32),
            success=Binary(n=1, shape=(1,), dtype=torch.bool),
            touched=Binary(n=1, shape=(1,), dtype=torch.bool),
            # the critic's privileged input (ppo.critic_privileged): the planner's lane, one-hot
            privileged=Unbounded(shape=(len(config.layout.lane_directions),), dtype=torch.float32),
        )
        self.action_spec = Bounded(low=-1.0, high=1.0, shape=(action_dim,), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32)
        self.full_done_spec = Composite(
            done=Binary(n=1, shape=(1,), dtype=torch.bool),
            terminated=Binary(n=1, shape=(1,), dtype=torch.bool),
            truncated=Binary(n=1, shape=(1,), dtype=torch.bool))
        if seed is not None:
            self.set_seed(seed)

    def _observation(self, info: StepInfo) -> dict[str, torch.Tensor]:
        return {
            "observation": torch.as_tensor(self.runner.flat_observation(), dtype=torch.float32),
            "f": torch.as_tensor(info.f, dtype=torch.float32),
            "g": torch.as_tensor(info.g, dtype=torch.float32),
            "phase": torch.tensor([info.phase], dtype=torch.int64),
            "x": torch.tensor([info.x], dtype=torch.float32),
            "distances": torch.as_tensor(info.distances, dtype=torch.float32),
            "success": torch.tensor([info.success]),
            "touched": torch.tensor([info.touched]),
            "privileged": torch.as_tensor(self.privileged),
        }

    def begin(self) -> StepInfo:
        """Start a new episode (the reset's work, without the TensorDict): its first step info."""
        transition = self.runner.reset()
        self._monitor = self.mechanism.constraint_monitor() if self.mechanism is not None else None
        self._recorder = EpisodeRecorder(transition.info)
        self._touch_charged = False  # task.rewards.touch_cost charged in this episode
        self._touched = False
        physics = self.runner.physics  # the planner's lane at the start (reading only): lane agreement
        directions = self.task.config.layout.lane_directions
        self._planned = directions[self.task.plan_lane(physics)]
        # what only the critic may read (ppo.critic_privileged; never the policy): the planner's lane
        self.privileged = np.array([float(d == self._planned) for d in directions], dtype=np.float32)
        self._cube_start = self.task.cube_xy(physics).tolist()
        return transition.info

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        out = self._observation(self.begin())
        out.update(done=torch.tensor([False]), terminated=torch.tensor([False]),
                   truncated=torch.tensor([False]))
        return TensorDict(out, batch_size=[])

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        info, reward, terminated, truncated = self.advance(tensordict["action"].detach().cpu().numpy())
        out = self._observation(info)
        out.update(reward=torch.tensor([reward], dtype=torch.float32),
                   done=torch.tensor([terminated or truncated]),
                   terminated=torch.tensor([terminated]), truncated=torch.tensor([truncated]))
        return TensorDict(out, batch_size=[])

    def advance(self, action) -> tuple[StepInfo, float, bool, bool]:
        """One step's work without the TensorDict: the action (normalised, numpy) through the task,
        the reward, the priority constraint, the episode's bookkeeping. Returns (step info,
        reward, terminated, truncated); an ended episode is summarised in :attr:`completed`."""
        info, terminated, truncated = self.runner.step_action(action)
        if self.mechanism is None:
            reward = float(info.g.sum())
        else:
            reward = float(self.mechanism.reward(info.g, info.distances))
        rewards = self.task.config.rewards
        if rewards.learning == "staged":  # the oracle control (the mechanism above still runs and logs)
            staged = rewards.staged
            reward = staged_push_reward(info.tip, info.target, 1.0 if self._planned == "+x" else -1.0,
                                        self.task.config.cube.size / 2, self.task.config.table.half_extent[0],
                                        info.touched, info.success, staged.tanh_scale, staged.push_offset,
                                        staged.reached_distance)
        if info.touched and not self._touch_charged:  # task.rewards.touch_cost: once per episode
            self._touch_charged = True
            reward -= self.touch_cost
        self._touched = self._touched or bool(info.touched)
        if info.success and self._touched:  # task.rewards.touched_success_cost: a touched success priced
            reward -= self.touched_success_cost
        if self.touch_penalty > 0 and info.touched and not terminated:
            reward -= self.touch_penalty
            if not truncated:  # a step that hit the time limit has closed the episode already
                self.runner.end_episode()
            terminated, truncated = True, False
        constrained = (self._monitor is not None and not terminated
                       and self._monitor.step(info.f, info.phase))
        if constrained and not truncated:
            truncated = True
            self.runner.end_episode()
        filtered = self.runner.last_filter_result
        self._recorder.step(info, reward, intervened=filtered is not None and filtered.modified)
        if terminated or truncated:
            self._finish_episode(constrained)
        return info, reward, bool(terminated), bool(truncated)

    def _finish_episode(self, constrained: bool) -> None:
        excluded = self._monitor is not None and self._monitor.violated_at_end()
        phase = self._monitor.violated_phase if constrained or excluded else None
        summary = self._recorder.summary(constraint_terminated=constrained, constraint_phase=phase,
                                         joint_limit_violations=self.runner.limit_violations)
        summary.constraint_excluded = excluded
        taken = taken_lane(self._cube_start, self.task.cube_xy(self.runner.physics).tolist(),
                           self.task.config.cube.size / 2)
        summary.lane_agrees = None if taken is None else taken == self._planned
        if self.mechanism is not None:
            summary.events = self.mechanism.end_episode(
                self._recorder.f, self._recorder.phase, constraint_terminated=constrained,
                terminated_phase=phase, constraint_excluded=excluded)
        summary.end_order = next(_END_ORDER)
        self.completed.append(summary)

    def _set_seed(self, seed: int | None) -> None:
        self.runner.seed(0 if seed is None else seed)
