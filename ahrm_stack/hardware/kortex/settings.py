"""The Kortex backend's numbers, from ``configs/deploy.yaml``'s ``kortex`` section (validated by
``ahrm_stack.deploy.settings.KortexSection``); :func:`kortex_options` turns them into the units the
adapter uses."""

from __future__ import annotations

import dataclasses
from typing import Mapping


@dataclasses.dataclass(frozen=True)
class KortexModel:
    """The Kortex arm a robot description is: ``ProductConfiguration`` ``model`` (a ``ModelId``
    name, e.g. ``MODEL_ID_L53``, the Gen3) and ``degree_of_freedom``."""

    model: str
    dof: int


@dataclasses.dataclass(frozen=True)
class KortexOptions:
    """The backend's numbers (``configs/deploy.yaml``, ``kortex``; see :func:`kortex_options`).

    Attributes:
        port: Kortex TCP port.
        session_inactivity_timeout_ms, connection_inactivity_timeout_ms: the arm closes the
            session / stops itself when the link is silent this long (ms).
        rpc_timeout_ms: timeout of every feedback, motion and mode RPC (ms).
        session_rpc_timeout_ms: timeout of CreateSession / CloseSession and of the reads on
            connect (product configuration, joint limits, protection zones) (ms).
        lost_link_stop_timeout_ms: timeout of the best-effort ``Base.Stop`` (and of closing the
            session) sent when the link is lost (ms).
        watchdog_timeout: s without a fresh command (while moving) before the watchdog stops the arm.
        watchdog_poll: s between two checks of the watchdog thread.
        reset_wait: s :meth:`KortexArm.clear_faults` waits for the arm to leave fault.
        reset_poll: s between two feedback polls during that wait.
        reset_estop_repeats: ApplyEmergencyStop calls before ClearFaults (ros2_kortex: 2).
        python: the interpreter that runs ``kortex_api`` in its own process ('' : this one).
        process_start_timeout_ms: that process must import ``kortex_api`` and answer this fast (ms).
        process_margin_ms: it must answer each call within the call's timeout plus this (ms); else
            it is killed and the link counts as lost.
        models: robot description name (``task.robot``) -> the Kortex arm it is.
        speed_limit_tolerance: fraction by which the description's joint velocity limit may exceed
            the arm's joint speed hard limit.
        refuse_zones_in_workspace: refuse to connect when an enabled protection zone reaches into
            the task workspace (else: report it only).
        workspace_height: m above the table top that the task workspace reaches.
        soft_limit_modes: ``ControlConfig.ControlMode`` names whose joint speed (and acceleration)
            soft limits must allow the policy's (the lowest over them, per joint).
        soft_limit_tolerance: fraction by which the policy's limit may exceed that soft limit.
        action_rpc_timeout_ms: timeout of ExecuteAction, OnNotificationActionTopic and Unsubscribe (ms).
        contact_torques: the actuators' torques, read with every frame, feed the deploy loop's
            contact stop (:attr:`KortexArm.torque_every_frame`).
    """

    port: int
    session_inactivity_timeout_ms: int
    connection_inactivity_timeout_ms: int
    rpc_timeout_ms: int
    session_rpc_timeout_ms: int
    lost_link_stop_timeout_ms: int
    watchdog_timeout: float
    watchdog_poll: float
    reset_wait: float
    reset_poll: float
    reset_estop_repeats: int
    python: str = ""
    process_start_timeout_ms: int = 20000
    process_margin_ms: int = 250
    models: Mapping[str, KortexModel] = dataclasses.field(default_factory=dict)
    speed_limit_tolerance: float = 0.0
    refuse_zones_in_workspace: bool = True
    workspace_height: float = 0.3
    soft_limit_modes: tuple[str, ...] = ("ANGULAR_JOYSTICK", "ANGULAR_TRAJECTORY")
    soft_limit_tolerance: float = 0.0
    action_rpc_timeout_ms: int = 1000
    contact_torques: bool = False


def kortex_options(settings) -> KortexOptions:
    """:class:`KortexOptions` from validated deploy settings (``ahrm_stack.deploy.DeploySettings``:
    its ``kortex`` section and control ``period``, s)."""
    k, period = settings.kortex, settings.period
    return KortexOptions(
        port=k.port, session_inactivity_timeout_ms=k.session_inactivity_timeout_ms,
        connection_inactivity_timeout_ms=k.connection_inactivity_timeout_ms,
        rpc_timeout_ms=k.rpc_timeout_ms, session_rpc_timeout_ms=k.session_rpc_timeout_ms,
        lost_link_stop_timeout_ms=k.lost_link_stop_timeout_ms,
        watchdog_timeout=k.watchdog_periods * period, watchdog_poll=k.watchdog_poll_periods * period,
        reset_wait=k.reset_wait_ms / 1e3, reset_poll=k.reset_poll_ms / 1e3,
        reset_estop_repeats=k.reset_estop_repeats, python=k.python or "",
        process_start_timeout_ms=k.process_start_timeout_ms,
        process_margin_ms=k.process_margin_ms,
        models={name: KortexModel(m.model, m.dof) for name, m in k.models.items()},
        speed_limit_tolerance=k.speed_limit_tolerance,
        refuse_zones_in_workspace=k.refuse_zones_in_workspace,
        workspace_height=k.workspace_height, soft_limit_modes=tuple(k.soft_limit_modes),
        soft_limit_tolerance=k.soft_limit_tolerance, action_rpc_timeout_ms=k.action_rpc_timeout_ms,
        contact_torques=k.contact_torques)
