"""The push-off task as a thin ``gymnasium.Env`` (issue 57), for tools that speak Gymnasium.

    import gymnasium, ahrm_stack.env.gym_env  # registers the id
    env = gymnasium.make("ahrm_stack/PushOff-v0", overrides=["task.robot=j2s6s200"])

One episode is one :class:`~ahrm_stack.env.runner.TaskRunner` episode: the same task, safety
filter, observation vector (:meth:`TaskRunner.flat_observation`, float32) and normalised action
(``task.action.mode``: joint velocities or the tip velocity, in [-1, 1]) as training and
evaluation use. ``terminated``: the cube left the table; ``truncated``: the episode's time limit
(``task.episode.duration``, or ``time_limit`` in s). The reward is the linear sum of the step's
penalty components g (spec §3: 0 when every objective is met, down to -3), the reward LS learns
from; the hierarchical mechanisms keep per-episode state and live in the trainer, not here.
``info`` holds the step's success, touch, phase and the ±1 components f.

``reset(seed=s)`` seeds the task's random stream (layouts, starts, noise) with ``s``: the same
seed gives the same episode. Without a seed the stream goes on.
"""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium
import numpy as np
from gymnasium import spaces

from ahrm_stack.config import Config, load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask, StepInfo

ENV_ID = "ahrm_stack/PushOff-v0"


class PushOffGymEnv(gymnasium.Env):
    """The push-off task behind Gymnasium's API (see the module)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, config: Config | None = None, overrides: Sequence[str] = (),
                 time_limit: float = 0.0) -> None:
        """``config``: a loaded configuration (default: ``configs/`` with ``overrides``);
        ``time_limit`` (s, > 0): episodes are truncated here instead of at the task's duration."""
        super().__init__()
        self.config = config if config is not None else load_config(list(overrides))
        self.task = PushOffTask(self.config.task)
        self.runner = TaskRunner(self.task, seed=0, safety=self.config.safety)
        if time_limit > 0:
            self.runner.max_steps = max(1, int(round(time_limit / self.config.task.episode.control_period)))
        self.runner.reset()
        size = self.runner.flat_observation().shape[0]
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.runner.control.action_size,), dtype=np.float32)

    def _observation(self) -> np.ndarray:
        return self.runner.flat_observation().astype(np.float32)

    @staticmethod
    def _info(info: StepInfo) -> dict[str, Any]:
        return {"success": bool(info.success), "touched": bool(info.touched), "phase": int(info.phase),
                "f": np.asarray(info.f, dtype=float).copy()}

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.runner.seed(int(seed))
        transition = self.runner.reset()
        return self._observation(), self._info(transition.info)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        info, terminated, truncated = self.runner.step_action(np.asarray(action, dtype=float))
        return self._observation(), float(np.sum(info.g)), bool(terminated), bool(truncated), self._info(info)


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="ahrm_stack.env.gym_env:PushOffGymEnv")

__all__ = ["ENV_ID", "PushOffGymEnv"]
