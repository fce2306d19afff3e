"""The adapter contract (ahrm_stack/hardware/protocol.py) that every backend passes; run against the sim
backend in fast (unpaced) mode, the Kortex backend on the fake ``kortex_api`` (tests/fake_kortex_api,
on the wall clock) and the Kinova Gen2 backend on the fake SDK (tests/fake_kinova_sdk, compiled
here; real time). A new backend adds a factory to BACKENDS."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from ahrm_stack.hardware.protocol import (ArmAdapter, ArmFaultError, ArmState, CommandRefusedError,
                               FastClock, Fault, HardwareError, NotConnectedError, ServoingMode)


def _sim(task_config) -> ArmAdapter:
    from ahrm_stack.sim_arm import SimArm

    return SimArm(task_config, seed=0, clock=FastClock())


def _kortex(task_config, command_timeout: float = 5.0) -> ArmAdapter:
    """KortexArm over the fake arm. Its command watchdog is relaxed to 5 s here: these tests hold
    one command for up to 0.5 s, which the configured watchdog (1.5 periods) rightly stops
    (tests/test_kortex_backend.py tests the watchdog)."""
    from fake_kortex_api.rig import make_for, options

    adapter, _ = make_for(_robot(task_config.robot),
                          opts=options(watchdog_timeout=command_timeout,
                                       watchdog_poll=min(command_timeout, options().watchdog_poll)))
    return adapter


@functools.lru_cache(maxsize=None)
def _robot(name: str):
    from ahrm_stack.robot import describe, make_arm

    return describe(name, make_arm(name))


def _kinova_gen2(task_config, command_timeout: float = 1.0) -> ArmAdapter:
    """The Gen2 backend on the fake SDK. The contract holds one command for up to 0.5 s, so its
    command watchdog is set to 1 s here (deploy uses configs/deploy.yaml's two periods)."""
    from fake_kinova_sdk.fake import CompilerMissing, FakeSdk, SERIAL, session_library

    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm

    try:
        library = session_library()
    except CompilerMissing as error:
        pytest.skip(str(error))
    robot = _robot(task_config.robot)
    FakeSdk(library).reset(position_deg=np.degrees(task_config.arm.home))  # gen2: joints as Kinova's
    settings = dataclasses.replace(load_deploy_settings().kinova_gen2, library=str(library),
                                   serial=SERIAL)
    return KinovaGen2Arm(robot, settings, command_timeout_s=command_timeout)


BACKENDS = {"sim": _sim, "kortex": _kortex, "kinova-gen2": _kinova_gen2}


@pytest.fixture(params=sorted(BACKENDS))
def arm(request, task_config):
    adapter = BACKENDS[request.param](task_config)
    yield adapter
    adapter.disconnect()


@pytest.fixture
def connected(arm):
    arm.connect()
    return arm


def _speeds(arm: ArmAdapter, joint: int, speed: float) -> np.ndarray:
    command = np.zeros(arm.num_joints)
    command[joint] = speed
    return command


def test_description_needs_no_connection(arm):
    assert not arm.is_connected
    assert len(arm.joint_names) == arm.num_joints == arm.velocity_limit.shape[0]
    assert (arm.velocity_limit > 0).all() and np.isfinite(arm.velocity_limit).all()


@pytest.mark.parametrize("call", [
    lambda a: a.refresh_feedback(), lambda a: a.send_joint_speeds(np.zeros(a.num_joints)),
    lambda a: a.stop(), lambda a: a.apply_emergency_stop(), lambda a: a.clear_faults(),
    lambda a: a.servoing_mode, lambda a: a.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)])
def test_every_call_needs_a_connection(arm, call):
    with pytest.raises(NotConnectedError):
        call(arm)
    arm.connect()
    arm.disconnect()
    with pytest.raises(NotConnectedError):
        call(arm)


def test_connect_and_disconnect(arm):
    arm.connect()
    assert arm.is_connected
    assert arm.servoing_mode == ServoingMode.SINGLE_LEVEL_SERVOING
    with pytest.raises(Exception):
        arm.connect()  # twice is an error
    arm.disconnect()
    assert not arm.is_connected
    arm.disconnect()  # idempotent
    with arm:  # context manager
        assert arm.is_connected
    assert not arm.is_connected


