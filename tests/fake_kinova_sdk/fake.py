"""Build and drive the fake Kinova Gen2 SDK (fake_kinova.c) from the tests and benchmarks.

:func:`build` compiles it with the system C compiler (``cc -shared -fPIC``) into a folder;
:func:`session_library` does so once per process into a temporary folder. :class:`FakeSdk` opens
the same file (the dynamic loader returns the same handle, so it shares the adapter's state) and
exposes the test-only functions and the call log.
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

#: the function ids of the call log (the enum in fake_kinova.c)
FUNCTIONS = ("InitAPI", "CloseAPI", "GetDevices", "SetActiveDevice", "StartControlAPI",
             "StopControlAPI", "SetAngularControl", "SendAdvanceTrajectory",
             "EraseAllTrajectories", "GetAngularPosition", "GetAngularVelocity", "GetAngularForce",
             "GetSensorsInfo", "GetSystemErrorCount", "GetSystemError", "RefresDevicesList",
             "GetAPIVersion")


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


@functools.lru_cache(maxsize=None)
def session_library() -> Path:
    """The fake, compiled once per process into a temporary folder."""
    return build(Path(tempfile.mkdtemp(prefix="fake-kinova-")))


class _Call(ctypes.Structure):
    _fields_ = [("t", ctypes.c_double), ("function", ctypes.c_int), ("result", ctypes.c_int),
                ("type", ctypes.c_int), ("values", ctypes.c_float * 7)]


@dataclasses.dataclass(frozen=True)
class Call:
    """One recorded SDK call: ``t`` (s, CLOCK_MONOTONIC = time.perf_counter), the function's
    name, its return code, ``type`` (the trajectory point's POSITION_TYPE, or a count/index) and
    ``values`` (a velocity command in deg/s, or the positions read)."""

    t: float
    function: str
    result: int
    type: int
    values: np.ndarray


class FakeSdk:
    """The fake's test-only side, on the library at ``path``."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.lib = ctypes.CDLL(str(self.path), mode=ctypes.RTLD_GLOBAL)
        lib = self.lib
        lib.FakeKinova_AddDevice.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
        lib.FakeKinova_SetPosition.argtypes = [ctypes.POINTER(ctypes.c_double)]
        lib.FakeKinova_GetState.argtypes = [ctypes.POINTER(ctypes.c_double)] * 2
        lib.FakeKinova_SetCommandExpiry.argtypes = [ctypes.c_double]
        lib.FakeKinova_InjectError.argtypes = [ctypes.c_int]
        lib.FakeKinova_SetEStop.argtypes = [ctypes.c_int]
        lib.FakeKinova_SetUnplugged.argtypes = [ctypes.c_int]
        lib.FakeKinova_CallCount.restype = ctypes.c_long
        lib.FakeKinova_GetCall.argtypes = [ctypes.c_long, ctypes.POINTER(_Call)]
        lib.FakeKinova_Sizeof.restype = ctypes.c_long
        lib.FakeKinova_Sizeof.argtypes = [ctypes.c_int]

    def reset(self, serials=(SERIAL,), position_deg=None) -> None:
        """A fresh fake: no call recorded, the given arms on the bus, joints at ``position_deg``."""
        self.lib.FakeKinova_Reset()
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

    def set_command_expiry(self, seconds: float) -> None:
        self.lib.FakeKinova_SetCommandExpiry(float(seconds))

    def inject_error(self, kind: int) -> None:
        self.lib.FakeKinova_InjectError(int(kind))

    def set_estop(self, pressed: bool) -> None:
        self.lib.FakeKinova_SetEStop(int(bool(pressed)))

    def set_unplugged(self, value: bool) -> None:
        self.lib.FakeKinova_SetUnplugged(int(bool(value)))

    @property
    def control_on(self) -> bool:
        return bool(self.lib.FakeKinova_ControlOn())

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
                                np.array(record.values[:6], dtype=float)))
        return out
