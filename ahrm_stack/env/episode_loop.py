"""One seeded episode on a :class:`~ahrm_stack.env.runner.TaskRunner`, as a generator of steps.

Every loop that drives an episode outside training — the scripted controller in evaluation, the
demo, the curriculum's recorded start states, the demonstrations, the benchmarks, the studies' replays
of a policy — is this generator with its own ``act``::

    for step in scripted_episode(runner, pusher, seed):
        ...  # step.info: the state now (the reset's first); the next step is taken when asked

The generator seeds the runner, resets it (and the controller, on the reset physics), yields the
reset's state, then one :class:`Step` per control step until success (``terminated``) or the time
limit (``truncated``). The consumer sees each state *before* the next action is chosen, so it can
record the state (start states, demonstrations), render it (evaluation's films) or stop early (a
replay that looks for the first touch).
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Iterator

import numpy as np
from dm_control import mjcf

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import StepInfo

Act = Callable[[], tuple[np.ndarray, StepInfo, bool, bool]]
"""One control step: the request or action it sent, then the runner's (info, terminated, truncated)."""


@dataclasses.dataclass(frozen=True)
class Step:
    """One state of an episode: the reset's (``sent`` is None) or the one after a control step."""

    info: StepInfo
    terminated: bool  # success: a terminal state
    truncated: bool  # the episode's time limit
    sent: np.ndarray | None  # what the step sent (a request or a normalised action); None at reset

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated


def episode(runner: TaskRunner, seed: int, act: Act,
            reset: Callable[[mjcf.Physics], None] | None = None) -> Iterator[Step]:
    """Episode ``seed`` on ``runner``: ``reset(physics)`` after the runner's reset (a controller's),
    then ``act()`` per control step until the episode ends."""
    runner.seed(seed)
    transition = runner.reset()
    if reset is not None:
        reset(runner.physics)
    yield Step(transition.info, False, False, None)
    while True:
        sent, info, terminated, truncated = act()
        yield Step(info, terminated, truncated, sent)
        if terminated or truncated:
            return


def scripted_episode(runner: TaskRunner, pusher: ScriptedPusher, seed: int,
                     cartesian: bool = False) -> Iterator[Step]:
    """Episode ``seed`` of the scripted controller through the runner's safety filter: its joint
    velocities (rad/s) by :meth:`TaskRunner.step_only`, or with ``cartesian`` its tip velocity (m/s,
    world frame) by :meth:`TaskRunner.step_cartesian`."""

    def act() -> tuple[np.ndarray, StepInfo, bool, bool]:
        if cartesian:
            request = pusher.tip_velocity(runner.physics)
            return (request, *runner.step_cartesian(request))
        request = pusher(runner.physics)
        return (request, *runner.step_only(request))

    return episode(runner, seed, act, pusher.reset)


__all__ = ["Act", "Step", "episode", "scripted_episode"]
