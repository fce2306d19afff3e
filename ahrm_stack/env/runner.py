"""A lean episode runner for :class:`PushOffTask`: the task's hooks, without composer's buffers.

``composer.Environment`` recompiles the physics at every reset and refreshes every observable at
every physics substep; this runner compiles the model once, resets with ``mj_resetData``, steps the
physics ``substeps`` times per control step and evaluates the task's declared observables once, at
the end of the control step. The task is the same object either way (``composer.Environment(task)``
still works), so the episode logic lives in one place.

Contacts are read at the end of each control step; a touch that does not last to the end of the
step is caught by the obstacle-speed test of f1.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import mujoco
import numpy as np
from dm_control import mjcf

from ahrm_stack.env.task import PushOffTask, StepInfo


@dataclasses.dataclass
class Transition:
    observation: dict[str, np.ndarray]
    info: StepInfo
    terminated: bool  # success: a terminal state
    truncated: bool  # the episode's time limit


class TaskRunner:
    """Resets and steps one :class:`PushOffTask` on its own physics. Seeded by ``seed``."""

    def __init__(self, task: PushOffTask, seed: int | None = None) -> None:
        self.task = task
        self.physics = mjcf.Physics.from_mjcf_model(task.root_entity.mjcf_model)
        self.random_state = np.random.RandomState(seed)
        self._substeps = task.config.substeps
        self._max_steps = task.config.max_steps
        self._steps = 0
        self._observe: dict[str, Callable[[], np.ndarray]] = {
            name: obs.observation_callable(self.physics, self.random_state)
            for name, obs in task.observables.items()}
        self.observation_order = task.observation_order

    def seed(self, seed: int) -> None:
        self.random_state.seed(seed)

    def observe(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(fn()) for name, fn in self._observe.items()}

    def flat_observation(self) -> np.ndarray:
        """The observation vector: the keys of ``observation_order``, flattened and concatenated."""
        return self.task.flat_observation(self.physics)

    def reset(self) -> Transition:
        mujoco.mj_resetData(self.physics.model.ptr, self.physics.data.ptr)
        self.task.initialize_episode(self.physics, self.random_state)
        self._steps = 0
        return Transition(self.observe(), self.task.step_info, False, False)

    def step_only(self, command: np.ndarray) -> tuple[StepInfo, bool, bool]:
        """Advance one control step without building the observation dict.

        ``command``: joint velocities for all arm joints, rad/s, from the safety layer.
        """
        self.task.before_step(self.physics, command, self.random_state)
        self.physics.step(self._substeps)
        self.task.after_step(self.physics, self.random_state)
        self._steps += 1
        info = self.task.step_info
        terminated = self.task.should_terminate_episode(self.physics)
        truncated = not terminated and self._steps >= self._max_steps
        if terminated or truncated:
            self.end_episode()
        return info, terminated, truncated

    def end_episode(self) -> None:
        """Close the episode's cross-episode bookkeeping (f3's phase budgets). Called on success
        and time limit here; a caller that ends an episode early for its own reason calls it."""
        self.task.time_objective.end_episode()

    def step(self, command: np.ndarray) -> Transition:
        info, terminated, truncated = self.step_only(command)
        return Transition(self.observe(), info, terminated, truncated)

    @property
    def steps(self) -> int:
        return self._steps
