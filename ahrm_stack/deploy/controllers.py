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


class PolicyStructureError(ValueError):
    """The actor handed to deploy is not of the structure :class:`NumpyPolicy` runs."""


class PolicyController:
    """A trained policy (deterministic action) on the training observation vector. Its request is
    what training's environment makes of the action (the same
    :class:`~ahrm_stack.env.control_step.ControlStep`): joint velocities (rad/s, ``action.mode:
    joint``) or a pusher-tip velocity (m/s, world frame, ``cartesian``: :attr:`cartesian` is then
    true and the loop hands it to the filter's differential IK).

    The forward pass is :class:`~ahrm_stack.deploy.policy.NumpyPolicy` (float32, on the world
    model's preallocated observation, no torch call per tick) of an actor of
    :func:`~ahrm_stack.learning.ppo.make_modules` or its ``LeanActor`` (what ``load_policy`` gives;
    in a lane frame or not): the one inference path, tested against the lean actor's torch forward.
    Any other actor is refused in one line (:class:`PolicyStructureError`)."""

    name = "policy"

    def __init__(self, world: WorldModel, actor, config: Config) -> None:
        from ahrm_stack.deploy.policy import NumpyPolicy
        from ahrm_stack.env.control_step import ControlStep

        self.control = ControlStep(world.robot, config.task.action)
        self.cartesian = self.control.cartesian
        self.world = world
        self.actor = actor
        numpy = NumpyPolicy.from_actor(actor)
        if numpy is None:
            raise PolicyStructureError(
                f"the policy's actor ({type(actor).__name__}) is not a trained actor of this project "
                "(running normaliser -> Linear/activation layers -> Gaussian head, float32): deploy runs "
                "only that structure, in NumPy")
        self._numpy = numpy

    def reset(self) -> None:
        self.control.reset()

    def __call__(self) -> np.ndarray:
        """The request for this tick: joint velocities (rad/s) or the tip velocity (m/s, world
        frame), a new array, smoothed as in training (``task.action.smoothing``); an entry whose
        action was NaN or infinite is NaN (the loop stops on it)."""
        return self.control.smooth(self._policy_request())

    def _policy_request(self) -> np.ndarray:
        return self._request(self._numpy(self.world.observation(copy=False)))

    def _request(self, action) -> np.ndarray:
        """:meth:`ControlStep.request_keeping_faults` of ``action`` (a new float64 array)."""
        return self.control.request_keeping_faults(action)

    @property
    def stage(self) -> str:
        return "policy"


def make_controller(world: WorldModel, config: Config, actor=None):
    """The scripted controller without an ``actor``, else the policy's."""
    return ScriptedController(world, config) if actor is None else PolicyController(world, actor, config)
