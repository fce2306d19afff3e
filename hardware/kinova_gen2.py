"""The Kinova Gen2 backend: a JACO2 (j2n6s300 curved wrist = dm_control's ``jaco``, or j2s6s200
spherical wrist) through Kinova's C SDK, loaded with :mod:`ctypes`.

The SDK is the vendor's shared library that kinova-ros ships in ``kinova_driver/lib/<arch>/``:
``USBCommandLayerUbuntu.so`` with its communication layer ``USBCommLayerUbuntu.so`` (installed by
Kinova's installer as ``Kinova.API.USBCommandLayerUbuntu.so`` and ``Kinova.API.CommLayerUbuntu.so``);
the x86_64 pair is in ``hardware/vendor/kinova_gen2/``. Only USB is implemented: the Ethernet
variant (``EthCommandLayerUbuntu.so``) needs ``InitEthernetAPI``, which is not called here. The path
is ``kinova_gen2.library`` in ``configs/deploy.yaml``; nothing is downloaded or guessed. ``InitAPI``
loads the communication layer by bare name, so its folder must be on the dynamic loader's path
when the process starts: :func:`check_library` checks that before anything runs
(:mod:`hardware.kinova_gen2_loader`). The function signatures and struct layouts below are those of
kinova-ros's headers (``kinova_driver/include/kinova/KinovaTypes.h``,
``Kinova.API.USBCommandLayerUbuntu.h``, ``Kinova.API.USBCommLayerUbuntu.h``) and match the vendor
binary's debug information; C++ references (``int &``) are pointers in the C ABI.

**One thread owns the USB.** The SDK handles one call at a time, each a USB round trip of several
ms, and an ANGULAR_VELOCITY trajectory point moves the arm for 10 ms only, so joint velocities must
reach it at 100 Hz while the deploy loop runs at 20 Hz with a 25 ms command deadline. Once
connected, every SDK call goes through :class:`~hardware.kinova_gen2_bus.UsbBus`'s thread, which
orders them: stops first, then trajectory points before the arm's FIFO runs dry, then the callers'
calls, then the status poll (see :mod:`hardware.kinova_gen2_bus`). A control tick costs one
position read (:meth:`KinovaGen2Arm.refresh_feedback`, stamped when the read returned; velocities
are position differences between reads); :meth:`~KinovaGen2Arm.send_joint_speeds` only makes the
command the standing one, which the thread sends in its next point (at most 100 per second,
``send_ahead`` s of motion queued: ``kinova_gen2.send_rate_hz`` is capped at 100 Hz since faster
points pile up in the arm's 2,000-point FIFO and keep it moving after commands stop). Supply
voltage, the system error log and the torques are polled at ``kinova_gen2.status_rate_hz`` (2 Hz).
Every stop sends zero velocity and erases the FIFO (``EraseAllTrajectories``). The **command
watchdog**: when no fresh command has come for ``kinova_gen2.command_timeout`` control periods, the
thread sends zero velocity, then ``EraseAllTrajectories``, at that deadline, and records why
(:attr:`KinovaGen2Arm.watchdog_stops`); the next fresh command moves the arm again.

Units: the protocol speaks rad and rad/s; Gen2 degrees and deg/s. The model's joint angle is
``sign * kinova_angle + offset`` per joint (``kinova_gen2.joints.<arm>``; both arms: sign +1,
offset 0, as kinova-ros's current driver publishes the raw angles for kinova_description's URDFs,
which dm_control's JACO MJCF copies). ``GetAngularVelocity`` (read only by the ``--check``:
the loop derives velocities from positions) reports half the real velocity with
negative values as 360 - |v| (kinova-ros's ``kinova_comm.cpp`` multiplies by 2 and
``kinova_arm.cpp`` subtracts 360 above 180); :func:`model_velocities` undoes both.

Faults: any SDK call that fails with a communication error (USB unplugged, power lost) is
:class:`~hardware.protocol.ConnectionLostError` and the adapter disconnects; another failing call
is a :class:`~hardware.protocol.HardwareError` naming the function and the code. A new entry in
the arm's system error log (``GetSystemErrorCount`` / ``GetSystemError``) puts the adapter in
fault (``Fault.HARDWARE``); a supply voltage below ``kinova_gen2.min_supply_voltage``
(``GetSensorsInfo``) or a logged voltage error is the e-stop cutting the actuators' power
(``Fault.EMERGENCY_STOP``). The status poll that sees a fault stops the arm at once, on the USB
thread, whatever the control loop is doing (:attr:`KinovaGen2Arm.fault_stops`), and the next
feedback frame carries the flags. Gen2 has no software e-stop: :meth:`KinovaGen2Arm.apply_emergency_stop`
sends zero, erases the trajectory FIFO and calls ``StopControlAPI`` (the arm ignores commands
until :meth:`~KinovaGen2Arm.clear_faults` calls ``StartControlAPI`` again). In fault, motion
commands raise :class:`~hardware.protocol.ArmFaultError`.

:meth:`KinovaGen2Arm.connect` selects the arm by its serial number (``kinova_gen2.serial``) from
``GetDevices``; it never takes the first one found. It starts the control API, stops it and starts
it again (as kinova-ros does: on a cold boot the arm may not respond to the first start). Every exit
path of connect (a failure included) and :meth:`~KinovaGen2Arm.disconnect` leave the arm stopped,
calling only what is valid after what succeeded: once ``StartControlAPI`` has succeeded, zero
velocity, ``EraseAllTrajectories``, ``StopControlAPI``; then ``CloseAPI`` (valid in every state).
Before that (``InitAPI`` failed, no arm) only ``CloseAPI``: the real SDK crashes in
``SendAdvanceTrajectory`` when ``InitAPI`` could not load its communication layer. An ``atexit``
hook disconnects an adapter left connected. Only the serial number is ever logged.

Tested against the fake SDK in ``tests/fake_kinova_sdk/`` (same exports and layouts; per-call USB
latency, one call at a time, the trajectory FIFO, noisy velocity feedback, a cold boot) and,
without an arm, against Kinova's own binary (``tests/test_kinova_gen2_vendor.py``); never against a
real arm: see docs/hardware.md.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import ctypes
import dataclasses
import logging
import math
import sys
import threading
import time
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Iterator, Optional

import numpy as np
from pydantic import AfterValidator, PlainValidator

from ahrm_stack.schema import Bool, ConfigError, Float, Int, Section, Str, count, fail, ge, gt, le
from hardware.kinova_gen2_bus import (POINT_PERIOD, BusClosedError, BusHeldError, CallTimes, UsbBus,
                                      WatchdogStop, is_link_error)
from hardware.kinova_gen2_loader import LoaderPathError, check_comm_layers
from hardware.kinova_gen2_lock import lock_warning
from hardware.protocol import (DescribedArm, ArmFaultError, ArmState, CommandRefusedError,
                               ConnectionLostError, Fault, Feedback, HardwareError,
                               NotConnectedError, ServoingMode, WallClock, check_joint_speeds,
                               range_centres, unwrap_positions)

if TYPE_CHECKING:
    from ahrm_stack.robot import RobotDescription

log = logging.getLogger(__name__)

DOCS = "docs/hardware.md (section 'Kinova Gen2')"

# ---------------------------------------------------------------------------------------------
# The SDK's constants and structs (kinova-ros kinova_driver/include/kinova/)
# ---------------------------------------------------------------------------------------------

NO_ERROR_KINOVA = 1
ERROR_NO_DEVICE_FOUND = 1015
ERROR_LOAD_COMM_DLL = 2002
ANGULAR_POSITION = 2  # POSITION_TYPE (KinovaTypes.h; the vendor binary's DWARF agrees)
ANGULAR_VELOCITY = 8  # POSITION_TYPE
ARM_POINT_RATE_HZ = 1.0 / POINT_PERIOD  # trajectory points the arm executes per second (100)
SERIAL_LENGTH = 20
MAX_KINOVA_DEVICE = 20
ERROR_LAYER_COUNT = 7
ERROR_DATA_COUNT_MAX = 50

#: Return codes of the communication and command layers (Kinova.API.USB*LayerUbuntu.h).
ERROR_CODES = {
    666: "UNKNOWN_ERROR", 1001: "ERROR_LOAD_USB_LIBRARY", 1002: "ERROR_OPEN_METHOD",
    1003: "ERROR_WRITE_METHOD", 1004: "ERROR_READ_METHOD", 1005: "ERROR_READ_INT_METHOD",
    1006: "ERROR_FREE_LIBRARY", 1007: "ERROR_JACO_CONNECTION", 1008: "ERROR_CLAIM_INTERFACE",
    1009: "ERROR_UNKNOWN_DEVICE", 1010: "ERROR_NOT_INITIALIZED", 1011: "ERROR_LIBUSB_NO_DEVICE",
    1012: "ERROR_LIBUSB_BUSY", 1013: "ERROR_LIBUSB_NOT_SUPPORTED", 1014: "ERROR_SENDPACKET_UNKNOWN",
    1015: "ERROR_NO_DEVICE_FOUND", 1016: "ERROR_OPERATION_INCOMPLETED",
    1017: "ERROR_RS485_INVALID_HANDLE", 1018: "ERROR_RS485_IO_PENDING",
    1019: "ERROR_RS485_NOT_ENOUGH_MEMORY", 1020: "ERROR_RS485_TIMEOUT",
    1021: "ERROR_FUNCTION_NOT_ACCESSIBLE", 1022: "ERROR_COMM_TIMEOUT", 9999: "ERROR_NACK_RECEIVED",
    2001: "ERROR_INIT_API", 2002: "ERROR_LOAD_COMM_DLL", 2003: "JACO_NACK_FIRST",
    2004: "JACO_COMM_FAILED", 2005: "JACO_NACK_NORMAL", 2006: "ERROR_INIT_COMM_METHOD",
    2007: "ERROR_CLOSE_METHOD", 2008: "ERROR_GET_DEVICE_COUNT_METHOD",
    2009: "ERROR_SEND_PACKET_METHOD", 2010: "ERROR_SET_ACTIVE_DEVICE_METHOD",
    2011: "ERROR_GET_DEVICES_LIST_METHOD", 2012: "ERROR_SEMAPHORE_FAILED",
    2013: "ERROR_SCAN_FOR_NEW_DEVICE", 2014: "ERROR_GET_ACTIVE_DEVICE_METHOD",
    2015: "ERROR_OPEN_RS485_ACTIVATE", 2100: "ERROR_INVALID_PARAM",
    2101: "ERROR_API_NOT_INITIALIZED", 2102: "ERROR_INIT_DATA_STRUCTURES_METHOD",
}
#: Codes that mean the link to the arm is gone (USB/Ethernet transport, the device vanished).
COMMUNICATION_ERRORS = frozenset({1002, 1003, 1004, 1005, 1007, 1011, 1014, 1015, 1016, 1020,
                                  1022, 2004, 2009, 2012})

#: errorLoggerType (KinovaTypes.h), in enum order: the system error log's entry types.
SYSTEM_ERROR_TYPES = (
    "ERROR_NOTINITIALIZED", "keos_err1", "keos_err2", "keos_err3", "User_err_start_marker",
    "errorlog_Actuator_Temperature", "errorlog_Actuator_TemperatureOK",
    "errorlog_Finger_Temperature", "errorlog_Finger_TemperatureOK", "errorlog_voltage",
    "errorlog_voltageOK", "errorlog_current_FingersClosing", "errorlog_current_FingersOpening",
    "errorlog_current_FingersOK", "errorlog_current_Actuators", "errorlog_current_ActuatorsOK",
    "errorLog_RobotStatus_Build_Incomplete", "errorLogger_END")
VOLTAGE_ERROR = SYSTEM_ERROR_TYPES.index("errorlog_voltage")


class KinovaDevice(ctypes.Structure):
    _fields_ = [("SerialNumber", ctypes.c_char * SERIAL_LENGTH),
                ("Model", ctypes.c_char * SERIAL_LENGTH), ("VersionMajor", ctypes.c_int),
                ("VersionMinor", ctypes.c_int), ("VersionRelease", ctypes.c_int),
                ("DeviceType", ctypes.c_int), ("DeviceID", ctypes.c_int)]


class AngularInfo(ctypes.Structure):
    _fields_ = [(f"Actuator{i}", ctypes.c_float) for i in range(1, 8)]


class CartesianInfo(ctypes.Structure):
    _fields_ = [(name, ctypes.c_float) for name in ("X", "Y", "Z", "ThetaX", "ThetaY", "ThetaZ")]


class FingersPosition(ctypes.Structure):
    _fields_ = [(f"Finger{i}", ctypes.c_float) for i in range(1, 4)]


class AngularPosition(ctypes.Structure):
    _fields_ = [("Actuators", AngularInfo), ("Fingers", FingersPosition)]


class Limitation(ctypes.Structure):
    _fields_ = [(name, ctypes.c_float) for name in (
        "speedParameter1", "speedParameter2", "speedParameter3", "forceParameter1",
        "forceParameter2", "forceParameter3", "accelerationParameter1", "accelerationParameter2",
        "accelerationParameter3")]


class UserPosition(ctypes.Structure):
    _fields_ = [("Type", ctypes.c_int), ("Delay", ctypes.c_float),  # Type: POSITION_TYPE
                ("CartesianPosition", CartesianInfo), ("Actuators", AngularInfo),
                ("HandMode", ctypes.c_int), ("Fingers", FingersPosition)]  # HandMode: HAND_MODE


class TrajectoryPoint(ctypes.Structure):
    _fields_ = [("Position", UserPosition), ("LimitationsActive", ctypes.c_int),
                ("SynchroType", ctypes.c_int), ("Limitations", Limitation)]


class SensorsInfo(ctypes.Structure):
    _fields_ = [(name, ctypes.c_float) for name in (
        "Voltage", "Current", "AccelerationX", "AccelerationY", "AccelerationZ",
        *(f"ActuatorTemp{i}" for i in range(1, 8)), "FingerTemp1", "FingerTemp2", "FingerTemp3")]


class SystemError(ctypes.Structure):
    _fields_ = [("ErrorHeader", ctypes.c_uint), ("ErrorType", ctypes.c_int),
                ("FirmwareVersion", ctypes.c_int), ("KeosVersion", ctypes.c_int),
                ("SystemTime", ctypes.c_uint), ("LayerErrorStatus", ctypes.c_bool * ERROR_LAYER_COUNT),
                ("LifeTime", ctypes.c_int), ("DataCount", ctypes.c_int),
                ("Data", ctypes.c_uint * ERROR_DATA_COUNT_MAX)]


_P = ctypes.POINTER
#: name -> (argument types); every function returns int.
SIGNATURES: dict[str, tuple] = {
    "InitAPI": (), "CloseAPI": (), "RefresDevicesList": (),
    "GetDevices": (_P(KinovaDevice), _P(ctypes.c_int)),
    "SetActiveDevice": (KinovaDevice,),
    "StartControlAPI": (), "StopControlAPI": (), "SetAngularControl": (),
    "SendAdvanceTrajectory": (TrajectoryPoint,),
    "EraseAllTrajectories": (),
    "GetAngularPosition": (_P(AngularPosition),), "GetAngularVelocity": (_P(AngularPosition),),
    "GetAngularForce": (_P(AngularPosition),), "GetSensorsInfo": (_P(SensorsInfo),),
    "GetSystemErrorCount": (_P(ctypes.c_uint),),
    "GetSystemError": (ctypes.c_uint, _P(SystemError)),
    "MoveHome": (),  # the factory home, as the joystick's home button (kinova-ros homeArm)
}


# ---------------------------------------------------------------------------------------------
# Settings (configs/deploy.yaml, section kinova_gen2)
# ---------------------------------------------------------------------------------------------


class Gen2ConfigError(ValueError):
    """A ``kinova_gen2`` setting is missing or invalid, or the SDK file is missing; one line that
    names the key (or the path)."""


def _sign(value: int) -> int:
    if value not in (1, -1):
        fail(f" must be 1 or -1, got {value!r}")
    return value


def _path(value: Any) -> str | None:
    """A path string (not blank) or None."""
    if value is not None and (not isinstance(value, str) or not value.strip()):
        fail(f" must be a path string or null, got {value!r}")
    return value


def _serial(value: Any) -> str | None:
    """The arm's serial number, stripped (it fits the SDK's char[SERIAL_LENGTH]), or None."""
    if value is not None and (not isinstance(value, str) or not value.strip()
                              or len(value.encode()) >= SERIAL_LENGTH):
        fail(f" must be the arm's serial number (a string of at most {SERIAL_LENGTH - 1} bytes) "
             f"or null, got {value!r}")
    return value.strip() if isinstance(value, str) else None


def _not_empty(value: dict) -> dict:
    if not value:
        fail(" must map each arm name to its sign and offset_deg, got {}")
    return value


FilePath = Annotated[Optional[str], PlainValidator(_path)]


@dataclasses.dataclass(frozen=True)
class HomeSettings(Section):
    """``kinova_gen2.home``: the homing step (``--home``, :mod:`hardware.kinova_gen2_home`)."""

    factory_home_first: Bool  # MoveHome (the firmware's move to its factory home, at its own speed)
    # before the slow move to the policy's start
    speed_deg_s: Annotated[Float, gt(0), le(20.0, " deg/s: the homing move is a slow, supervised "
                                             "first motion (kinova-ros's default joint speed limit "
                                             "is 10)")]  # deg/s per joint, the final move's limit
    tolerance_deg: Annotated[Float, gt(0), le(5.0)]  # deg: each joint this near its target is there
    still_deg_s: Annotated[Float, gt(0), le(5.0)]  # deg/s: every joint slower than this is still
    settle: Annotated[Float, gt(0), le(5.0)]  # s the arm must stay still to count as arrived
    timeout: Annotated[Float, gt(0), le(600.0)]  # s each stage may take before the arm is stopped
    poll_rate_hz: Annotated[Float, gt(0), le(50.0)]  # Hz: position reads while it moves
    clearance: Annotated[Float, ge(0), le(0.5)]  # m: the pusher tip above the table top all along
    # the final move's joint-space path


@dataclasses.dataclass(frozen=True)
class JointConvention(Section):
    """model angle (deg) = ``sign`` * Kinova angle (deg) + ``offset_deg``, per joint."""

    sign: Annotated[tuple[Annotated[Int, AfterValidator(_sign)], ...], count(1)]  # +1 or -1 per joint
    offset_deg: tuple[Float, ...]  # deg, one per joint

    def check(self, key: str) -> None:
        if len(self.offset_deg) != len(self.sign):
            raise ConfigError(f"{key}.offset_deg must be {len(self.sign)} finite numbers (deg), "
                              f"got {list(self.offset_deg)}")


@dataclasses.dataclass(frozen=True)
class Gen2Settings(Section):
    """``configs/deploy.yaml``'s ``kinova_gen2`` section. Files are not looked at here
    (:func:`check_library` does, when the backend is used)."""

    library: FilePath  # the command layer .so (its communication layer: on the loader's path)
    serial: Annotated[Optional[str], PlainValidator(_serial)]  # the arm's serial; required to connect
    send_rate_hz: Annotated[Float, gt(0), le(ARM_POINT_RATE_HZ, " Hz: the arm executes one trajectory "
                                              "point per 10 ms; faster points pile up in its 2,000-point "
                                              "FIFO and keep it moving after commands stop")]  # Hz: at
    # most this many trajectory points per second (100: the arm's own rate)
    send_ahead: Annotated[Float, gt(0), le(0.05, " s: queued motion delays every command by as much and "
                                           "keeps the arm moving that long after a lost link")]  # s of
    # motion left in the arm's FIFO when the next point is sent
    status_rate_hz: Annotated[Float, gt(0), le(10.0, " Hz: each poll is three USB calls of several ms "
                                           "(kinova-ros polls at 10 Hz)")]  # Hz: supply voltage, error
    # log and torques are read this often (a logged fault is seen within 1 / this)
    command_timeout: Annotated[Float, gt(1, " (a healthy loop sends one command per period)"),
                               le(100.0)]  # control periods without a fresh command before the
    # USB thread stops the arm
    check_calls: Annotated[Int, ge(10), le(10000)]  # --check: calls of each SDK function timed, and
    # control ticks of its held-still loop
    speed_scale: Annotated[Float, gt(0), le(1.0)]  # every command is multiplied by this
    velocity_window: Annotated[Float, gt(0), le(1.0)]  # s: velocities are the position difference to
    # the latest read at least this much older (angle noise over a few ms would be tens of deg/s)
    velocity_feedback_scale: Annotated[Float, gt(0)]  # GetAngularVelocity reports 1/this of the real one
    min_supply_voltage: Annotated[Float, gt(0)]  # V; below it the actuators are unpowered (the e-stop)
    scene: FilePath  # the static scene layout (hardware/scene.py) deploy uses for perception
    switch_interval: Annotated[Float, gt(0), le(0.005)]  # s, Python's GIL switch interval while
    # connected (sys.setswitchinterval)
    joints: Annotated[dict[Str, JointConvention], AfterValidator(_not_empty)]  # per arm (task.robot)
    home: HomeSettings  # the homing step (--home)


def _key(name: str) -> str:
    return f"deploy.kinova_gen2.{name}"


def check_library(settings: Gen2Settings) -> Path:
    """The command layer's path if it is a file whose communication layer the dynamic loader finds
    by bare name (:func:`check_sdk_path`); else a one-line :class:`Gen2ConfigError` naming the key
    or the path and saying what to do (nothing is downloaded or guessed)."""
    if settings.library is None:
        raise Gen2ConfigError(f"{_key('library')} is not set: give the path of Kinova's "
                              f"USBCommandLayerUbuntu.so (hardware/vendor/kinova_gen2/x86_64-linux-gnu/ "
                              f"or kinova-ros kinova_driver/lib/); see {DOCS}")
    library = Path(settings.library).expanduser()
    if not library.is_file():
        raise Gen2ConfigError(f"{_key('library')}: no file at {settings.library}; install Kinova's "
                              f"Gen2 SDK as described in {DOCS}")
    check_sdk_path(library)
    return library


def check_sdk_path(library: Path) -> dict[str, str | None]:
    """The communication layers ``library``'s ``InitAPI`` loads by bare name, each loaded here as
    the dynamic loader finds it (name -> file); a one-line :class:`Gen2ConfigError` saying what to
    set when it does not (see :mod:`hardware.kinova_gen2_loader`)."""
    try:
        return check_comm_layers(library, _key("library"), DOCS)
    except LoaderPathError as error:
        raise Gen2ConfigError(str(error)) from None
    except OSError as error:
        raise Gen2ConfigError(f"{_key('library')}: cannot read {library} "
                              f"({error.strerror or error})") from None


def joint_convention(settings: Gen2Settings, robot: RobotDescription) -> JointConvention:
    """The arm's joint convention; a one-line error when ``joints.<arm>`` is missing or of the
    wrong size."""
    convention = settings.joints.get(robot.name)
    if convention is None:
        raise Gen2ConfigError(f"{_key('joints.' + robot.name)} is missing (the deployed arm is "
                              f"{robot.name!r}; configured: {sorted(settings.joints)})")
    if len(convention.sign) != robot.num_joints:
        raise Gen2ConfigError(f"{_key('joints.' + robot.name)} has {len(convention.sign)} joints; "
                              f"{robot.name} has {robot.num_joints}")
    return convention


# ---------------------------------------------------------------------------------------------
# Unit and convention conversions (pure)
# ---------------------------------------------------------------------------------------------


def model_positions(kinova_deg, convention: JointConvention) -> np.ndarray:
    """Kinova joint angles (deg) -> the model's (rad), before unwrapping."""
    sign = np.asarray(convention.sign, dtype=float)
    return np.radians(sign * np.asarray(kinova_deg, dtype=float) + np.asarray(convention.offset_deg))


