"""A dry run: the real arm's feedback and the real scene, every command computed, filtered, checked
by the command gate and logged, and none sent.

:class:`DryRunArm` wraps a backend (``python -m ahrm_stack.deploy --dry-run``). Reads go to the
backend (feedback, perception, servoing mode, fault state); a joint-speed command passes the same
gate as a live one (connected, not in fault, single-level servoing, within the velocity limits: a
refused command still e-stops) and is then recorded here instead of sent. Stops are passed through:
a stop or an e-stop cannot move the arm, and a fault found during a dry run must stop it as it
would a live run. So the arm never moves under a dry run, and its telemetry is the live run's,
tick for tick, with a ``dry run`` event at its start.
"""

from __future__ import annotations

import numpy as np

from ahrm_stack.hardware.protocol import ArmAdapter, Fault, Feedback, ServoingMode, WallClock


class DryRunArm(ArmAdapter):
    """``arm`` with its sending replaced by a record: :attr:`withheld` counts the commands that
    passed the gate and were not sent, :attr:`last_withheld` is the latest (rad/s)."""

    def __init__(self, arm: ArmAdapter) -> None:
        self.arm = arm
        self.withheld = 0
        self.last_withheld: np.ndarray | None = None

    def __getattr__(self, name: str):  # perception() and the backend's inspection attributes
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
    def is_connected(self) -> bool:
        return self.arm.is_connected

    def connect(self) -> None:
        self.arm.connect()

    def disconnect(self) -> None:
        self.arm.disconnect()

    def refresh_feedback(self) -> Feedback:
        return self.arm.refresh_feedback()

    def _require(self):
        return self.arm._require()

    def _fault_state(self) -> tuple[Fault, str]:
        return self.arm._fault_state()

    def _add_fault(self, flag: Fault, reason: str) -> None:
        self.arm._add_fault(flag, reason)

    def _send(self, command: np.ndarray) -> np.ndarray:
        """The gate passed it: record it, send nothing."""
        self.withheld += 1
        self.last_withheld = np.array(command, dtype=float)
        return self.last_withheld

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
