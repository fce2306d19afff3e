"""One deploy session: an arm adapter, the world model, a controller and the settings, and a fresh
:class:`~ahrm_stack.deploy.loop.DeployLoop` per episode through the one safety filter.

The one place that assembles a deploy episode: ``python -m ahrm_stack.deploy``
(:func:`ahrm_stack.deploy.run.deploy`), the robustness evaluation, and the deploy benchmarks all
open a session and ask it for loops, so the controller, the world model and the filter are wired
the same way in each.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ahrm_stack.config import Config
from ahrm_stack.deploy.controllers import make_controller
from ahrm_stack.deploy.loop import DeployFault, DeployLoop
from ahrm_stack.deploy.settings import DeploySettings
from ahrm_stack.deploy.world import WorldModel


@dataclasses.dataclass
class DeploySession:
    """``arm`` (a :class:`ahrm_stack.hardware.protocol.ArmAdapter`), ``world`` (the task's model of the scene,
    fed by feedback and perception only), ``controller`` (the policy's, or the scripted controller's
    without an actor), the checkpoint's ``config`` (its safety section already merged into deploy's)
    and the loop ``settings``."""

    arm: Any
    world: WorldModel
    controller: Any
    config: Config
    settings: DeploySettings

    @classmethod
    def open(cls, arm: Any, config: Config, actor: Any, settings: DeploySettings,
             world_seed: int | None = None) -> "DeploySession":
        """A session of ``actor`` (None: the scripted controller) on ``arm``; the world model is
        seeded ``world_seed`` (default ``settings.seed``)."""
        world = WorldModel(config.task, seed=settings.seed if world_seed is None else world_seed)
        return cls(arm, world, make_controller(world, config, actor), config, settings)

    def loop(self, telemetry: Any = None, scene: Any = None) -> DeployLoop:
        """A fresh loop for one episode (``telemetry``: an open JSONL file or None; ``scene``: a
        perception source, None for the arm's own ``perception()``)."""
        return DeployLoop(self.arm, self.world, self.controller, self.config.safety, self.settings,
                          telemetry, scene)

    def reset_sim(self, seed: int, sim: Any = None) -> None:
        """Start a simulated episode: the sim arm (``sim``, default the session's arm; give it when
        the session's arm wraps it) reset to the scene of ``seed``, the session's arm reconnected and
        its faults cleared."""
        if self.arm.is_connected:
            self.arm.disconnect()
        (self.arm if sim is None else sim).reset_scene(seed)
        self.arm.connect()
        self.arm.clear_faults()

    def run(self, duration: float) -> tuple[Any, str]:
        """One fresh loop run for up to ``duration`` s: its summary, and the fault's text when a
        software fault ended it (its summary then the one the fault carried), else ``""``."""
        try:
            return self.loop().run(duration), ""
        except DeployFault as error:
            return error.summary, str(error)
