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

from ahrm_stack.hardware.protocol import ArmAdapter
from ahrm_stack.hardware.wrapper import ArmWrapper


class DryRunArm(ArmWrapper):
    """``arm`` with its sending replaced by a record: :attr:`withheld` counts the commands that
    passed the gate and were not sent, :attr:`last_withheld` is the latest (rad/s)."""

    def __init__(self, arm: ArmAdapter) -> None:
        super().__init__(arm)
        self.withheld = 0
        self.last_withheld: np.ndarray | None = None

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        """The command gate, run here on the wrapped backend's state (its hooks), then
        :meth:`_send`: the backend's own gate would send."""
        return ArmAdapter.send_joint_speeds(self, speeds)

    def _send(self, command: np.ndarray) -> np.ndarray:
        """The gate passed it: record it, send nothing."""
        self.withheld += 1
        self.last_withheld = np.array(command, dtype=float)
        return self.last_withheld