def test_feedback_shape_and_health(connected):
    first = connected.refresh_feedback()
    connected.clock.sleep(0.01)
    second = connected.refresh_feedback()
    n = connected.num_joints
    for frame in (first, second):
        assert frame.position.shape == frame.velocity.shape == frame.torque.shape == (n,)
        assert frame.healthy and frame.faults == Fault.NONE
        assert frame.arm_state == ArmState.SERVOING_READY
    assert second.frame_id > first.frame_id and second.timestamp > first.timestamp


def test_units_are_radians_and_seconds(connected):
    """0.2 rad/s on the base joint for 0.5 s turns it by about 0.1 rad (not 0.1 degree)."""
    start = connected.refresh_feedback().position
    sent = connected.send_joint_speeds(_speeds(connected, 0, 0.2))
    np.testing.assert_allclose(sent, _speeds(connected, 0, 0.2))
    connected.clock.sleep(0.5)
    frame = connected.refresh_feedback()
    assert frame.position[0] - start[0] == pytest.approx(0.1, rel=0.2)
    assert frame.velocity[0] == pytest.approx(0.2, rel=0.1)


def test_command_round_trip_returns_what_was_sent(connected):
    command = 0.5 * connected.velocity_limit * np.linspace(-1, 1, connected.num_joints)
    sent = connected.send_joint_speeds(command.tolist())
    assert isinstance(sent, np.ndarray) and sent.dtype == float
    np.testing.assert_array_equal(sent, command)


def test_stop_brings_the_arm_to_rest(connected):
    connected.send_joint_speeds(_speeds(connected, 0, 0.5))
    connected.clock.sleep(0.3)
    assert abs(connected.refresh_feedback().velocity[0]) > 0.3
    connected.stop()
    connected.clock.sleep(0.2)
    assert np.abs(connected.refresh_feedback().velocity).max() < 0.05


@pytest.mark.parametrize("bad", ["over_limit", "nan", "inf", "wrong_size"])
def test_limits_are_rechecked_at_the_adapter(connected, bad):
    limit = connected.velocity_limit
    command = {"over_limit": _speeds(connected, 1, 1.01 * limit[1]),
               "nan": _speeds(connected, 2, np.nan), "inf": _speeds(connected, 0, np.inf),
               "wrong_size": np.zeros(connected.num_joints + 1)}[bad]
    with pytest.raises(CommandRefusedError):
        connected.send_joint_speeds(command)
    frame = connected.refresh_feedback()
    assert frame.arm_state == ArmState.IN_FAULT and Fault.EMERGENCY_STOP in frame.faults
    with pytest.raises(ArmFaultError):  # refused and e-stopped: nothing moves until cleared
        connected.send_joint_speeds(np.zeros(connected.num_joints))


def test_emergency_stop_blocks_commands_until_faults_are_cleared(connected):
    connected.send_joint_speeds(_speeds(connected, 0, 0.4))
    connected.clock.sleep(0.2)
    connected.apply_emergency_stop()
    frame = connected.refresh_feedback()
    assert frame.arm_state == ArmState.IN_FAULT and not frame.healthy
    for _ in range(3):
        with pytest.raises(ArmFaultError):
            connected.send_joint_speeds(_speeds(connected, 0, 0.1))
    connected.stop()  # stopping is always allowed
    connected.clock.sleep(0.2)
    assert np.abs(connected.refresh_feedback().velocity).max() < 0.05
    connected.clear_faults()
    frame = connected.refresh_feedback()
    assert frame.healthy and frame.arm_state == ArmState.SERVOING_READY
    np.testing.assert_array_equal(connected.send_joint_speeds(_speeds(connected, 0, 0.1)),
                                  _speeds(connected, 0, 0.1))