def kinova_positions(model_rad, convention: JointConvention) -> np.ndarray:
    """The model's joint angles (rad) -> Kinova's (deg); the inverse of :func:`model_positions`."""
    sign = np.asarray(convention.sign, dtype=float)
    return sign * (np.degrees(np.asarray(model_rad, dtype=float)) - np.asarray(convention.offset_deg))


def kinova_velocities(model_rad_s, convention: JointConvention) -> np.ndarray:
    """Model joint velocities (rad/s) -> the ANGULAR_VELOCITY command (deg/s)."""
    return np.asarray(convention.sign, dtype=float) * np.degrees(np.asarray(model_rad_s, dtype=float))


def model_velocities(reported, convention: JointConvention, feedback_scale: float) -> np.ndarray:
    """``GetAngularVelocity``'s values -> model joint velocities (rad/s): times ``feedback_scale``
    (the firmware reports half), values above 180 deg/s minus 360 (negative velocities come as
    360 - |v|), then the joint sign."""
    v = np.asarray(reported, dtype=float) * feedback_scale
    v = np.where(v > 180.0, v - 360.0, v)
    return np.asarray(convention.sign, dtype=float) * np.radians(v)


# ---------------------------------------------------------------------------------------------
# The SDK
# ---------------------------------------------------------------------------------------------


