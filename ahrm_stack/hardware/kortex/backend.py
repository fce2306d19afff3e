"""Deploy wiring: the Kortex adapter built from the deploy settings, and why deploy cannot run it
yet."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.hardware.kortex.arm import KortexArm, KortexNotInstalledError
from ahrm_stack.hardware.kortex.credentials import Credentials, CredentialsError, load_credentials
from ahrm_stack.hardware.kortex.settings import kortex_options
from ahrm_stack.hardware.kortex.vendor_link import INSTALL_HINT, LinkError, import_modules
from ahrm_stack.hardware.protocol import HardwareError


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
                        workspace: np.ndarray | None = None) -> KortexArm:
    """The Kortex adapter for a deploy run, not yet connected.

    Args:
        settings: validated deploy settings (``ahrm_stack.deploy.DeploySettings``): the
            ``kortex`` section (address, credentials file, timeouts, watchdog, reset, the
            ``kortex_api`` interpreter, the arm models, protection zones) and the control period.
        robot: the deployed arm model (a checkpoint's own).
        credentials: the login; default :func:`load_credentials` from ``kortex.credentials_file``
            or the environment (``env``, default ``os.environ``).
        api: vendor modules to use in this process (default: ``kortex_api`` in a child process
            under ``kortex.python``).
        workspace: the task workspace in the arm's base frame
            (:func:`ahrm_stack.hardware.kortex.zones.task_workspace`), checked against protection zones.

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
                     workspace=workspace)


def kortex_deploy_blocker(settings, env: Mapping[str, str] | None = None) -> str:
    """Why ``python -m ahrm_stack.deploy --backend kortex`` cannot run yet, as one line naming what
    is missing: the address, credentials, real-time pacing, and in any case an arm model to run (no
    Gen3 description is trained on yet: ``kortex.models`` is empty, so connect would refuse every
    arm's model) with the deploy command's Kortex path wired to the camera scene source (a static
    layout is not used in its place: the cube moves when pushed, so a static pose would keep the
    controller pushing at where the cube was and miss success)."""
    if not settings.kortex.address:
        return ("--backend kortex: deploy.kortex.address is not set (the arm's IP address; there "
                "is no default)")
    try:
        load_credentials(settings.kortex.credentials_file, env=env)
    except CredentialsError as error:
        return f"--backend kortex: {error}"
    if not settings.realtime:
        return "--backend kortex: --fast / deploy.realtime false is for the sim backend only"
    return ("--backend kortex: no Gen3 policy to run yet (deploy.kortex.models is empty: no Gen3 arm "
            "description is trained on, and connect refuses an arm whose model is not listed) and the "
            "deploy command's Kortex path is not wired to --scene camera; the arm was not contacted "
            "(docs/kortex.md, Deploy)")