def test_joint_speeds_need_single_level_servoing(connected):
    connected.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING)
    assert connected.servoing_mode == ServoingMode.LOW_LEVEL_SERVOING
    with pytest.raises(HardwareError):
        connected.send_joint_speeds(np.zeros(connected.num_joints))
    connected.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
    connected.send_joint_speeds(np.zeros(connected.num_joints))


# ------------------------------------------------------------------ the command gate (protocol.py)


def test_a_speed_at_its_limit_is_sent_and_the_next_float_beyond_it_is_refused_and_e_stops(connected):
    limit = connected.velocity_limit
    connected.send_joint_speeds(_speeds(connected, 0, -limit[0]))  # inclusive: sent
    connected.stop()
    assert connected.refresh_feedback().faults == Fault.NONE
    with pytest.raises(CommandRefusedError, match=r"joint speed \[0\]"):
        connected.send_joint_speeds(_speeds(connected, 0, np.nextafter(limit[0], np.inf)))
    frame = connected.refresh_feedback()
    assert Fault.EMERGENCY_STOP in frame.faults and Fault.LIMIT in frame.faults
    connected.clear_faults()
    assert connected.refresh_feedback().faults == Fault.NONE


def test_a_bad_command_in_fault_is_refused_as_the_fault_without_another_e_stop(connected):
    connected.apply_emergency_stop()
    for bad in (_speeds(connected, 0, np.nan), _speeds(connected, 1, 10 * connected.velocity_limit[1])):
        with pytest.raises(ArmFaultError, match="EMERGENCY_STOP"):
            connected.send_joint_speeds(bad)
    assert Fault.LIMIT not in connected.refresh_feedback().faults  # no refusal was recorded


def test_a_bad_command_outside_single_level_servoing_is_refused_without_an_e_stop(connected):
    connected.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING)
    with pytest.raises(ArmFaultError, match="single-level servoing"):
        connected.send_joint_speeds(_speeds(connected, 0, np.inf))
    connected.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
    assert connected.refresh_feedback().faults == Fault.NONE
    connected.send_joint_speeds(np.zeros(connected.num_joints))


# ------------------------------------------------------------------ the command watchdog (protocol.py)

WATCHDOG_TIMEOUT = 0.1  # s


@pytest.fixture(params=["kortex", "kinova-gen2"])  # the sim has no command watchdog (its docstring)
def watched(request, task_config):
    adapter = BACKENDS[request.param](task_config, command_timeout=WATCHDOG_TIMEOUT)
    adapter.connect()
    yield adapter
    adapter.disconnect()


def test_the_command_watchdog_stops_the_arm_and_latches_until_faults_are_cleared(watched):
    """A moving command, then silence beyond the command timeout: the arm is stopped by the
    adapter, the feedback reports WATCHDOG, commands are refused until clear_faults()."""
    move = _speeds(watched, 0, 0.3)
    watched.send_joint_speeds(move)
    watched.clock.sleep(WATCHDOG_TIMEOUT + 0.25)  # the control loop stalls
    frame = watched.refresh_feedback()
    assert Fault.WATCHDOG in frame.faults and not frame.healthy
    watched.clock.sleep(0.1)
    assert np.abs(watched.refresh_feedback().velocity).max() < 0.05  # stopped
    with pytest.raises(ArmFaultError, match="WATCHDOG"):
        watched.send_joint_speeds(move)  # a stalled loop does not resume motion silently
    with pytest.raises(ArmFaultError, match="WATCHDOG"):
        watched.send_joint_speeds(np.zeros(watched.num_joints))
    watched.clear_faults()
    assert watched.refresh_feedback().faults == Fault.NONE
    np.testing.assert_array_equal(watched.send_joint_speeds(move), move)
    watched.stop()


def test_a_zero_command_or_a_stop_disarms_the_command_watchdog(watched):
    for halt in (lambda: watched.send_joint_speeds(np.zeros(watched.num_joints)), watched.stop):
        watched.send_joint_speeds(_speeds(watched, 0, 0.3))
        halt()
        watched.clock.sleep(WATCHDOG_TIMEOUT + 0.25)
        assert watched.refresh_feedback().faults == Fault.NONE
