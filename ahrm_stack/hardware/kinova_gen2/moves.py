"""The Gen2 adapter's position moves for ``--home`` (:class:`Gen2Moves`, a base of
:class:`~ahrm_stack.hardware.kinova_gen2.arm.KinovaGen2Arm`): Kinova's ``MoveHome`` where it can be
stopped, and one ``ANGULAR_POSITION`` point at a speed limit. The supervision (positions read,
faults, timeouts, Ctrl-C) is :mod:`ahrm_stack.hardware.kinova_gen2.home`'s.

**MoveHome blocks.** Disassembled (the vendored ``USBCommandLayerUbuntu.so``;
``tests/test_kinova_gen2_move_home.py`` reads its instructions), it sends the home packet, sleeps
40 ms, reads ``GetGlobalTrajectoryInfo`` every 100 ms until the arm's trajectory FIFO holds no
point, then calls ``SetAngularControl``, sleeps 40 ms and calls ``SetCartesianControl``: it returns
only when the arm is home, and leaves it in Cartesian control. On the USB thread it would hold back
every other call for the whole move: no position read, no status poll (e-stop, error log), no stop.

So it runs on a thread of its own (:class:`MoveHomeThread`), outside :class:`~.sdk.Sdk`'s lock
(:meth:`~.sdk.Sdk.call_blocking`). Kinova's SDK serialises its USB traffic per packet itself
(``SendGetCommand`` and ``SendSetCommand`` each ``sem_wait`` on the library's ``mutex``), so the USB
thread's reads and stops go on between MoveHome's polls. A stop (zero velocity,
``EraseAllTrajectories``) empties the FIFO, which is what MoveHome waits for: it returns within one
poll and its 40 ms tail. Nothing else is sent until it has returned (:meth:`Gen2Moves.end_move_home`),
so that its closing ``SetCartesianControl`` cannot land after the next move's ``SetAngularControl``;
and ``CloseAPI`` waits for it (:meth:`Gen2Moves._move_home_returned`).
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ahrm_stack.hardware.kinova_gen2.faults import Gen2Faults
from ahrm_stack.hardware.kinova_gen2.sdk import Sdk, position_point
from ahrm_stack.hardware.kinova_gen2.settings import JointConvention, kinova_positions
from ahrm_stack.hardware.protocol import HardwareError

if TYPE_CHECKING:
    from ahrm_stack.robot import RobotDescription

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")

#: s MoveHome may take to return once its FIFO is empty: one 100 ms poll, its 40 ms tail and three
#: calls of a few ms, with margin for a loaded machine
RETURN_WITHIN = 0.5


class MoveHomeThread:
    """``MoveHome`` running on a daemon thread of its own (see the module docstring); its error,
    if the call failed, is kept in :attr:`error`."""

    def __init__(self, sdk: Sdk, serial: str) -> None:
        self._sdk = sdk
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=f"kinova-gen2-movehome-{serial}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._sdk.call_blocking("MoveHome")
        except BaseException as error:  # noqa: BLE001 - kept for the caller
            self.error = error

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def join(self, timeout: float = RETURN_WITHIN) -> bool:
        """Wait up to ``timeout`` s for MoveHome to return; True when it has."""
        self._thread.join(timeout)
        return not self._thread.is_alive()


class Gen2Moves(Gen2Faults):
    """Position moves of the Gen2 adapter; the adapter sets the attributes below and defines the
    USB thread's helpers."""

    _sdk: Sdk | None
    _convention: JointConvention
    _robot: RobotDescription
    _move_home: MoveHomeThread | None = None

    def _halt(self, then: Callable[[Any], None] | None = None, hold: bool = False) -> None:
        raise NotImplementedError

    def _on_bus(self, job: Callable[[Any], Any]) -> Any:
        raise NotImplementedError

    def _read_position(self, sdk: Sdk) -> tuple[np.ndarray, float]:
        raise NotImplementedError

    def _position_move(self, job) -> np.ndarray:
        """Stop any velocity command, then ``job(sdk)`` (one position move) on the USB thread, in
        angular control with an empty FIFO; refused in fault (:class:`ArmFaultError`) or while
        MoveHome has not returned."""
        self._refuse_in_fault()
        if self._move_home is not None and self._move_home.running:
            raise HardwareError("MoveHome has not returned: end_move_home() first")
        self._halt()

        def move(sdk: Sdk) -> np.ndarray:
            sdk.call("SetAngularControl")
            sdk.call("EraseAllTrajectories")
            return job(sdk)

        return self._on_bus(move)

    def move_home(self) -> None:
        """``MoveHome``: the firmware moves the arm to its factory home at its own speed (as the
        joystick's home button; kinova-ros's homeArm), on a thread of its own (the module
        docstring). Returns at once; :meth:`stop` stops the arm and so ends MoveHome;
        :meth:`end_move_home` waits for it to return."""
        self._position_move(lambda sdk: None)
        assert self._sdk is not None
        self._move_home = MoveHomeThread(self._sdk, self._serial)
        log.warning("kinova_gen2: MoveHome sent to %s (the firmware's factory home)", self._serial)

    @property
    def move_home_running(self) -> bool:
        """MoveHome is inside the SDK (the arm on its way home, or its return pending)."""
        return self._move_home is not None and self._move_home.running

    def end_move_home(self, timeout: float = RETURN_WITHIN) -> None:
        """Wait up to ``timeout`` s for MoveHome to return (the arm home or stopped: its FIFO
        empty) and put the arm back in angular control; :class:`HardwareError` when it has not
        returned (the arm is stopped, and waited for once more: a home packet that arrived after a
        stop is erased too) or its call failed."""
        thread = self._move_home
        if thread is None:
            return
        if not thread.join(timeout):
            self._halt()
            thread.join(timeout)
            raise HardwareError(f"MoveHome did not return within {timeout:g} s of the arm's FIFO "
                                "emptying; the arm was stopped")
        self._move_home = None
        self._on_bus(lambda sdk: sdk.call("SetAngularControl"))  # MoveHome left Cartesian control
        if thread.error is not None:
            raise HardwareError(f"MoveHome: {(str(thread.error).splitlines() or [''])[0]}")

    def _move_home_returned(self) -> bool:
        """Before ``CloseAPI`` (this thread owning the USB): MoveHome (if it ran) has returned,
        waiting up to :data:`RETURN_WITHIN` s (the FIFO was just erased), then erasing once more
        (its home packet may have landed after the erase) and waiting again; False, logged, when it
        is still inside the SDK (closing the API under it is not safe: CloseAPI is then skipped).
        A Ctrl-C during the wait ends it (the arm was stopped already)."""
        thread = self._move_home
        if thread is None:
            return True
        try:
            if thread.join():
                return True
            if self._sdk is not None:
                self._sdk.call_quietly("EraseAllTrajectories")
            if thread.join():
                return True
        except KeyboardInterrupt:
            log.error("kinova_gen2: interrupted while waiting for MoveHome on %s to return", self._serial)
        log.error("kinova_gen2: MoveHome on %s has not returned after the FIFO was erased; CloseAPI "
                  "skipped", self._serial)
        return False

    def move_to(self, q: np.ndarray, speed_deg_s: float) -> np.ndarray:
        """One ANGULAR_POSITION point to the model posture ``q`` (rad), every joint at most
        ``speed_deg_s`` deg/s, the joints arriving together; a continuous joint goes the short way
        round from where it is (its Kinova angle within 180 deg of the present one). Returns the
        target sent (Kinova's deg); :meth:`stop` stops the move."""
        target = kinova_positions(np.asarray(q, dtype=float), self._convention)
        continuous = ~self._robot.limited

        def send(sdk: Sdk) -> np.ndarray:
            now, _ = self._read_position(sdk)
            goal = np.where(continuous, now + (target - now + 180.0) % 360.0 - 180.0, target)
            sdk.call("SendAdvanceTrajectory", position_point(goal, speed_deg_s))
            return goal

        goal = self._position_move(send)
        log.warning("kinova_gen2: position move of %s to %s deg at %g deg/s", self._serial,
                    np.round(goal, 1).tolist(), speed_deg_s)
        return goal
