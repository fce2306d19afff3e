"""The Gen2 adapter's fault state (:class:`Gen2Faults`, the base of
:class:`~ahrm_stack.hardware.kinova_gen2.arm.KinovaGen2Arm`): the fault flags and their reason, shared by the
control thread and the USB thread under one lock; the status poll's steps, run on the USB thread
(supply voltage, the system error log, the torques); and :meth:`Gen2Faults._latch`, which enters
fault and stops the arm at once (:class:`FaultStop`).

A new entry in the arm's system error log (``GetSystemErrorCount`` / ``GetSystemError``) is
``Fault.HARDWARE``; a supply voltage below ``kinova_gen2.min_supply_voltage`` (``GetSensorsInfo``)
or a logged voltage error is the e-stop cutting the actuators' power (``Fault.EMERGENCY_STOP``).
"""

from __future__ import annotations

import ctypes
import dataclasses
import logging
import threading
import time

import numpy as np

from ahrm_stack.hardware.kinova_gen2.bus import UsbBus, WatchdogStop, is_link_error
from ahrm_stack.hardware.kinova_gen2.sdk import (SYSTEM_ERROR_TYPES, VOLTAGE_ERROR, AngularPosition, Sdk,
                                      SensorsInfo, SystemError, actuators)
from ahrm_stack.hardware.kinova_gen2.settings import Gen2Settings
from ahrm_stack.hardware.protocol import DescribedArm, Fault

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")


@dataclasses.dataclass(frozen=True)
class FaultStop:
    """A fault the adapter found by itself (the status poll, a failed call of the USB thread):
    ``detected_at`` (perf_counter s) when the read that showed it returned, ``stopped_at`` when the
    FIFO was erased after a zero-velocity point (None if the arm could not be reached), ``reason``."""

    detected_at: float
    stopped_at: float | None
    reason: str


class Gen2Faults(DescribedArm):
    """The fault state of a Gen2 adapter and the status poll's steps (see the module docstring).
    The adapter sets the attributes below in its ``__init__``."""

    settings: Gen2Settings
    _serial: str
    _sign: np.ndarray
    _bus: UsbBus | None
    _status: threading.Lock  # guards the fields below: the USB thread writes them
    _faults: Fault
    _fault_reason: str
    _errors_seen: int
    _voltage: float
    _torque: np.ndarray
    fault_stops: list[FaultStop]

    @property
    def faults(self) -> Fault:
        """The fault flags as of now (the status poll's and the adapter's own)."""
        with self._status:
            return self._faults

    @property
    def fault_reason(self) -> str:
        """Why the adapter is in fault ('' when it is not)."""
        with self._status:
            return self._fault_reason

    def _fault_state(self) -> tuple[Fault, str]:
        with self._status:
            return self._faults, self._fault_reason

    def _add_fault(self, flag: Fault, reason: str) -> None:
        with self._status:
            self._faults |= flag
            self._fault_reason = reason

    def _watchdog_stopped(self, stop: WatchdogStop) -> None:
        """The USB thread's command watchdog stopped the arm (on that thread, which now holds it
        stopped): ``Fault.WATCHDOG`` until :meth:`clear_faults`, as the protocol says."""
        self._add_fault(Fault.WATCHDOG, stop.reason)
        log.error("kinova_gen2: arm %s in fault: %s; clear_faults() to move again", self._serial,
                  stop.reason)

    # ------------------------------------------------------------------ the status poll (USB thread)
    def _read_sensors(self, sdk: Sdk) -> None:
        """GetSensorsInfo: a supply voltage below ``min_supply_voltage`` is the e-stop."""
        sensors = SensorsInfo()
        sdk.call("GetSensorsInfo", ctypes.byref(sensors))
        at = time.perf_counter()
        with self._status:
            self._voltage = float(sensors.Voltage)
        if sensors.Voltage < self.settings.min_supply_voltage:
            self._latch(Fault.EMERGENCY_STOP | Fault.HARDWARE,
                        f"supply voltage {sensors.Voltage:.1f} V below "
                        f"{self.settings.min_supply_voltage:g} V (e-stop pressed or power lost)", at)

    def _read_error_log(self, sdk: Sdk) -> None:
        """GetSystemErrorCount, and GetSystemError for each new entry: new entries put the adapter
        in fault (the ``...OK`` entries, a condition ending, do not)."""
        count = ctypes.c_uint(0)
        sdk.call("GetSystemErrorCount", ctypes.byref(count))
        at = time.perf_counter()
        with self._status:
            seen = self._errors_seen
            if count.value <= seen:
                self._errors_seen = min(seen, int(count.value))
                return
        for index in range(seen, int(count.value)):
            entry = SystemError()
            sdk.call("GetSystemError", ctypes.c_uint(index), ctypes.byref(entry))
            kind = entry.ErrorType
            name = SYSTEM_ERROR_TYPES[kind] if 0 <= kind < len(SYSTEM_ERROR_TYPES) else f"type {kind}"
            if name.endswith("OK"):
                log.info("kinova_gen2: arm %s reports %s", self._serial, name)
                continue
            fault = Fault.HARDWARE | (Fault.EMERGENCY_STOP if kind == VOLTAGE_ERROR else Fault.NONE)
            self._latch(fault, f"the arm logged system error {name}", at)
        with self._status:
            self._errors_seen = int(count.value)

    def _read_torques(self, sdk: Sdk) -> None:
        """GetAngularForce: the joint torques (N·m, model signs) of the next feedback frames."""
        force = AngularPosition()
        sdk.call("GetAngularForce", ctypes.byref(force))
        torque = self._sign * actuators(force.Actuators, self.num_joints)
        with self._status:
            self._torque = torque

    def _latch(self, fault: Fault, reason: str, detected_at: float) -> None:
        """Enter fault: no standing command; on a new fault, zero velocity and an empty FIFO now
        (on the USB thread, before any other call) and the stop recorded."""
        with self._status:
            new = Fault(fault) & ~self._faults
            self._faults |= fault
            self._fault_reason = reason
        bus = self._bus
        if not new:
            if bus is not None:
                bus.drop()
            return
        log.error("kinova_gen2: arm %s in fault: %s", self._serial, reason)
        stopped_at = None
        if bus is not None:
            try:
                stopped_at = bus.halt(hold=True)
            except Exception as error:  # noqa: BLE001 - the lost link surfaces at the next call
                log.error("kinova_gen2: could not stop %s on its fault (%s)", self._serial, error)
                if bus.on_thread() and is_link_error(error):
                    raise
        with self._status:
            self.fault_stops.append(FaultStop(detected_at, stopped_at, reason))