class SdkCallError(HardwareError):
    """An SDK function returned an error code (``code``; ``function`` its name)."""

    def __init__(self, function: str, code: int) -> None:
        self.function, self.code = function, int(code)
        super().__init__(f"{function} failed: {ERROR_CODES.get(self.code, 'error')} ({self.code})")

    @property
    def communication(self) -> bool:
        return self.code in COMMUNICATION_ERRORS


class Sdk:
    """The loaded SDK: :meth:`call` runs one function under one lock (the SDK is not re-entrant),
    times it (:attr:`times`) and raises :class:`SdkCallError` for a code other than
    NO_ERROR_KINOVA. Loading it checks first that the dynamic loader finds the communication
    layers it loads by name (:func:`check_sdk_path`: :class:`Gen2ConfigError`); :attr:`comm_layers`
    says which files. Once an adapter is connected only its USB thread calls it
    (:mod:`hardware.kinova_gen2_bus`)."""

    def __init__(self, library: Path) -> None:
        self.comm_layers = check_sdk_path(library)  # before InitAPI can ever run
        try:
            self.lib = ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
        except OSError as error:
            raise HardwareError(f"cannot load the Kinova SDK {library}: {error}; see {DOCS}") from None
        missing = [name for name in SIGNATURES if not hasattr(self.lib, name)]
        if missing:
            raise HardwareError(f"{library} does not export {missing[0]}: not Kinova's Gen2 "
                                f"command layer? see {DOCS}")
        for name, argtypes in SIGNATURES.items():
            function = getattr(self.lib, name)
            function.argtypes = list(argtypes)
            function.restype = ctypes.c_int
        self.lock = threading.RLock()
        self.times = CallTimes()

    def call(self, name: str, *args) -> int:
        with self.lock:
            start = time.perf_counter()
            code = getattr(self.lib, name)(*args)
            self.times.record(name, time.perf_counter() - start)
        if code != NO_ERROR_KINOVA:
            raise SdkCallError(name, code)
        return code

    def call_quietly(self, name: str, *args) -> None:
        """Best effort (stop paths): failures are logged, never raised."""
        try:
            self.call(name, *args)
        except Exception as error:  # noqa: BLE001 - a stop path continues whatever happens
            log.error("kinova_gen2: %s failed on a stop path (%s)", name, error)

    def devices(self) -> list[KinovaDevice]:
        """``GetDevices``: the arms on the bus."""
        found = (KinovaDevice * MAX_KINOVA_DEVICE)()
        result = ctypes.c_int(0)
        with self.lock:
            count = self.lib.GetDevices(found, ctypes.byref(result))
        if result.value != NO_ERROR_KINOVA:
            raise SdkCallError("GetDevices", result.value)
        return [found[i] for i in range(max(0, min(count, MAX_KINOVA_DEVICE)))]


