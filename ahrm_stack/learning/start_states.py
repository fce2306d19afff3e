"""Start states for the reverse curriculum (``train.start_curriculum: scripted_states``).

The scripted controller is run on its own seeded episodes (``configs/seeds.yaml``: the
``start_states`` range) and the simulator's state is recorded at every control step of the
episodes it wins: only *states* are kept — no action labels reach the learner. A training episode
then starts from a recorded state at the fraction ``1 - level`` of a random recorded trajectory:
at level 0 the last state before the cube fell, at level 1 the trajectory's first state (the
task's own start). The trainer raises the level as the training success rate grows; at level 1 the
curriculum is over and episodes start as the task draws them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrm_stack.config import Config, ConfigError
from ahrm_stack.env.layout import Layout
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.episode_loop import scripted_episode
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.seeds import seed_table


@dataclasses.dataclass(frozen=True)
class StartState:
    """One recorded simulator state: the episode's layout and MuJoCo's qpos / qvel (world frame,
    m, rad, m/s, rad/s)."""

    layout: Layout
    qpos: np.ndarray
    qvel: np.ndarray


@dataclasses.dataclass(frozen=True)
class Trajectory:
    layout: Layout
    qpos: np.ndarray  # (T, nq): the state before each control step
    qvel: np.ndarray  # (T, nv)


def record_trajectories(config: Config, episodes: int) -> list[Trajectory]:
    """The scripted controller's won episodes among ``episodes`` seeded ones (seeds
    ``start_states.start + i``), each as the states before each of its control steps."""
    task = PushOffTask(config.task)
    first = seed_table()["start_states"].start
    runner = TaskRunner(task, seed=first, safety=config.safety)
    controller = ScriptedPusher(task, config.scripted)
    trajectories = []
    for episode in range(episodes):
        qpos, qvel = [], []
        for step in scripted_episode(runner, controller, first + episode):
            if not step.done:  # the state before each control step
                qpos.append(runner.physics.data.qpos.copy())
                qvel.append(runner.physics.data.qvel.copy())
        if step.terminated:
            assert task.layout is not None  # set by the reset
            layout = Layout(task.layout.cube_xy.copy(), task.layout.obstacle_xy.copy())
            trajectories.append(Trajectory(layout, np.array(qpos), np.array(qvel)))
    return trajectories


class ScriptedStartStates:
    """Draws start states from recorded trajectories at the curriculum's ``level`` (0 to 1)."""

    def __init__(self, trajectories: list[Trajectory]) -> None:
        if not trajectories:
            raise ConfigError("train.curriculum_states: the scripted controller won none of its "
                              "start-state episodes; record more")
        self.trajectories = trajectories
        self.level = 0.0

    def __call__(self, random_state: np.random.RandomState) -> StartState | None:
        """A state at the fraction ``1 - level`` of a uniformly drawn trajectory; None at level 1
        (the task draws the start itself)."""
        if self.level >= 1.0:
            return None
        trajectory = self.trajectories[random_state.randint(len(self.trajectories))]
        index = int(np.floor((1.0 - self.level) * (len(trajectory.qpos) - 1)))
        return StartState(trajectory.layout, trajectory.qpos[index], trajectory.qvel[index])
