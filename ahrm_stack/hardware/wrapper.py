"""An adapter around another: every protocol call goes to the wrapped backend (``arm``).

The base of the adapters that add one thing to a backend: a scene source
(:class:`~ahrm_stack.hardware.scene.PerceivedArm`) or a dry run that sends nothing
(:class:`~ahrm_stack.hardware.dry_run.DryRunArm`). Attributes the protocol does not name (the
backend's inspection attributes, ``perception()`` of a wrapped wrapper) are looked up on ``arm``.
"""

from __future__ import annotations

import numpy as np

from ahrm_stack.hardware.protocol import ArmAdapter, Fault, Feedback, ServoingMode, WallClock


class ArmWrapper(ArmAdapter):
    """``arm`` behind the protocol, unchanged: subclasses override what they add."""

    def __init__(self, arm: ArmAdapter) -> None:
        self.arm = arm

    def __getattr__(self, name: str):  # inspection attributes of the wrapped backend
        if name == "arm":
            raise AttributeError(name)
        return getattr(self.arm, name)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.arm.joint_names

    @property
    def velocity_limit(self) -> np.ndarray:
        return self.arm.velocity_limit

    @property
    def clock(self) -> WallClock:
        return self.arm.clock

    @property
    def torque_every_frame(self) -> bool:
        return self.arm.torque_every_frame

    @property
    def is_connected(self) -> bool:
        return self.arm.is_connected

    def connect(self) -> None:
        self.arm.connect()

    def disconnect(self) -> None:
        self.arm.disconnect()

    def refresh_feedback(self) -> Feedback:
        return self.arm.refresh_feedback()

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        return self.arm.send_joint_speeds(speeds)  # the wrapped backend's gate, once

    # the gate's hooks: the wrapped backend's (its gate runs them; see send_joint_speeds)
    def _require(self):
        return self.arm._require()

    def _fault_state(self) -> tuple[Fault, str]:
        return self.arm._fault_state()

    def _add_fault(self, flag: Fault, reason: str) -> None:
        self.arm._add_fault(flag, reason)

    def _send(self, command: np.ndarray) -> np.ndarray:
        return self.arm._send(command)

    def stop(self) -> None:
        self.arm.stop()

    def apply_emergency_stop(self) -> None:
        self.arm.apply_emergency_stop()

    def clear_faults(self) -> None:
        self.arm.clear_faults()

    @property
    def servoing_mode(self) -> ServoingMode:
        return self.arm.servoing_mode

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self.arm.set_servoing_mode(mode)