def velocity_point(kinova_deg_s: np.ndarray) -> TrajectoryPoint:
    """A zeroed TrajectoryPoint of type ANGULAR_VELOCITY carrying joint velocities (deg/s) in
    ``Position.Actuators`` (where the SDK reads them, as in kinova-ros's setJointVelocities)."""
    point = TrajectoryPoint()  # ctypes zero-initialises: no limitations, synchro type 0
    point.Position.Type = ANGULAR_VELOCITY
    for i, value in enumerate(np.asarray(kinova_deg_s, dtype=float)):
        setattr(point.Position.Actuators, f"Actuator{i + 1}", float(value))
    return point


def position_point(kinova_deg: np.ndarray, speed_deg_s: float) -> TrajectoryPoint:
    """A TrajectoryPoint of type ANGULAR_POSITION to joint angles ``kinova_deg`` (Kinova's deg)
    with every joint's speed limited to ``speed_deg_s`` (deg/s: ``speedParameter1`` joints 1-3,
    ``speedParameter2`` the others, ``LimitationsActive`` 1), as kinova-ros's setJointAngles."""
    point = TrajectoryPoint()
    point.Position.Type = ANGULAR_POSITION
    for i, value in enumerate(np.asarray(kinova_deg, dtype=float)):
        setattr(point.Position.Actuators, f"Actuator{i + 1}", float(value))
    point.LimitationsActive = 1
    point.Limitations.speedParameter1 = point.Limitations.speedParameter2 = float(speed_deg_s)
    return point


