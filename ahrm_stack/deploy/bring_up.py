"""The two bring-up steps before a deploy run, each its own command: ``--check`` (the backend's
link check, the arm held still) and ``--home`` (one slow move to the policy's start posture, after a
typed confirmation), on the kinova-gen2 and kortex backends. Called by
:func:`ahrm_stack.deploy.cli.main`."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Sequence

from ahrm_stack.config import ConfigError
from ahrm_stack.deploy.settings import DeployConfigError, DeploySettings


def check_link(backend: str, settings: DeploySettings, checkpoint: Path | None,
               overrides: Sequence[str], policy_file: Path | None = None) -> int:
    """``--check``: the backend's link check (:data:`ahrm_stack.deploy.backends.BACKENDS`), the arm held
    still; prints its lines. Exit status: 0 the budget fits, 1 it does not, 2 bad input (one line,
    the arm never contacted), 3 the arm could not be reached (one line, e.g. no arm found), 130
    Ctrl-C."""
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.learning.checkpoint import CheckpointError
    from ahrm_stack.deploy import backends
    from ahrm_stack.hardware.protocol import HardwareError

    prog = "python -m ahrm_stack.deploy"
    try:
        config, _ = load_controller_config(checkpoint, overrides, policy_file=policy_file)
        chosen = backends.get(backend)
        if chosen.link_check is None:
            raise DeployConfigError(f"--check measures an arm's link (the kinova-gen2 backend's USB "
                                    f"budget, the kortex backend's per-tick RPCs); --backend {backend} "
                                    "has none")
        chosen.check_bring_up(config, settings)
    except (ConfigError, DeployConfigError, CheckpointError, ValueError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    try:
        lines, fits = chosen.link_check(config, settings)
    except (HardwareError, ValueError) as error:
        print(f"{prog}: error: {(str(error).splitlines() or [''])[0]}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("interrupted: the check stopped (the arm was held still)", file=sys.stderr)
        return 130
    print("\n".join(lines))
    return 0 if fits else 1


def home_limits(world, settings: DeploySettings, home_settings=None):
    """The deploy settings homing applies to ``world`` (a :class:`~ahrm_stack.deploy.WorldModel`):
    the backend's home section (``home_settings``; default ``kinova_gen2.home``), the velocity
    alarm and the loop's start check (:class:`ahrm_stack.hardware.homing.Limits`)."""
    import math

    from ahrm_stack.deploy.start_check import start_refusal
    from ahrm_stack.hardware.homing import Limits

    start = settings.start_posture
    home_settings = settings.kinova_gen2.home if home_settings is None else home_settings
    return Limits(home_settings, settings.watchdog.velocity_tolerance,
                  settings.watchdog.velocity_alarm_ticks,
                  lambda q: start_refusal(world, q, math.radians(start.joint_tolerance_deg),
                                          start.region_margin, math.radians(start.tilt_tolerance_deg)))


def home(config, settings: DeploySettings, yes: bool, say=print, ask=input, touch_off: bool = False,
         backend: str = "kinova-gen2"):
    """Connect to the arm of ``backend`` (``settings.kinova_gen2`` or ``settings.kortex``) and run
    the homing (:class:`ahrm_stack.hardware.kinova_gen2.home.Homing`,
    :class:`ahrm_stack.hardware.kortex.home.KortexHoming`) to the start of ``config``'s task (the
    policy's), with the deploy settings that apply, or with ``touch_off`` (Gen2) the tool's
    touch-off (:class:`ahrm_stack.hardware.kinova_gen2.touch_off.TouchOff`, its record written); its
    outcome. Bad settings raise before anything is contacted (one-line ``Gen2ConfigError``,
    ``CredentialsError``: ValueErrors); a failed connect raises
    :class:`~ahrm_stack.hardware.protocol.HardwareError` (the arm stopped, the session closed)."""
    from ahrm_stack.deploy.world import WorldModel
    from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm
    from ahrm_stack.hardware.kinova_gen2.home import Homing
    from ahrm_stack.hardware.kinova_gen2.touch_off import TouchOff

    world = WorldModel(config.task)
    if backend == "kortex":
        from ahrm_stack.deploy import backends
        from ahrm_stack.hardware.kortex.home import KortexHoming

        kortex = backends.kortex_adapter(config, settings)
        kortex.connect()
        return KortexHoming(kortex, world, home_limits(world, settings, settings.kortex.home),
                            settings.period, say, None if yes else ask).run()
    gen2 = settings.kinova_gen2
    arm = KinovaGen2Arm(world.robot, gen2, command_timeout_s=gen2.command_timeout * settings.period)
    arm.connect()
    if not touch_off:
        return Homing(arm, world, home_limits(world, settings), say, None if yes else ask).run()
    step = TouchOff(arm, world, home_limits(world, settings), gen2.touch_off, say, ask)
    outcome = step.run()
    if outcome.moved:
        step.record(Path(gen2.touch_off.record))
    return outcome


def home_arm(backend: str, settings: DeploySettings, checkpoint: Path | None,
             overrides: Sequence[str], policy_file: Path | None, yes: bool, touch_off: bool = False) -> int:
    """``--home``: move the arm (``--backend kinova-gen2`` or ``kortex``) to the start posture of the
    policy's task after a confirmation (:func:`home`); ``--touch-off`` (``touch_off``, Gen2 only):
    the tool's touch-off, its record written. Prints why it ended. Exit status: 0 at the start posture (the
    touch-off passed), 1 not confirmed (nothing moved; the touch-off failed), 2 bad input (one line,
    nothing moved), 3 stopped (a fault, the timeout, the link) or the arm not reached, 130 Ctrl-C."""
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.learning.checkpoint import CheckpointError
    from ahrm_stack.deploy import backends
    from ahrm_stack.hardware.homing import DONE
    from ahrm_stack.hardware.kinova_gen2 import check_library
    from ahrm_stack.hardware.protocol import HardwareError

    prog = "python -m ahrm_stack.deploy"
    flag, name = ("--touch-off", "touch-off") if touch_off else ("--home", "homing")
    movers = ("kinova-gen2",) if touch_off else ("kinova-gen2", "kortex")
    try:
        if backend not in movers:
            raise DeployConfigError(f"{flag} moves a Kinova arm (--backend {' or '.join(movers)}); "
                                    f"--backend {backend} has no {name} step")
        config, _ = load_controller_config(checkpoint, overrides, policy_file=policy_file)
        if backend == "kinova-gen2":
            check_library(settings.kinova_gen2)
        else:
            backends.get(backend).check_bring_up(config, settings)
    except (ConfigError, DeployConfigError, CheckpointError, ValueError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    try:
        outcome = home(config, settings, yes, touch_off=touch_off, backend=backend)
    except ValueError as error:  # a setting (Gen2ConfigError), before the arm was contacted
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    except HardwareError as error:  # the connect failed: the arm stopped, the API closed
        print(f"{prog}: error: {(str(error).splitlines() or [''])[0]}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("interrupted while connecting: nothing moved", file=sys.stderr)
        return 130
    print(f"{name}: {outcome.reason}", file=sys.stdout if outcome.status == DONE else sys.stderr)
    return outcome.status
