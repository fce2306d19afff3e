"""What Kinova's real Gen2 SDK returns without an arm, and a runner that replays it on any build.

:data:`SEQUENCES` are calls in order with the codes Kinova's x86_64 binary
(ahrm_stack/hardware/vendor/kinova_gen2/, kinova-ros commit 924781d) returned on 2026-12-04 on this project's
machine (Debian 12, libusb 1.0.26, no arm on the bus); GetDevices gives ``(count, result)``; a
set lists codes seen in different runs (:data:`EITHER`, after a CloseAPI and a new InitAPI the real
SDK answers SendAdvanceTrajectory with one or the other, by timing).
:data:`CRASHES` are the calls after which that binary died of SIGSEGV. Not replayed: ``MoveHome``
after an ``InitAPI`` that found no arm (1015) did not return within 60 s (observed 2026-12-05): the
adapter calls it only once connected to the arm by serial. (:data:`LOCKING`: why the getters
without an arm are replayed one per process.) The tests replay both on the
real binary (in child processes: tests/test_kinova_gen2_vendor.py) and on the fake
(fake_kinova.c, in process: its crashes are counted), so the fake answers as the real SDK does.

As a child process: ``python -m fake_kinova_sdk.no_arm LIBRARY CALL...`` loads LIBRARY with
:mod:`ctypes` (the argument types of ahrm_stack/hardware/kinova_gen2/sdk.py), makes the calls and prints
``CALL CODE`` per call, flushed, so a crash shows as the return code after the last line printed.
"""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

Code = int | tuple[int, int]
Expected = Code | frozenset
EITHER = frozenset({1, 2004})  # SendAdvanceTrajectory without an arm after InitAPI was repeated

#: name -> (whether InitAPI can load the communication layer, [(call, code), ...])
SEQUENCES: dict[str, tuple[bool, list[tuple[str, Expected]]]] = {
    "before InitAPI": (True, [
        ("GetAngularPosition", 1010), ("GetAngularVelocity", 2101), ("GetAngularForce", 2101),
        ("GetSensorsInfo", 2101), ("GetSystemErrorCount", 2101), ("GetSystemError", 2101),
        ("GetDevices", (0, 2101)), ("SetActiveDevice", 2101), ("StartControlAPI", 2101),
        ("SetAngularControl", 2101), ("StopControlAPI", 2101), ("EraseAllTrajectories", 1),
        ("MoveHome", 2101), ("CloseAPI", 1)]),
    "InitAPI without an arm": (True, [
        ("InitAPI", 1015), ("SendAdvanceTrajectory", 1), ("EraseAllTrajectories", 1),
        ("StartControlAPI", 1), ("SetAngularControl", 1), ("SendAdvanceTrajectory", 1),
        ("GetAngularPosition", 1015),  # the other getters keep the lock here: see LOCKING
        ("SendAdvanceTrajectory", 1),
        ("GetDevices", (0, 1010)),  # from here on SendAdvanceTrajectory fails with JACO_COMM_FAILED
        ("SetActiveDevice", 1010), ("RefresDevicesList", 1001), ("SendAdvanceTrajectory", 2004),
        ("EraseAllTrajectories", 1), ("StopControlAPI", 1),
        ("InitAPI", 1),  # a second InitAPI "succeeds" without an arm
        ("GetDevices", (0, 1010)), ("CloseAPI", 1),
        ("SendAdvanceTrajectory", 2101), ("StartControlAPI", 2101), ("GetAngularPosition", 1010),
        ("EraseAllTrajectories", 1), ("StopControlAPI", 2101), ("CloseAPI", 1),
        ("InitAPI", 1015), ("SendAdvanceTrajectory", EITHER), ("CloseAPI", 1)]),
    "communication layer not found": (False, [
        ("InitAPI", 2002), ("MoveHome", 2101), ("GetDevices", (0, 2101)), ("StartControlAPI", 2101),
        ("GetAngularPosition", 1010), ("EraseAllTrajectories", 1), ("StopControlAPI", 2101),
        ("CloseAPI", 1), ("CloseAPI", 1)]),
}

