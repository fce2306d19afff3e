"""Kinova's machine-wide SDK lock (ahrm_stack/hardware/kinova_gen2/lock.py) read from real POSIX named
semaphores (a private name per test, made and removed here with the C library's own sem_open /
sem_post / sem_unlink), and the warning connect() logs before InitAPI."""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import sys

import numpy as np
import pytest

from ahrm_stack.hardware.kinova_gen2.lock import lock_value, lock_warning

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="POSIX named semaphores")
O_CREAT, O_EXCL = os.O_CREAT, os.O_EXCL


@pytest.fixture
def semaphore():
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    libc.sem_open.restype = ctypes.c_void_p
    libc.sem_open.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_uint, ctypes.c_uint]
    libc.sem_post.argtypes = libc.sem_close.argtypes = [ctypes.c_void_p]
    name = f"/ahrm-test-lock-{os.getpid()}"
    made = []

    def make(value: int):
        handle = libc.sem_open(name.encode(), O_CREAT | O_EXCL, 0o600, value)
        assert handle not in (None, ctypes.c_void_p(-1).value), ctypes.get_errno()
        made.append(handle)
        return name, lambda: libc.sem_post(ctypes.c_void_p(handle))

    yield make
    for handle in made:
        libc.sem_close(ctypes.c_void_p(handle))
    libc.sem_unlink(name.encode())


def test_lock_values_and_the_warning(semaphore):
    assert lock_value("/ahrm-test-lock-absent") is None
    assert lock_warning("/ahrm-test-lock-absent") is None
    name, post = semaphore(0)
    assert lock_value(name) == 0
    line = lock_warning(name, patience=0.05)
    assert line is not None and "\n" not in line and f"rm /dev/shm/sem.{name[1:]}" in line
    post()
    assert lock_value(name) == 1 and lock_warning(name) is None


def test_connect_warns_about_a_stuck_lock(semaphore, monkeypatch, caplog):
    """connect() reads the lock before InitAPI and logs the line (here: a private lock at 0 in place
    of Kinova's), then goes on."""
    fake_module = pytest.importorskip("fake_kinova_sdk.fake")
    try:
        library = fake_module.session_library()
    except fake_module.CompilerMissing as error:
        pytest.skip(str(error))
    import dataclasses

    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.robot import describe, make_arm
    from ahrm_stack.hardware import kinova_gen2
    from ahrm_stack.hardware.kinova_gen2 import arm as gen2_arm, lock as gen2_lock

    name, _ = semaphore(0)
    monkeypatch.setattr(gen2_arm, "lock_warning",
                        lambda: gen2_lock.lock_warning(name, patience=0.05))
    config = load_config()
    fake = fake_module.FakeSdk(library)
    fake.reset(position_deg=np.degrees(config.task.arm.home), latency=0.0)
    settings = dataclasses.replace(load_deploy_settings().kinova_gen2, library=str(library),
                                   serial=fake_module.SERIAL)
    arm = kinova_gen2.KinovaGen2Arm(describe(config.task.robot, make_arm(config.task.robot)),
                                    settings, 0.1)
    with caplog.at_level(logging.WARNING, logger="ahrm_stack.hardware.kinova_gen2"):
        arm.connect()
    arm.disconnect()
    assert any(f"/dev/shm/sem.{name[1:]}" in r.getMessage() for r in caplog.records)
