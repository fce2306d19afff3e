"""The Gen2 adapter, :class:`KinovaGen2Arm`: the session (connect, disconnect, a lost link), the
feedback, the commands and the faults (the status poll's steps, run on the USB thread); the homing
moves are :mod:`~ahrm_stack.hardware.kinova_gen2.moves`'s. The design (one USB thread, the points,
the watchdog, the faults) is the package's docstring, :mod:`ahrm_stack.hardware.kinova_gen2`.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import ctypes
import logging
import math
import sys
import threading
import time
import weakref
from typing import TYPE_CHECKING, Iterator

import numpy as np

from ahrm_stack.hardware.kinova_gen2.bus import (BusClosedError, BusHeldError, CallTimes, UsbBus, WatchdogStop,
                                      is_link_error)
from ahrm_stack.hardware.kinova_gen2.faults import FaultStop
from ahrm_stack.hardware.kinova_gen2.lock import lock_warning
from ahrm_stack.hardware.kinova_gen2.moves import Gen2Moves
from ahrm_stack.hardware.kinova_gen2.sdk import (ERROR_LOAD_COMM_DLL, ERROR_NO_DEVICE_FOUND, AngularInfo,
                                                 AngularPosition, QuickStatus, Sdk, SdkCallError, SensorsInfo,
                                                 actuators, velocity_point)
from ahrm_stack.hardware.kinova_gen2.settings import (DOCS, Gen2ConfigError, Gen2Settings, JointConvention,
                                           check_library, joint_convention, robot_type_refusal, setting_key,
                                           kinova_velocities, model_positions,
                                           model_velocities)
from ahrm_stack.hardware.protocol import (ArmFaultError, ArmState, ConnectionLostError, Fault, Feedback,
                               HardwareError, NotConnectedError, ServoingMode, WallClock,
                               range_centres, unwrap_positions)

if TYPE_CHECKING:
    from ahrm_stack.robot import RobotDescription

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")


_LIVE: "weakref.WeakSet[KinovaGen2Arm]" = weakref.WeakSet()


@atexit.register
def _disconnect_all() -> None:  # pragma: no cover - runs at interpreter exit
    for arm in list(_LIVE):
        try:
            arm.disconnect()
        except Exception:  # noqa: BLE001 - exiting
            pass


class KinovaGen2Arm(Gen2Moves):
    """A Kinova Gen2 arm (JACO2) over the C SDK, every call through one USB thread
    (:class:`~ahrm_stack.hardware.kinova_gen2.bus.UsbBus`: the 100 Hz points, the command watchdog, the status
    poll; see the module docstring).

    Args:
        robot: the arm model the controller was trained on (its joint count must be the arm's).
        settings: the ``kinova_gen2`` section (library, serial, rates, joint conventions).
        command_timeout_s: s without a fresh command before the USB thread stops the arm
            (``settings.command_timeout`` control periods; the caller knows the period).
    """

    @property
    def torque_every_frame(self) -> bool:
        """``kinova_gen2.torque_each_tick``: the torques read with each frame's positions (one USB
        call more per tick); else they are one step of the status poll (``status_rate_hz``) and the
        deploy loop's contact stop is off on this backend."""
        return self.settings.torque_each_tick

    def __init__(self, robot: RobotDescription, settings: Gen2Settings,
                 command_timeout_s: float) -> None:
        if not command_timeout_s > 0:
            raise Gen2ConfigError(f"the command timeout must be > 0 s, got {command_timeout_s!r}")
        if robot.num_joints > len(AngularInfo._fields_):
            raise Gen2ConfigError(f"{robot.name} has {robot.num_joints} joints; a Gen2 arm has at "
                                  f"most {len(AngularInfo._fields_)} actuators")
        self._robot = robot
        self.settings = settings
        self._convention = joint_convention(settings, robot)
        self._sign = np.asarray(self._convention.sign, dtype=float)
        self._library = check_library(settings)
        if settings.serial is None:
            raise Gen2ConfigError(f"{setting_key('serial')} is not set: the arm is chosen by its serial "
                                  "number, never the first one found")
        self._serial = settings.serial
        self._timeout = float(command_timeout_s)
        self._clock = WallClock()
        self._sdk: Sdk | None = None
        self._bus: UsbBus | None = None
        self._connected = False
        self._api_open = False  # InitAPI was called: CloseAPI is due (valid whatever InitAPI returned)
        self._control_started = False  # StartControlAPI succeeded: trajectory calls are valid
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._range_centre = range_centres(robot)
        self._switch_interval = sys.getswitchinterval()
        # the control thread's: the last position read (velocity from position differences)
        self._frame = 0
        self._last_position: np.ndarray | None = None
        self._reads: collections.deque[tuple[float, np.ndarray]] = collections.deque(maxlen=64)  # (stamp,
        # model rad) of recent position reads: the velocity's reference
        # shared with the USB thread (its status poll), under _status
        self._status = threading.Lock()
        self._faults = Fault.NONE
        self._fault_reason = ""
        self._errors_seen = 0
        self._voltage = math.nan  # V, the last GetSensorsInfo
        self._torque = np.zeros(robot.num_joints)  # N·m (model signs), the last GetAngularForce
        self.fault_stops: list[FaultStop] = []
        self.watchdog_stops: list[WatchdogStop] = []  # the USB thread's, over every connection
        self._points_before = 0  # points sent on earlier connections

    # ------------------------------------------------------------------ description
    @property
    def serial(self) -> str:
        return self._serial

    @property
    def convention(self) -> JointConvention:
        """This arm's joint convention (``kinova_gen2.joints.<arm>``)."""
        return self._convention

    @property
    def command_timeout(self) -> float:
        """s without a fresh command before the USB thread stops the arm."""
        return self._timeout

    @property
    def bus(self) -> UsbBus | None:
        """The USB thread while connected (its points, watchdog stops, call times)."""
        return self._bus

    @property
    def sends(self) -> int:
        """Trajectory points carrying a standing command (``SendAdvanceTrajectory`` calls by the
        USB thread), over every connection."""
        return self._points_before + (self._bus.points if self._bus is not None else 0)

    @property
    def call_times(self) -> CallTimes | None:
        """Durations of every SDK call made (per function), or None before the first connect."""
        return self._sdk.times if self._sdk is not None else None

    # ------------------------------------------------------------------ session
    def connect(self) -> None:
        """Open the API, select the arm by serial, start control (start, stop, start: on a cold
        boot the arm may not respond to the first StartControlAPI, as kinova-ros does it), angular
        control, an empty FIFO and a zero point; read the error count, the sensors, the torques and
        the position (the first velocity's reference); then start the USB thread."""
        if self._connected:
            raise HardwareError(f"KinovaGen2Arm({self._serial}) is already connected")
        if self._sdk is None:
            self._sdk = Sdk(self._library)
        sdk = self._sdk
        warning = lock_warning()  # a stuck machine-wide lock would hang the calls below
        if warning is not None:
            log.warning("kinova_gen2: %s", warning)
        try:
            self._api_open = True
            try:
                sdk.call("InitAPI")
            except SdkCallError as error:
                raise HardwareError(self._init_failure(error)) from None
            devices = sdk.devices()
            serials = [d.SerialNumber.decode(errors="replace") for d in devices]
            chosen = [d for d, s in zip(devices, serials) if s == self._serial]
            if not chosen:
                raise HardwareError(f"no Kinova arm with serial {self._serial!r} (found: "
                                    f"{serials or 'none'}); set deploy.kinova_gen2.serial")
            sdk.call("SetActiveDevice", chosen[0])
            status = QuickStatus()  # which kind of arm: refused before control starts if not the model's
            sdk.call("GetQuickStatus", ctypes.byref(status))
            if refusal := robot_type_refusal(int(status.RobotType), self._convention, self._serial, self._robot.name):
                raise HardwareError(refusal)
            sdk.call("StartControlAPI")
            self._control_started = True
            sdk.call("StopControlAPI")  # the cold-boot kick (kinova-ros kinova_comm.cpp)
            sdk.call("StartControlAPI")
            sdk.call("SetAngularControl")
            sdk.call("EraseAllTrajectories")
            sdk.call("SendAdvanceTrajectory", velocity_point(np.zeros(self.num_joints)))
            count = ctypes.c_uint(0)
            sdk.call("GetSystemErrorCount", ctypes.byref(count))
            with self._status:
                self._errors_seen = int(count.value)
                self._faults, self._fault_reason = Fault.NONE, ""
            self._read_sensors(sdk)
            self._read_torques(sdk)
            degrees, stamp = self._read_position(sdk)
        except BaseException:
            self._close_sdk()  # every exit path leaves the arm stopped and the API closed
            raise
        self._last_position = None
        self._last_position = self._model_position(degrees)
        self._reads.clear()
        self._reads.append((stamp, self._last_position))
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        settings = self.settings
        self._bus = UsbBus(sdk, velocity_point, self.num_joints, 1.0 / settings.send_rate_hz,
                           settings.send_ahead, self._timeout, 1.0 / settings.status_rate_hz,
                           (self._read_sensors, self._read_error_log)
                           + (() if settings.torque_each_tick else (self._read_torques,)),
                           f"kinova-gen2-usb-{self._serial}", self.watchdog_stops,
                           self._watchdog_stopped)
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, settings.switch_interval))
        self._bus.start()
        self._connected = True
        _LIVE.add(self)
        comm = ", ".join(f"{path or name}" for name, path in sdk.comm_layers.items()) or "none named"
        log.info("kinova_gen2: connected to the arm with serial %s (%s Hz points, %s Hz status, "
                 "watchdog %.0f ms; communication layer: %s)", self._serial,
                 f"{settings.send_rate_hz:g}", f"{settings.status_rate_hz:g}", self._timeout * 1e3, comm)

    def _init_failure(self, error: SdkCallError) -> str:
        """One line for a failed ``InitAPI``: what the code means here and what to check."""
        if error.code == ERROR_NO_DEVICE_FOUND:
            return (f"no Kinova arm found on USB ({error}): check that the arm is powered "
                    f"on, its USB cable plugged in and the udev rule installed; see {DOCS}")
        if error.code == ERROR_LOAD_COMM_DLL:
            names = ", ".join(self._sdk.comm_layers) if self._sdk else "its communication layer"
            return (f"Kinova's communication layer did not load ({error}): the dynamic "
                    f"loader must find {names or 'it'} by name when the process starts "
                    f"(LD_LIBRARY_PATH); see {DOCS}")
        return f"InitAPI failed ({error}); see {DOCS}"

    def _close_sdk(self) -> None:
        """Leave the arm stopped and the API closed, calling only what is valid after what
        succeeded: zero velocity, erase the FIFO and StopControlAPI once StartControlAPI has
        succeeded; CloseAPI once InitAPI was called and a MoveHome has returned. Each best effort.
        Only with the USB thread ended (this thread then owns the USB)."""
        sdk = self._sdk
        if sdk is None:
            return
        if self._control_started:
            sdk.call_quietly("SendAdvanceTrajectory", velocity_point(np.zeros(self.num_joints)))
            sdk.call_quietly("EraseAllTrajectories")
        returned = self._move_home_returned()  # a MoveHome running ends once its FIFO is empty
        if self._control_started:
            sdk.call_quietly("StopControlAPI")
        if self._api_open and returned:
            sdk.call_quietly("CloseAPI")
        self._control_started = self._api_open = False

    def _stop_bus(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()
            sys.setswitchinterval(self._switch_interval)
            self._points_before += bus.points

    def disconnect(self) -> None:
        if not self._connected:
            return
        try:
            self._stop_bus()
        finally:
            self._connected = False
            self._close_sdk()
            _LIVE.discard(self)
            log.info("kinova_gen2: disconnected from %s (arm stopped, API closed)", self._serial)

    def _lose(self, error: BaseException) -> ConnectionLostError:
        """The link is gone: end the USB thread, close what can be closed, be disconnected."""
        log.error("kinova_gen2: connection to %s lost (%s)", self._serial, error)
        bus = self._bus
        failed_at = bus.closed_at if bus is not None and bus.closed_at is not None else time.perf_counter()
        self._stop_bus()
        self._connected = False
        self._close_sdk()
        _LIVE.discard(self)
        with self._status:
            self.fault_stops.append(FaultStop(failed_at, None, f"link lost: {error}"))
        return ConnectionLostError(f"the link to the Kinova arm {self._serial} was lost ({error}); "
                                   "the arm stops itself when velocity points stop")

    def _require(self) -> UsbBus:
        """The USB thread, or NotConnectedError; a failure of its own calls surfaces here (a lost
        link as ConnectionLostError, the adapter then disconnected; anything else as a fault)."""
        bus = self._bus
        if not self._connected or bus is None:
            raise NotConnectedError(f"KinovaGen2Arm({self._serial}) is not connected; call connect()")
        error = bus.take_error()
        if error is not None:
            if is_link_error(error) or not bus.running:
                raise self._lose(error)
            self._latch(Fault.COMMUNICATION, f"a call of the USB thread failed: {error}",
                        time.perf_counter())
        return bus

    @contextlib.contextmanager
    def _link_errors(self) -> Iterator[None]:
        """A communication error of the SDK, or the USB thread closed: the link is lost
        (:meth:`_lose` disconnects; ConnectionLostError); other SDK errors pass through."""
        try:
            yield
        except SdkCallError as error:
            if error.communication:
                raise self._lose(error) from None
            raise
        except BusClosedError as error:
            raise self._lose(error.__cause__ or error) from None

    def _on_bus(self, job):
        """``job(sdk)`` on the USB thread; a lost link disconnects (ConnectionLostError)."""
        bus = self._require()
        with self._link_errors():
            return bus.call(job)

    def _read_position(self, sdk: Sdk) -> tuple[np.ndarray, float]:
        """GetAngularPosition: Kinova's angles (deg) and when the read returned (perf_counter s)."""
        position = AngularPosition()
        sdk.call("GetAngularPosition", ctypes.byref(position))
        return actuators(position.Actuators, self.num_joints), time.perf_counter()

    # ------------------------------------------------------------------ protocol
    def _model_position(self, degrees: np.ndarray) -> np.ndarray:
        return unwrap_positions(model_positions(degrees, self._convention), self._last_position,
                                ~self._robot.limited, self._range_centre)

    def _velocity(self, q: np.ndarray, stamp: float) -> np.ndarray:
        """rad/s: the position difference to the latest read at least ``velocity_window`` s older
        (else the oldest kept) over the time between their stamps."""
        window = self.settings.velocity_window
        reference = None
        for then, before in reversed(self._reads):
            reference = (then, before)
            if stamp - then >= window:
                break
        if reference is None or stamp <= reference[0]:
            return np.zeros_like(q)
        return (q - reference[1]) / (stamp - reference[0])

    def refresh_feedback(self) -> Feedback:
        """One position read (the frame's stamp: when it returned); velocities are the position
        difference to an earlier read, at least ``velocity_window`` s older, over the time between
        their stamps (:meth:`_velocity`: at 20 Hz the previous tick's; the firmware's velocity
        feedback is noisy and not read here); with ``torque_each_tick`` the torques are read next, as
        a second call of the USB thread (a point that falls due may go between the two, so neither
        holds a point back by more than one call), else they are the last status poll's
        (``status_rate_hz``); faults as of the last status poll."""
        degrees, stamp = self._on_bus(self._read_position)
        if self.settings.torque_each_tick:
            self._on_bus(self._read_torques)
        q = self._model_position(degrees)
        dq = self._velocity(q, stamp)
        self._last_position = q
        self._reads.append((stamp, q))
        self._frame += 1
        with self._status:
            faults, torque = self._faults, self._torque.copy()
        return Feedback(timestamp=stamp, frame_id=self._frame, position=q, velocity=dq,
                        torque=torque,
                        arm_state=ArmState.IN_FAULT if faults != Fault.NONE else ArmState.SERVOING_READY,
                        faults=faults)

    def _send(self, command: np.ndarray) -> np.ndarray:
        """Make a command that passed the gate the standing one (times ``speed_scale``): the USB
        thread sends it in the next trajectory point (from rest, before this returns)."""
        bus = self._require()
        sent = command * self.settings.speed_scale
        try:
            bus.command(kinova_velocities(sent, self._convention))
        except BusHeldError:  # a fault latched since the gate's check (status poll, watchdog)
            faults, reason = self._fault_state()
            raise ArmFaultError(f"Kinova arm {self._serial} held stopped in fault ({faults!r}: "
                                f"{reason or 'being latched'}); clear_faults() first") from None
        except BusClosedError as error:
            raise self._lose(error.__cause__ or error) from None
        except SdkCallError as error:
            raise self._lose(error) from None
        self._require()  # the first point's failure, if it failed
        return sent

    def _halt(self, then=None, hold: bool = False) -> None:
        """No standing command; zero velocity and an empty FIFO on the arm (then ``then(sdk)``);
        ``hold``: commands refused until :meth:`clear_faults`."""
        bus = self._require()
        with self._link_errors():
            bus.halt(then, hold)

    def stop(self) -> None:
        self._halt()

    def apply_emergency_stop(self) -> None:
        self._require()
        self._add_fault(Fault.EMERGENCY_STOP, "emergency stop applied")
        # the arm ignores commands until StartControlAPI (clear_faults)
        self._halt(lambda sdk: sdk.call("StopControlAPI"), hold=True)
        log.error("kinova_gen2: EMERGENCY STOP on %s: zero velocity, trajectories erased, "
                  "control API stopped", self._serial)

    def clear_faults(self) -> None:
        def clear(sdk: Sdk) -> None:
            sensors, count = SensorsInfo(), ctypes.c_uint(0)
            sdk.call("GetSensorsInfo", ctypes.byref(sensors))
            if sensors.Voltage < self.settings.min_supply_voltage:
                raise ArmFaultError(f"supply voltage {sensors.Voltage:.1f} V is below "
                                    f"{self.settings.min_supply_voltage:g} V: release the e-stop "
                                    "(restore the actuators' power) first")
            sdk.call("StartControlAPI")
            self._control_started = True
            sdk.call("SetAngularControl")
            sdk.call("SendAdvanceTrajectory", velocity_point(np.zeros(self.num_joints)))
            sdk.call("EraseAllTrajectories")
            sdk.call("GetSystemErrorCount", ctypes.byref(count))
            with self._status:
                self._voltage = float(sensors.Voltage)
                self._errors_seen = int(count.value)  # the logged errors are acknowledged
                self._faults, self._fault_reason = Fault.NONE, ""
            bus.release()

        bus = self._require()
        bus.drop()
        self._on_bus(clear)
        log.info("kinova_gen2: faults cleared on %s", self._serial)

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        """Gen2 has no Kortex servoing modes: single-level is angular control with joint velocity
        commands; any other mode holds the arm stopped and refuses joint speed commands."""
        mode = ServoingMode(mode)
        self._halt((lambda sdk: sdk.call("SetAngularControl"))
                   if mode == ServoingMode.SINGLE_LEVEL_SERVOING else None)
        self._mode = mode

    # ------------------------------------------------------------------ inspection
    @property
    def standing_command(self) -> np.ndarray | None:
        """The command the USB thread resends (model rad/s), or None when stopped."""
        bus = self._bus
        degrees = bus.standing if bus is not None else None
        return None if degrees is None else self._sign * np.radians(degrees)

    def time_calls(self, rounds: int) -> CallTimes:
        """``rounds`` calls of each function the loop uses, on the USB thread between its own
        (the arm held still: zero-velocity points, each followed by EraseAllTrajectories);
        :attr:`call_times` then holds their durations (also returned)."""
        n = self.num_joints

        def one_round(sdk: Sdk) -> None:
            buffer, sensors, count = AngularPosition(), SensorsInfo(), ctypes.c_uint(0)
            sdk.call("GetAngularPosition", ctypes.byref(buffer))
            sdk.call("GetAngularVelocity", ctypes.byref(buffer))
            sdk.call("GetAngularForce", ctypes.byref(buffer))
            sdk.call("GetSensorsInfo", ctypes.byref(sensors))
            sdk.call("GetSystemErrorCount", ctypes.byref(count))
            sdk.call("SendAdvanceTrajectory", velocity_point(np.zeros(n)))
            sdk.call("EraseAllTrajectories")

        for _ in range(rounds):
            self._on_bus(one_round)
        assert self._sdk is not None
        return self._sdk.times

    def raw_velocities(self, reads: int) -> np.ndarray:
        """``reads`` GetAngularVelocity readings decoded to model rad/s
        (:func:`model_velocities`), shape (reads, joints): the firmware's velocity feedback, which
        the control loop does not use (its noise, for the ``--check``)."""
        n = self.num_joints

        def read(sdk: Sdk) -> np.ndarray:
            velocity = AngularPosition()
            sdk.call("GetAngularVelocity", ctypes.byref(velocity))
            return actuators(velocity.Actuators, n)

        return np.array([model_velocities(self._on_bus(read), self._convention,
                                          self.settings.velocity_feedback_scale)
                         for _ in range(reads)])

