"""Deploy wiring: the Kortex adapter built from the deploy settings, and what the bring-up steps
(``--check``, ``--home``) and a run need before the arm is contacted."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.hardware.kortex.arm import KortexArm, KortexNotInstalledError
from ahrm_stack.hardware.kortex.credentials import Credentials, CredentialsError, load_credentials
from ahrm_stack.hardware.kortex.settings import kortex_options
from ahrm_stack.hardware.kortex.vendor_link import INSTALL_HINT, LinkError, import_modules
from ahrm_stack.hardware.protocol import HardwareError
from ahrm_stack.hardware.scene import scene_unset


def import_kortex_api() -> dict:
    """The vendor modules the backend uses, imported in this process (tests, a direct link), or
    :class:`KortexNotInstalledError`. Deploy itself imports them only in the child process."""
    try:
        return import_modules()
    except LinkError:
        raise KortexNotInstalledError(INSTALL_HINT) from None


def make_kortex_backend(settings, robot: RobotDescription, *,
                        credentials: Credentials | None = None, api: dict | None = None,
                        env: Mapping[str, str] | None = None,
                        workspace: np.ndarray | None = None,
                        acceleration_limit: Sequence[float] | None = None) -> KortexArm:
    """The Kortex adapter for a deploy run (or ``--check`` / ``--home``), not yet connected.

    Args:
        settings: validated deploy settings (``ahrm_stack.deploy.DeploySettings``): the
            ``kortex`` section (address, credentials file, timeouts, watchdog, reset, the
            ``kortex_api`` interpreter, the arm models, soft limits, protection zones) and the
            control period.
        robot: the deployed arm model (a checkpoint's own).
        credentials: the login; default :func:`load_credentials` from ``kortex.credentials_file``
            or the environment (``env``, default ``os.environ``).
        api: vendor modules to use in this process (default: ``kortex_api`` in a child process
            under ``kortex.python``).
        workspace: the task workspace in the arm's base frame
            (:func:`ahrm_stack.hardware.kortex.zones.task_workspace`), checked against protection zones.
        acceleration_limit: the policy's joint acceleration limits (rad/s^2, the safety filter's),
            checked against the arm's acceleration soft limits where it reports them.

    Raises :class:`HardwareError` (one line, naming ``deploy.kortex.address``) without an address
    and :class:`CredentialsError` without credentials; nothing is contacted.
    """
    address = settings.kortex.address
    if not address or not str(address).strip():
        raise HardwareError("deploy.kortex.address is not set: give the arm's IP address in "
                            "configs/deploy.yaml (there is no default)")
    if credentials is None:
        credentials = load_credentials(settings.kortex.credentials_file, env=env)
    return KortexArm(robot, str(address), credentials, kortex_options(settings), api=api,
                     workspace=workspace, acceleration_limit=acceleration_limit)


def kortex_bring_up_blocker(settings, robot: str | None = None,
                            env: Mapping[str, str] | None = None) -> str | None:
    """Why the Kortex backend cannot contact an arm (``--check``, ``--home``, a run), as one line
    naming what is missing: the address, the credentials, and with ``robot`` (the policy's
    ``task.robot``) a ``kortex.models`` entry for it (connect would refuse the arm); None when
    nothing is."""
    if not settings.kortex.address:
        return ("--backend kortex: deploy.kortex.address is not set (the arm's IP address; there "
                "is no default)")
    try:
        load_credentials(settings.kortex.credentials_file, env=env)
    except CredentialsError as error:
        return f"--backend kortex: {error}"
    if robot is not None and robot not in settings.kortex.models:
        return _no_model(robot)
    return None


def _no_model(robot: str | None) -> str:
    """The one line for a policy whose robot has no ``kortex.models`` entry."""
    named = "the policy's robot" if robot is None else f"the policy's robot {robot!r}"
    where = "configs/robots/<arm>.yaml" if robot is None else f"configs/robots/{robot}.yaml"
    return (f"--backend kortex: {named} has no deploy.kortex.models entry ({where} kortex), so connect "
            "would refuse the arm: deploy a policy trained on a Kortex arm (task.robot=gen3); the arm "
            "was not contacted (docs/kortex.md)")


def kortex_deploy_blocker(settings, env: Mapping[str, str] | None = None,
                          robot: str | None = None) -> str | None:
    """Why ``python -m ahrm_stack.deploy --backend kortex`` cannot run, as one line naming the
    first thing missing: the address, the credentials (:func:`kortex_bring_up_blocker`), real-time
    pacing, a policy whose robot (``robot``, its ``task.robot``) has a ``kortex.models`` entry
    (connect would refuse the arm), and a scene source (``kortex.scene``, the static layout the
    run's ``perception()`` reads, as ``kinova_gen2.scene``; required with ``--scene camera`` too);
    None when nothing is. The arm is not contacted. ``--check`` and ``--home`` need no scene."""
    blocker = kortex_bring_up_blocker(settings, env=env)
    if blocker is not None:
        return blocker
    if not settings.realtime:
        return "--backend kortex: --fast / deploy.realtime false is for the sim backend only"
    if robot is None or robot not in settings.kortex.models:
        return _no_model(robot)
    if settings.kortex.scene is None:
        return (f"--backend kortex: {scene_unset('deploy.kortex.scene')}, the run's scene source "
                "(with --scene camera too); the arm was not contacted (docs/kortex.md, Deploy)")
    return None
