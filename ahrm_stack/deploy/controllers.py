"""Controllers: the world (:class:`~ahrm_stack.deploy.world.WorldModel`) -> the safety filter's
request for this tick (joint velocities, rad/s, all joints; or the pusher tip's velocity, m/s,
world frame, when :attr:`cartesian` is true)."""

from __future__ import annotations

import numpy as np

from ahrm_stack.config import Config
from ahrm_stack.deploy.world import WorldModel


class ScriptedController:
    """The scripted mink pusher, run on the :class:`WorldModel`'s mirror physics."""

    name = "scripted"
    cartesian = False  # returns joint velocities, rad/s

    def __init__(self, world: WorldModel, config: Config) -> None:
        from ahrm_stack.env.scripted import ScriptedPusher

        self.world = world
        self.pusher = ScriptedPusher(world.task, config.scripted)

    def reset(self) -> None:
        """Plan the episode from the current world (after the first update)."""
        self.pusher.reset(self.world.physics)

    def __call__(self) -> np.ndarray:
        return self.pusher(self.world.physics)

    @property
    def stage(self) -> str:
        return self.pusher.stage


class PolicyController:
    """A trained policy (deterministic action) on the training observation vector. Its request is
    what training's environment makes of the action (the same
    :class:`~ahrm_stack.env.control_step.ControlStep`): joint velocities (rad/s, ``action.mode:
    joint``) or a pusher-tip velocity (m/s, world frame, ``cartesian``: :attr:`cartesian` is then true and the
    loop hands it to the filter's differential IK)."""

    name = "policy"

    def __init__(self, world: WorldModel, actor, config: Config) -> None:
        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        from ahrm_stack.env.control_step import ControlStep
        from ahrm_stack.learning.ppo import lean_actor

        self.control = ControlStep(world.robot, config.task.action)
        self.cartesian = self.control.cartesian
        self.world = world
        self.actor = actor
        # An actor of make_modules (or its LeanActor, what load_policy gives) runs as one plain
        # torch forward on the observation tensor: the same deterministic action, no TensorDict.
        lean = lean_actor(actor)
        self._act = None if lean is None else lean.act
        self._torch, self._tensordict = torch, TensorDict
        self._deterministic, self._exploration = set_exploration_type, ExplorationType

    def reset(self) -> None:
        pass

    def __call__(self) -> np.ndarray:
        """The request for this tick: joint velocities (rad/s) or the tip velocity (m/s, world
        frame); an entry whose action was NaN or infinite is NaN (the loop stops on it)."""
        torch = self._torch
        observation = torch.as_tensor(self.world.observation(), dtype=torch.float32)
        if self._act is not None:
            action = self._act(observation)
        else:  # any other policy: the TensorDict call
            with torch.no_grad(), self._deterministic(self._exploration.DETERMINISTIC):
                action = self.actor(self._tensordict({"observation": observation}, batch_size=[]))["action"]
        # a non-finite action is a fault, not a zero: it stays NaN for the loop to flag
        return self.control.request_keeping_faults(np.asarray(action.numpy(), dtype=float).reshape(-1))

    @property
    def stage(self) -> str:
        return "policy"


def make_controller(world: WorldModel, config: Config, actor=None):
    """The scripted controller without an ``actor``, else the policy's."""
    return ScriptedController(world, config) if actor is None else PolicyController(world, actor, config)
