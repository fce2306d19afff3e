"""Build and drive the fake Kinova Gen2 SDK (fake_kinova.c) from the tests and benchmarks.

:func:`build` compiles it with the system C compiler (``cc -shared -fPIC``) into a folder;
:func:`session_library` does so once per process into a temporary folder. :class:`FakeSdk` opens
the same file (the dynamic loader returns the same handle, so it shares the adapter's state) and
exposes the test-only functions and the call log. :meth:`FakeSdk.reset` gives a fake that behaves
like the arm (fake_kinova.c's header: USB latency per call, the 2,000-point trajectory FIFO with
velocity and position points, MoveHome, the real SDK's return codes without an arm, noisy velocity
feedback; a cold boot, a runaway and position noise on request);
``latency=0`` and ``velocity_noise=0`` make it instant and exact where a test checks logic, not
timing.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).resolve().parent / "fake_kinova.c"
SERIAL = "PJ00900006151300001"  # 19 characters, a JACO2-like serial number
MODEL = "JACO2"
LATENCY = 0.003  # s per SDK call: fake_kinova.c's DEFAULT_LATENCY (why: its header)
VELOCITY_NOISE = 1.0  # deg/s, GetAngularVelocity's noise: fake_kinova.c's DEFAULT_VELOCITY_NOISE
FIFO_SIZE = 2000  # trajectory points the arm holds
POINT_PERIOD = 0.010  # s: the arm executes one point per 10 ms
#: MoveHome's target, deg: j2n6s300's "Home" in kinova-ros's j2n6s300.srdf (fake_kinova.c FACTORY_HOME)
FACTORY_HOME = (275.2885, 167.5800, 57.4104, 240.8247, 82.8383, 75.8196)
POSITION_SPEED = 20.0  # deg/s: MoveHome's (fake_kinova.c DEFAULT_POSITION_SPEED, an assumption)

#: the function ids of the call log (the enum in fake_kinova.c)
FUNCTIONS = ("InitAPI", "CloseAPI", "GetDevices", "SetActiveDevice", "StartControlAPI",
             "StopControlAPI", "SetAngularControl", "SendAdvanceTrajectory",
             "EraseAllTrajectories", "GetAngularPosition", "GetAngularVelocity", "GetAngularForce",
             "GetSensorsInfo", "GetSystemErrorCount", "GetSystemError", "RefresDevicesList",
             "GetAPIVersion", "MoveHome", "GetQuickStatus", "GetGlobalTrajectoryInfo",
             "SetCartesianControl")


class CompilerMissing(RuntimeError):
    """No C compiler (cc, gcc, clang) on PATH."""


def compiler() -> str | None:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def build(directory: Path) -> Path:
    """Compile fake_kinova.c into ``directory``/libfakekinova.so; :class:`CompilerMissing`
    without a compiler."""
    cc = compiler()
    if cc is None:
        raise CompilerMissing("no C compiler (cc, gcc or clang) on PATH: the fake Kinova SDK cannot "
                              "be built (`make setup` installs gcc when missing)")
    target = Path(directory) / "libfakekinova.so"
    done = subprocess.run([cc, "-shared", "-fPIC", "-O1", "-o", str(target), str(SOURCE), "-lm",
                           "-lpthread"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"compiling {SOURCE.name} failed:\n{done.stderr}")
    return target


_FOLDERS: list[tempfile.TemporaryDirectory] = []  # kept alive until exit, then removed


@functools.lru_cache(maxsize=None)
def session_library() -> Path:
    """The fake, compiled once per process into a temporary folder that is removed when the
    process exits."""
    folder = tempfile.TemporaryDirectory(prefix="fake-kinova-")
    _FOLDERS.append(folder)
    return build(Path(folder.name))


class _Call(ctypes.Structure):
    _fields_ = [("t", ctypes.c_double), ("function", ctypes.c_int), ("result", ctypes.c_int),
                ("type", ctypes.c_int), ("values", ctypes.c_float * 7), ("start", ctypes.c_double)]


@dataclasses.dataclass(frozen=True)
class Call:
    """One recorded SDK call: ``t`` (s, CLOCK_MONOTONIC = time.perf_counter) when it returned, the
    function's name, its return code, ``type`` (the trajectory point's POSITION_TYPE, or a
    count/index), ``values`` (a velocity command in deg/s, or the true positions/velocities) and
    ``start`` (s) when it was called (before waiting for the USB bus)."""

    t: float
    function: str
    result: int
    type: int
    values: np.ndarray
    start: float = 0.0


class FakeSdk:
    """The fake's test-only side, on the library at ``path``."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.lib = ctypes.CDLL(str(self.path), mode=ctypes.RTLD_GLOBAL)
        lib = self.lib
        lib.FakeKinova_AddDevice.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
        lib.FakeKinova_SetPosition.argtypes = [ctypes.POINTER(ctypes.c_double)]
        lib.FakeKinova_GetState.argtypes = [ctypes.POINTER(ctypes.c_double)] * 2
        lib.FakeKinova_SetLatency.argtypes = [ctypes.c_double]
        lib.FakeKinova_SetHome.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_double]
        lib.FakeKinova_SetDrift.argtypes = [ctypes.POINTER(ctypes.c_double)]
        lib.FakeKinova_SetForce.argtypes = [ctypes.POINTER(ctypes.c_double)]
        lib.FakeKinova_SetPositionNoise.argtypes = [ctypes.c_double]
        lib.FakeKinova_SetVelocityNoise.argtypes = [ctypes.c_double, ctypes.c_ulonglong]
        lib.FakeKinova_SetCommMissing.argtypes = [ctypes.c_int]
        lib.FakeKinova_FailNext.argtypes = [ctypes.c_int, ctypes.c_int]
        lib.FakeKinova_Dropped.restype = ctypes.c_long
        lib.FakeKinova_Crashes.restype = ctypes.c_long
        lib.FakeKinova_InjectError.argtypes = [ctypes.c_int]
        lib.FakeKinova_SetEStop.argtypes = [ctypes.c_int]
        lib.FakeKinova_SetUnplugged.argtypes = [ctypes.c_int]
        lib.FakeKinova_SetColdBoot.argtypes = [ctypes.c_int]
        lib.FakeKinova_CallCount.restype = ctypes.c_long
        lib.FakeKinova_GetCall.argtypes = [ctypes.c_long, ctypes.POINTER(_Call)]
        lib.FakeKinova_Sizeof.restype = ctypes.c_long
        lib.FakeKinova_Sizeof.argtypes = [ctypes.c_int]

    def reset(self, serials=(SERIAL,), position_deg=None, latency: float = LATENCY,
              velocity_noise: float = VELOCITY_NOISE, seed: int = 1) -> None:
        """A fresh fake: no call recorded, the given arms on the bus, joints at ``position_deg``
        (deg), ``latency`` s per SDK call, velocity feedback noise ``velocity_noise`` deg/s
        (standard deviation; ``seed`` its generator's). Calls that would crash the real SDK are
        counted (:meth:`crashes`), not crashed."""
        self.lib.FakeKinova_Reset()
        self.set_latency(latency)
        self.set_velocity_noise(velocity_noise, seed)
        for serial in serials:
            self.lib.FakeKinova_AddDevice(serial.encode(), MODEL.encode())
        if position_deg is not None:
            self.set_position(position_deg)

    def set_position(self, degrees) -> None:
        values = (ctypes.c_double * 6)(*np.asarray(degrees, dtype=float))
        self.lib.FakeKinova_SetPosition(values)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The true joint angles (deg) and velocities (deg/s)."""
        q, dq = (ctypes.c_double * 6)(), (ctypes.c_double * 6)()
        self.lib.FakeKinova_GetState(q, dq)
        return np.array(q[:]), np.array(dq[:])

    def set_latency(self, seconds: float) -> None:
        """s each SDK call blocks (one call at a time on the bus)."""
        self.lib.FakeKinova_SetLatency(float(seconds))

    def set_home(self, degrees, speed: float = POSITION_SPEED) -> None:
        """MoveHome's target (deg) and joint speed (deg/s; also that of a position point sent
        without limitations)."""
        self.lib.FakeKinova_SetHome((ctypes.c_double * 6)(*np.asarray(degrees, dtype=float)),
                                    float(speed))

    def set_drift(self, deg_s) -> None:
        """A runaway: the joints move by themselves at ``deg_s`` (deg/s) from now, whatever they are
        sent or erased (zeros: none); the e-stop stops it."""
        self.lib.FakeKinova_SetDrift((ctypes.c_double * 6)(*np.asarray(deg_s, dtype=float)))

    def set_force(self, newton_metres) -> None:
        """GetAngularForce's joint torques (N·m, Kinova's signs) from now on (after a reset: 0.5,
        1.0, ... 3.0)."""
        self.lib.FakeKinova_SetForce((ctypes.c_double * 6)(*np.asarray(newton_metres, dtype=float)))

    def set_position_noise(self, degrees: float) -> None:
        """GetAngularPosition's noise, deg (standard deviation; 0, the default: exact)."""
        self.lib.FakeKinova_SetPositionNoise(float(degrees))

    def set_velocity_noise(self, deg_s: float, seed: int = 1) -> None:
        self.lib.FakeKinova_SetVelocityNoise(float(deg_s), int(seed))

    def set_comm_missing(self, value: bool) -> None:
        """InitAPI cannot load the communication layer (2002, ERROR_LOAD_COMM_DLL)."""
        self.lib.FakeKinova_SetCommMissing(int(bool(value)))

    def fail_next(self, function: str, code: int) -> None:
        """The next call of ``function`` (not GetDevices) returns ``code``, whatever it did."""
        self.lib.FakeKinova_FailNext(FUNCTIONS.index(function) + 1, int(code))

    def fifo_count(self) -> int:
        """Trajectory points the arm holds (the executing one included)."""
        return int(self.lib.FakeKinova_FifoCount())

    def fifo_peak(self) -> int:
        """The most points the FIFO held at once since :meth:`reset` (the executing one included)."""
        return int(self.lib.FakeKinova_FifoPeak())

    def dropped(self) -> int:
        """Points dropped because the FIFO was full."""
        return int(self.lib.FakeKinova_Dropped())

    def crashes(self) -> int:
        """Calls since :meth:`reset` that crash the real SDK (SendAdvanceTrajectory,
        RefresDevicesList before InitAPI loaded the communication layer)."""
        return int(self.lib.FakeKinova_Crashes())

    def inject_error(self, kind: int) -> None:
        self.lib.FakeKinova_InjectError(int(kind))

    def set_robot_type(self, robot_type: int) -> None:
        """QuickStatus.RobotType from now on (ROBOT_TYPE; 3, JACOV2_6DOF_SERVICE, after reset)."""
        self.lib.FakeKinova_SetRobotType(int(robot_type))

    def set_estop(self, pressed: bool) -> None:
        self.lib.FakeKinova_SetEStop(int(bool(pressed)))

    def set_unplugged(self, value: bool) -> None:
        self.lib.FakeKinova_SetUnplugged(int(bool(value)))

    def set_cold_boot(self, value: bool) -> None:
        """As after power-up: the next StartControlAPI is ignored until a StopControlAPI."""
        self.lib.FakeKinova_SetColdBoot(int(bool(value)))

    @property
    def control_on(self) -> bool:
        return bool(self.lib.FakeKinova_ControlOn())

    @property
    def angular(self) -> bool:
        """In angular control (SetAngularControl); False in Cartesian control (MoveHome ends there)."""
        return bool(self.lib.FakeKinova_Angular())

    @property
    def initialized(self) -> bool:
        return bool(self.lib.FakeKinova_Initialized())

    def sizeof(self, which: int) -> int:
        return int(self.lib.FakeKinova_Sizeof(which))

    def call_count(self) -> int:
        return int(self.lib.FakeKinova_CallCount())

    def calls(self, since: int = 0, function: str | None = None,
              until: int | None = None) -> list[Call]:
        """The recorded calls from index ``since`` to ``until`` (excluded; default: all so far),
        only ``function``'s if given."""
        out, record = [], _Call()
        for index in range(since, self.call_count() if until is None else until):
            if not self.lib.FakeKinova_GetCall(index, ctypes.byref(record)):
                continue
            name = FUNCTIONS[record.function - 1]
            if function is None or name == function:
                out.append(Call(record.t, name, record.result, record.type,
                                np.array(record.values[:6], dtype=float), record.start))
        return out
