"""The arm backends ``python -m ahrm_stack.deploy --backend NAME`` can build.

:data:`BACKENDS` maps a name to a :class:`Backend`: ``check(config, settings)`` validates the
backend's settings before anything is written or contacted (a one-line ``ValueError`` naming the
key or the file), ``make(config, settings)`` builds the adapter, not yet connected, with the
``perception()`` method the deploy loop calls; ``link_check(config, settings)``, for a backend
with a link worth measuring (``--check``), connects, measures the link with the arm held still,
disconnects and returns the lines to print and whether the budget fits (None: the backend has no
such check); ``bring_up_check(config, settings)``, where set, replaces ``check`` before
``--check`` and ``--home`` (a Kortex run needs a scene source its bring-up steps do not). A real
arm's adapter is wrapped with its static scene source (:func:`static_scene`, ``perception()`` for
the loop; ``--scene camera`` replaces it) in one way for every backend: :func:`_perceived`.
``config`` is the run's :class:`~ahrm_stack.config.Config` (its ``task.robot`` is the arm model),
``settings`` the :class:`~ahrm_stack.deploy.DeploySettings`. Backends are imported only when built.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Optional

from ahrm_stack.hardware.protocol import ArmAdapter


@dataclasses.dataclass(frozen=True)
class Backend:
    name: str
    help: str
    check: Callable[[Any, Any], None]
    make: Callable[[Any, Any], ArmAdapter]
    link_check: Optional[Callable[[Any, Any], tuple[list[str], bool]]] = None
    bring_up_check: Optional[Callable[[Any, Any], None]] = None

    def check_bring_up(self, config, settings) -> None:
        """The checks before ``--check`` or ``--home`` contacts the arm (one-line ValueError)."""
        (self.bring_up_check or self.check)(config, settings)


def _check_sim(config, settings) -> None:
    pass


def _make_sim(config, settings) -> ArmAdapter:
    from ahrm_stack.hardware.protocol import FastClock, WallClock
    from ahrm_stack.sim_arm import SimArm

    clock = WallClock() if settings.realtime else FastClock()
    return SimArm(config.task, seed=settings.seed, clock=clock,
                  command_delay=settings.sim.command_delay, realism=settings.sim.realism)


def _gen2_parts(config, settings):
    """Validated Gen2 settings, the robot description and the scene (one-line errors)."""
    from ahrm_stack.robot import describe, make_arm
    from ahrm_stack.hardware.kinova_gen2 import Gen2ConfigError, check_library, joint_convention
    from ahrm_stack.hardware.scene import static_scene

    gen2 = settings.kinova_gen2
    if not settings.realtime:
        raise Gen2ConfigError("deploy.realtime: a real arm runs on the wall clock; --fast is for "
                              "the sim backend only")
    check_library(gen2)
    if gen2.serial is None:
        raise Gen2ConfigError("deploy.kinova_gen2.serial is not set: the arm is chosen by its "
                              "serial number, never the first one found")
    scene = static_scene(gen2.scene, config.task, "deploy.kinova_gen2.scene")
    robot = describe(config.task.robot, make_arm(config.task.robot))
    joint_convention(gen2, robot)
    return gen2, robot, scene


def _perceived(arm: ArmAdapter, scene) -> ArmAdapter:
    """A real arm's adapter for a deploy run: ``arm`` with the scene source ``scene`` (a
    :func:`~ahrm_stack.hardware.scene.static_scene`) as its ``perception()``."""
    from ahrm_stack.hardware.scene import PerceivedArm

    return PerceivedArm(arm, scene)


def _check_gen2(config, settings) -> None:
    """A deploy run's checks: the settings and, with ``kinova_gen2.touch_off.required``, a passing
    touch-off of this arm (:func:`~ahrm_stack.hardware.kinova_gen2.touch_off.touch_off_refusal`)."""
    from pathlib import Path

    from ahrm_stack.hardware.kinova_gen2 import Gen2ConfigError
    from ahrm_stack.hardware.kinova_gen2.touch_off import touch_off_refusal

    gen2, _, _ = _gen2_parts(config, settings)
    if gen2.touch_off.required:
        refusal = touch_off_refusal(Path(gen2.touch_off.record), gen2.serial)
        if refusal is not None:
            raise Gen2ConfigError(f"{refusal} (or set kinova_gen2.touch_off.required: false)")


def _make_gen2(config, settings) -> ArmAdapter:
    from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm

    gen2, robot, scene = _gen2_parts(config, settings)
    return _perceived(KinovaGen2Arm(robot, gen2, command_timeout_s=gen2.command_timeout * settings.period),
                      scene)


def _link_check_gen2(config, settings) -> tuple[list[str], bool]:
    """The Gen2 USB budget on the arm (:mod:`ahrm_stack.hardware.kinova_gen2.check`), held still."""
    from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm
    from ahrm_stack.hardware.kinova_gen2.check import Rates, check_link

    gen2, robot, _ = _gen2_parts(config, settings)
    arm = KinovaGen2Arm(robot, gen2, command_timeout_s=gen2.command_timeout * settings.period)
    rates = Rates(control_hz=settings.rate_hz,
                  command_deadline=settings.watchdog.command_deadline * settings.period,
                  send_rate_hz=gen2.send_rate_hz, send_ahead=gen2.send_ahead,
                  status_rate_hz=gen2.status_rate_hz, torque_each_tick=gen2.torque_each_tick)
    return check_link(arm, rates, gen2.check_calls)


def _kortex_scene(config, settings):
    """A Kortex run's static scene source (``kortex.scene``; one-line SceneError)."""
    from ahrm_stack.hardware.scene import static_scene

    return static_scene(settings.kortex.scene, config.task, "deploy.kortex.scene")


