"""Kinova's Gen2 C SDK as :mod:`ctypes` sees it: its constants and structs, the functions' argument
types (:data:`SIGNATURES`), the loaded library (:class:`Sdk`, :class:`SdkCallError`) and the
trajectory points sent to it (:func:`velocity_point`, :func:`position_point`).

The function signatures and struct layouts are those of kinova-ros's headers
(``kinova_driver/include/kinova/KinovaTypes.h``, ``Kinova.API.USBCommandLayerUbuntu.h``,
``Kinova.API.USBCommLayerUbuntu.h``) and match the vendor binary's debug information
(``tests/test_kinova_gen2_dwarf.py``); C++ references (``int &``) are pointers in the C ABI.
"""

from __future__ import annotations

import ctypes
import logging
import threading
import time
from pathlib import Path

import numpy as np

from ahrm_stack.hardware.kinova_gen2.bus import CallTimes
from ahrm_stack.hardware.kinova_gen2.settings import DOCS, SERIAL_LENGTH, check_sdk_path
from ahrm_stack.hardware.protocol import HardwareError

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")

NO_ERROR_KINOVA = 1
ERROR_NO_DEVICE_FOUND = 1015
ERROR_LOAD_COMM_DLL = 2002
ANGULAR_POSITION = 2  # POSITION_TYPE (KinovaTypes.h; the vendor binary's DWARF agrees)
ANGULAR_VELOCITY = 8  # POSITION_TYPE
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


class QuickStatus(ctypes.Structure):
    """``GetQuickStatus``'s reply (14 bytes; members and offsets as the vendored binary's DWARF
    gives them, ``tests/test_kinova_gen2_dwarf.py``)."""

    _fields_ = [(name, ctypes.c_ubyte) for name in (
        "Finger1Status", "Finger2Status", "Finger3Status", "RetractType", "RetractComplexity",
        "ControlEnableStatus", "ControlActiveModule", "ControlFrameType", "CartesianFaultState",
        "ForceControlStatus", "CurrentLimitationStatus", "RobotType", "RobotEdition", "TorqueSensorsStatus")]


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
    "MoveHome": (),  # the factory home, as the joystick's home button (kinova-ros homeArm); blocks
    "GetQuickStatus": (_P(QuickStatus),),  # its RobotType: which arm is connected (kinova-ros reads it too)
}



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
    (:mod:`ahrm_stack.hardware.kinova_gen2.bus`)."""

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

    def call_blocking(self, name: str, *args) -> int:
        """:meth:`call` without the lock, for a function that blocks inside the SDK for seconds
        (``MoveHome``: :mod:`~ahrm_stack.hardware.kinova_gen2.moves`) while other threads go on
        calling: Kinova's library serialises its USB packets itself (a semaphore per packet). Its
        duration is kept under its name only, not among the recent calls that estimate one call."""
        start = time.perf_counter()
        code = getattr(self.lib, name)(*args)
        self.times.by_function[name].append(time.perf_counter() - start)
        if code != NO_ERROR_KINOVA:
            raise SdkCallError(name, code)
        return code

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


def actuators(info: AngularInfo, n: int) -> np.ndarray:
    return np.array([getattr(info, f"Actuator{i + 1}") for i in range(n)], dtype=float)

