"""The Kortex adapter's position move for ``--home`` (:class:`KortexMoves`, a base of
:class:`~ahrm_stack.hardware.kortex.arm.KortexArm`): one ``Base.ExecuteAction`` of a
``ReachJointAngles`` action, as Kinova's api_python/examples/102-Movement_high_level/
01-move_angular_and_cartesian.py sends it, and its ``ACTION_*`` notifications, read without waiting.
The supervision (feedback polled, the timeout, faults, Ctrl-C, Stop) is
:mod:`ahrm_stack.hardware.kortex.home`'s.

Kinova's example blocks on a ``threading.Event`` set by the notification callback
(``e.wait(TIMEOUT_DURATION)``): nothing could be read or stopped during the wait. Here the link
queues the notifications (:meth:`~ahrm_stack.hardware.kortex.vendor_link.VendorLink.call`
``("action_events")``) and the supervision reads them at its poll rate, between two feedback
reads, so a Stop goes out at once whatever the action does.

The target goes out in the convention the arm reports its angles in (continuous joints in
[0, 360) deg, limited ones in (-180, 180] deg). **Not verified on hardware:** that the arm takes a
continuous joint the short way round to it (ros_kortex's simulated arm,
kortex_driver/src/non-generated/driver/kortex_arm_simulation.cpp ``ExecuteReachJointAngles``,
keeps the turns it is on); the supervision stops the arm when any joint strays from the planned
straight joint-space path (``kortex.home.path_tolerance_deg``), which a long way round does.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ahrm_stack.hardware.protocol import ArmFaultError, Fault, HardwareError, ServoingMode

log = logging.getLogger("ahrm_stack.hardware.kortex")

ACTION_NAME = "ahrm-stack home"  # Action.name of the homing move (shown in Kinova's Web App)
#: ``Base.ActionEvent`` names that end an action (enums/Base/ActionEvent.md)
ACTION_END, ACTION_ABORT = "ACTION_END", "ACTION_ABORT"


def kortex_degrees(q: np.ndarray, continuous: np.ndarray) -> np.ndarray:
    """Model angles (rad) -> the arm's reporting convention (deg): continuous joints in [0, 360),
    limited ones in (-180, 180]."""
    deg = np.degrees(np.asarray(q, dtype=float))
    return np.where(continuous, np.mod(deg, 360.0), 180.0 - np.mod(180.0 - deg, 360.0))


class KortexMoves:
    """The action move of the Kortex adapter; the adapter sets the attributes below."""

    _robot: Any
    _options: Any
    _mode: ServoingMode
    _address: str

    def _require(self) -> None:
        raise NotImplementedError

    def _call(self, what: str, method: str, timeout_ms: int, **args: Any) -> Any:
        raise NotImplementedError

    def _fault_state(self) -> tuple[Fault, str]:
        raise NotImplementedError

    @property
    def address(self) -> str:
        """The arm's address (what ``--home`` asks the user to type)."""
        return self._address

    @property
    def fault_reason(self) -> str:
        """Why the adapter or the arm's last feedback reports a fault ('' when none)."""
        return self._fault_state()[1]

    def subscribe_actions(self) -> None:
        """``Base.OnNotificationActionTopic``: the arm's action events are queued from now on
        (before :meth:`move_to`, so that none is missed)."""
        self._require()
        self._call("OnNotificationActionTopic", "subscribe_actions", self._options.action_rpc_timeout_ms)

    def move_to(self, q: np.ndarray, speed_deg_s: float) -> np.ndarray:
        """``Base.ExecuteAction``: a ``ReachJointAngles`` action to the model posture ``q`` (rad)
        with a ``JOINT_CONSTRAINT_SPEED`` of ``speed_deg_s`` (deg/s). Returns the target sent
        (deg); :meth:`stop` (``Base.Stop``) ends the action (the arm reports ``ACTION_ABORT``).
        Refused (:class:`ArmFaultError`) in fault, and outside single-level servoing."""
        self._require()
        faults, reason = self._fault_state()
        if faults != Fault.NONE:
            raise ArmFaultError(f"the arm is in fault ({faults!r}: {reason}): clear_faults() first")
        if self._mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise HardwareError("an action needs single-level servoing (set_servoing_mode)")
        goal = kortex_degrees(q, ~self._robot.limited)
        self._call("ExecuteAction", "execute_joint_angles", self._options.action_rpc_timeout_ms,
                   angles=[float(v) for v in goal], speed_deg_s=float(speed_deg_s), name=ACTION_NAME)
        log.warning("kortex: %s: ReachJointAngles to %s deg at %g deg/s", self._address,
                    np.round(goal, 1).tolist(), speed_deg_s)
        return goal

    def action_events(self) -> list[dict]:
        """The action notifications received since the last call (``event``: a
        ``Base.ActionEvent`` name, ``abort_details``); never waits."""
        self._require()
        return list(self._call("action events", "action_events", self._options.rpc_timeout_ms))

    def unsubscribe_actions(self) -> None:
        """``Base.Unsubscribe`` of the action topic; a failure is logged only."""
        try:
            self._require()
            self._call("Unsubscribe", "unsubscribe", self._options.action_rpc_timeout_ms)
        except HardwareError as error:
            log.error("kortex: Unsubscribe failed: %s", error)