def _actuators(info: AngularInfo, n: int) -> np.ndarray:
    return np.array([getattr(info, f"Actuator{i + 1}") for i in range(n)], dtype=float)


@dataclasses.dataclass(frozen=True)
class FaultStop:
    """A fault the adapter found by itself (the status poll, a failed call of the USB thread):
    ``detected_at`` (perf_counter s) when the read that showed it returned, ``stopped_at`` when the
    FIFO was erased after a zero-velocity point (None if the arm could not be reached), ``reason``."""

    detected_at: float
    stopped_at: float | None
    reason: str


_LIVE: "weakref.WeakSet[KinovaGen2Arm]" = weakref.WeakSet()


@atexit.register
def _disconnect_all() -> None:  # pragma: no cover - runs at interpreter exit
    for arm in list(_LIVE):
        try:
            arm.disconnect()
        except Exception:  # noqa: BLE001 - exiting
            pass


class KinovaGen2Arm(DescribedArm):
    """A Kinova Gen2 arm (JACO2) over the C SDK, every call through one USB thread
    (:class:`~hardware.kinova_gen2_bus.UsbBus`: the 100 Hz points, the command watchdog, the status
    poll; see the module docstring).

    Args:
        robot: the arm model the controller was trained on (its joint count must be the arm's).
        settings: the ``kinova_gen2`` section (library, serial, rates, joint conventions).
        command_timeout_s: s without a fresh command before the USB thread stops the arm
            (``settings.command_timeout`` control periods; the caller knows the period).
    """

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
            raise Gen2ConfigError(f"{_key('serial')} is not set: the arm is chosen by its serial "
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
    def fault_reason(self) -> str:
        """Why the adapter is in fault ('' when it is not)."""
        with self._status:
            return self._fault_reason

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
                           (self._read_sensors, self._read_error_log, self._read_torques),
                           f"kinova-gen2-usb-{self._serial}", self.watchdog_stops)
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
        succeeded; CloseAPI once InitAPI was called. Each best effort. Only with the USB thread
        ended (this thread then owns the USB)."""
        sdk = self._sdk
        if sdk is None:
            return
        if self._control_started:
            sdk.call_quietly("SendAdvanceTrajectory", velocity_point(np.zeros(self.num_joints)))
            sdk.call_quietly("EraseAllTrajectories")
            sdk.call_quietly("StopControlAPI")
        if self._api_open:
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
        torque = self._sign * _actuators(force.Actuators, self.num_joints)
        with self._status:
            self._torque = torque

    def _read_position(self, sdk: Sdk) -> tuple[np.ndarray, float]:
        """GetAngularPosition: Kinova's angles (deg) and when the read returned (perf_counter s)."""
        position = AngularPosition()
        sdk.call("GetAngularPosition", ctypes.byref(position))
        return _actuators(position.Actuators, self.num_joints), time.perf_counter()

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
        feedback is noisy and not read here); torques and faults as of the last status poll
        (``status_rate_hz``)."""
        degrees, stamp = self._on_bus(self._read_position)
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

    @property
    def faults(self) -> Fault:
        """The fault flags as of now (the status poll's and the adapter's own)."""
        with self._status:
            return self._faults

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        """Check the command and make it the standing one: the USB thread sends it in the next
        trajectory point (from rest, before this returns)."""
        bus = self._require()
        with self._status:
            faults, reason = self._faults, self._fault_reason
        if faults != Fault.NONE:
            raise ArmFaultError(f"Kinova arm {self._serial} in fault ({faults!r}: {reason}); "
                                "clear_faults() first")
        if self._mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            raise ArmFaultError(f"joint speed commands need single-level servoing, not {self._mode}")
        try:
            command = check_joint_speeds(speeds, self._robot.velocity_limit)
        except CommandRefusedError as error:
            self.apply_emergency_stop()
            with self._status:
                self._faults |= Fault.LIMIT
                self._fault_reason = f"refused command: {error}"
            raise
        sent = command * self.settings.speed_scale
        try:
            bus.command(kinova_velocities(sent, self._convention))
        except BusHeldError:  # a fault latched since the check above (the status poll)
            with self._status:
                faults, reason = self._faults, self._fault_reason
            raise ArmFaultError(f"Kinova arm {self._serial} in fault ({faults!r}: {reason}); "
                                "clear_faults() first") from None
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
        with self._status:
            self._faults |= Fault.EMERGENCY_STOP
            self._fault_reason = "emergency stop applied"
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

    # ------------------------------------------------------------------ homing (--home)
    def _position_move(self, job) -> np.ndarray:
        """Stop any velocity command, then ``job(sdk)`` (one position move) on the USB thread, in
        angular control with an empty FIFO; refused in fault (:class:`ArmFaultError`)."""
        with self._status:
            faults, reason = self._faults, self._fault_reason
        if faults != Fault.NONE:
            raise ArmFaultError(f"Kinova arm {self._serial} in fault ({faults!r}: {reason}); "
                                "clear_faults() first")
        self._halt()

        def move(sdk: Sdk) -> np.ndarray:
            sdk.call("SetAngularControl")
            sdk.call("EraseAllTrajectories")
            return job(sdk)

        return self._on_bus(move)

    def move_home(self) -> None:
        """``MoveHome``: the firmware moves the arm to its factory home at its own speed (as the
        joystick's home button; kinova-ros's homeArm). Returns at once; :meth:`stop` stops it."""
        self._position_move(lambda sdk: sdk.call("MoveHome"))
        log.warning("kinova_gen2: MoveHome sent to %s (the firmware's factory home)", self._serial)

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
            return _actuators(velocity.Actuators, n)

        return np.array([model_velocities(self._on_bus(read), self._convention,
                                          self.settings.velocity_feedback_scale)
                         for _ in range(reads)])