#: Getters that, without an arm, return 1015 and keep Kinova's lock: the named semaphore
#: /dev/shm/sem.KinovaMutex, shared by every process on the machine (observed 2026-12-05 from a
#: fresh semaphore). The next call that takes it (those, SendAdvanceTrajectory, ...) blocks, in any
#: process, until CloseAPI posts it; a process
#: killed there leaves it taken (every later Kinova process hangs; docs/hardware.md says how to
#: clear it). So each is replayed alone: InitAPI, the getter, CloseAPI.
LOCKING = ("GetAngularVelocity", "GetAngularForce", "GetSensorsInfo", "GetSystemErrorCount",
           "GetSystemError")
for _getter in LOCKING:
    SEQUENCES[f"{_getter} without an arm"] = (True, [("InitAPI", 1015), (_getter, 1015),
                                                       ("CloseAPI", 1)])

#: name -> (whether InitAPI can load the communication layer, calls; the last one crashes)
CRASHES: dict[str, tuple[bool, list[str]]] = {
    "SendAdvanceTrajectory before InitAPI": (True, ["SendAdvanceTrajectory"]),
    "RefresDevicesList before InitAPI": (True, ["RefresDevicesList"]),
    "SendAdvanceTrajectory after InitAPI returned 2002": (False, ["InitAPI", "SendAdvanceTrajectory"]),
}


def bind(library: Path | str) -> ctypes.CDLL:
    """The library, loaded with ahrm_stack/hardware/kinova_gen2/sdk.py's argument and return types."""
    from ahrm_stack.hardware.kinova_gen2 import SIGNATURES

    lib = ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
    for name, argtypes in SIGNATURES.items():
        function = getattr(lib, name)
        function.argtypes = list(argtypes)
        function.restype = ctypes.c_int
    return lib


def call(lib: ctypes.CDLL, name: str) -> Code:
    """One call with zeroed arguments (a zero velocity point, device, index 0); its code."""
    from ahrm_stack.hardware.kinova_gen2 import (MAX_KINOVA_DEVICE, AngularPosition, KinovaDevice, SensorsInfo,
                                      SystemError, velocity_point)

    if name == "GetDevices":
        found, result = (KinovaDevice * MAX_KINOVA_DEVICE)(), ctypes.c_int(-1)
        count = lib.GetDevices(found, ctypes.byref(result))
        return (int(count), int(result.value))
    if name == "SetActiveDevice":
        return int(lib.SetActiveDevice(KinovaDevice()))
    if name == "SendAdvanceTrajectory":
        return int(lib.SendAdvanceTrajectory(velocity_point([0.0] * 6)))
    if name in ("GetAngularPosition", "GetAngularVelocity", "GetAngularForce"):
        return int(getattr(lib, name)(ctypes.byref(AngularPosition())))
    if name == "GetSensorsInfo":
        return int(lib.GetSensorsInfo(ctypes.byref(SensorsInfo())))
    if name == "GetSystemErrorCount":
        return int(lib.GetSystemErrorCount(ctypes.byref(ctypes.c_uint(0))))
    if name == "GetSystemError":
        return int(lib.GetSystemError(ctypes.c_uint(0), ctypes.byref(SystemError())))
    return int(getattr(lib, name)())


def matches(got: list[tuple[str, Code]], expected: list[tuple[str, Expected]]) -> bool:
    """``got`` (calls and codes) is what ``expected`` allows, call by call."""
    return len(got) == len(expected) and all(
        name == want_name and (code in want if isinstance(want, frozenset) else code == want)
        for (name, code), (want_name, want) in zip(got, expected))


def parse(output: str) -> list[tuple[str, Code]]:
    """The child's printed lines -> [(call, code), ...]."""
    out: list[tuple[str, Code]] = []
    for line in output.splitlines():
        name, _, text = line.partition(" ")
        values = [int(v) for v in text.split(",")]
        out.append((name, (values[0], values[1]) if len(values) == 2 else values[0]))
    return out


def main(argv: list[str]) -> int:
    lib = bind(argv[0])
    for name in argv[1:]:
        code = call(lib, name)
        text = ",".join(map(str, code)) if isinstance(code, tuple) else str(code)
        print(f"{name} {text}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