def _check_kortex(config, settings) -> None:
    """A run's checks, in one line before anything is written or contacted: what is missing
    (address, credentials, real-time pacing, a policy whose robot is a Kortex arm, a scene source;
    :func:`~ahrm_stack.hardware.kortex.kortex_deploy_blocker`), then the scene layout file itself."""
    from ahrm_stack.hardware.kortex import kortex_deploy_blocker

    blocker = kortex_deploy_blocker(settings, robot=config.task.robot)
    if blocker is not None:
        raise ValueError(blocker)
    _kortex_scene(config, settings)


def _bring_up_check_kortex(config, settings) -> None:
    """``--check`` / ``--home``: the address, the credentials and a Gen3 policy (one line)."""
    from ahrm_stack.hardware.kortex import kortex_bring_up_blocker

    blocker = kortex_bring_up_blocker(settings, robot=config.task.robot)
    if blocker is not None:
        raise ValueError(blocker)


def kortex_adapter(config, settings):
    """The Kortex adapter (not connected) for ``config``'s robot, its workspace and its safety
    filter's acceleration limits, without a scene source (``--check``, ``--home``)."""
    from ahrm_stack.config import arm_acceleration_limit
    from ahrm_stack.robot import describe, make_arm
    from ahrm_stack.hardware.kortex import make_kortex_backend, task_workspace

    robot = config.task.robot
    return make_kortex_backend(settings, describe(robot, make_arm(robot)),
                               workspace=task_workspace(config.task, settings.kortex.workspace_height),
                               acceleration_limit=arm_acceleration_limit(config.safety.acceleration_limit, robot))


def _link_check_kortex(config, settings) -> tuple[list[str], bool]:
    """The Kortex link's per-tick RPCs on the arm (:mod:`ahrm_stack.hardware.kortex.check`), held
    still."""
    from ahrm_stack.hardware.kortex.check import Rates, check_link

    rates = Rates(control_hz=settings.rate_hz,
                  send_deadline=settings.watchdog.command_deadline * settings.period,
                  rpc_timeout_ms=settings.kortex.rpc_timeout_ms)
    return check_link(kortex_adapter(config, settings), rates, settings.kortex.check_ticks)


def _make_kortex(config, settings) -> ArmAdapter:
    """A run's Kortex adapter with its static scene source, as the Gen2 backend's (:func:`_perceived`)."""
    return _perceived(kortex_adapter(config, settings), _kortex_scene(config, settings))


BACKENDS: dict[str, Backend] = {
    "sim": Backend("sim", "the training physics (dm_control), paced or --fast", _check_sim, _make_sim),
    "kinova-gen2": Backend("kinova-gen2", "a Kinova Gen2 / JACO2 over Kinova's C SDK "
                           "(configs/deploy.yaml kinova_gen2; docs/hardware.md)",
                           _check_gen2, _make_gen2, _link_check_gen2),
    "kortex": Backend("kortex", "a Kinova Gen3 over kortex_api (configs/deploy.yaml kortex; a run needs "
                      "the address, credentials, a policy whose robot has a kortex.models entry and "
                      "kortex.scene, else it is refused naming what is missing; --check and --home need "
                      "no scene)",
                      _check_kortex, _make_kortex, _link_check_kortex, _bring_up_check_kortex),
}


def names() -> list[str]:
    """The backend names, for ``--backend``'s choices."""
    return list(BACKENDS)


def get(name: str) -> Backend:
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; choose one of {names()}")
    return BACKENDS[name]
