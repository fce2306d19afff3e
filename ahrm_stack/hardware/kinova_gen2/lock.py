"""Kinova's machine-wide SDK lock: is it free before ``InitAPI``? (:func:`lock_warning`)

Kinova's Gen2 SDK serialises every process on the machine with one POSIX named semaphore,
``/KinovaMutex`` (the file ``/dev/shm/sem.KinovaMutex``; ``InitAPI`` creates it with the value 1).
Its getters without an arm return 1015 *keeping* it until ``CloseAPI`` posts it (observed on the
vendored x86_64 binary, 2026-12-05: tests/fake_kinova_sdk/no_arm.py ``LOCKING``), so a process
killed in between leaves it at 0 and every later Kinova process blocks forever in its first call
that takes it. :meth:`~ahrm_stack.hardware.kinova_gen2.KinovaGen2Arm.connect` logs :func:`lock_warning`'s line
before ``InitAPI``, so a hang that follows is explained; it does not refuse (another Kinova
program may hold the lock for a moment, legitimately). docs/hardware.md's checklist says how to
clear it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time

LOCK_NAME = "/KinovaMutex"
SEM_FAILED = ctypes.c_void_p(-1).value  # sem_open's failure value, (sem_t *) -1


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name, use_errno=True)
    except OSError:
        return None
    libc.sem_open.restype = ctypes.c_void_p
    libc.sem_open.argtypes = [ctypes.c_char_p, ctypes.c_int]
    libc.sem_getvalue.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)]
    libc.sem_close.argtypes = [ctypes.c_void_p]
    return libc


def lock_value(name: str = LOCK_NAME) -> int | None:
    """The named semaphore's value (1: free, 0: taken), or None when it does not exist (no Kinova
    process ran since boot) or cannot be read. Opening it changes nothing."""
    libc = _libc()
    if libc is None:
        return None
    handle = libc.sem_open(name.encode(), 0)
    if handle is None or handle == SEM_FAILED:
        return None
    try:
        value = ctypes.c_int(0)
        if libc.sem_getvalue(ctypes.c_void_p(handle), ctypes.byref(value)) != 0:
            return None
        return int(value.value)
    finally:
        libc.sem_close(ctypes.c_void_p(handle))


def lock_warning(name: str = LOCK_NAME, patience: float = 0.2, poll: float = 0.02) -> str | None:
    """One line when the lock stays taken for ``patience`` s (read every ``poll`` s), else None."""
    deadline = time.perf_counter() + patience
    while True:
        value = lock_value(name)
        if value is None or value > 0:
            return None
        if time.perf_counter() >= deadline:
            return (f"Kinova's SDK lock /dev/shm/sem.{name.lstrip('/')} has been taken for "
                    f"{patience:g} s: another Kinova program is running, or one was killed inside "
                    f"an SDK call; if the next calls hang and no other Kinova program runs, "
                    f"`rm /dev/shm/sem.{name.lstrip('/')}` (docs/hardware.md)")
        time.sleep(poll)
