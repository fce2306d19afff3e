"""The Kinova Gen2 backend (hardware/kinova_gen2.py) against the fake SDK (tests/fake_kinova_sdk),
compiled here with the system C compiler: settings, struct layouts, unit and joint conventions,
device selection, the 100 Hz sender, the command watchdog, faults, the e-stop, a lost link, and
every exit path leaving the arm stopped. Real time (the sender is a thread)."""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import math
import time

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ahrm_stack.deploy import DEPLOY_CONFIG, DeployConfigError, load_deploy_settings
from hardware.kinova_gen2 import (SYSTEM_ERROR_TYPES, AngularPosition, Gen2ConfigError,
                                  JointConvention, KinovaDevice, KinovaGen2Arm, SensorsInfo,
                                  Sdk, SystemError, TrajectoryPoint, UserPosition, check_library,
                                  kinova_positions, kinova_velocities,
                                  model_positions, model_velocities, unwrap_positions,
                                  velocity_point)
from hardware.protocol import (ArmFaultError, ArmState, ConnectionLostError, Fault, HardwareError,
                               NotConnectedError)

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
FakeSdk, SERIAL = fake_module.FakeSdk, fake_module.SERIAL

@functools.lru_cache(maxsize=None)
def _robot(name: str):
    from ahrm_stack.robot import describe, make_arm

    return describe(name, make_arm(name))


@pytest.fixture(scope="module")
def library():
    try:
        return fake_module.session_library()
    except fake_module.CompilerMissing as error:
        pytest.skip(str(error))


@pytest.fixture
def fake(library, task_config):
    sdk = FakeSdk(library)
    sdk.reset(position_deg=np.degrees(task_config.arm.home))
    return sdk


def _settings(library, **changes):
    values = {"library": str(library), "serial": SERIAL, **changes}
    return dataclasses.replace(load_deploy_settings().kinova_gen2, **values)


@pytest.fixture
def make_arm(library, task_config):
    made = []

    def make(timeout: float = 0.1, **changes) -> KinovaGen2Arm:
        arm = KinovaGen2Arm(_robot(task_config.robot), _settings(library, **changes), timeout)
        made.append(arm)
        return arm

    yield make
    for arm in made:
        arm.disconnect()


# ------------------------------------------------------------------ settings and layouts


def test_settings_errors_name_the_key(tmp_path):
    def bad(mutate) -> str:
        data = yaml.safe_load(DEPLOY_CONFIG.read_text())
        mutate(data["kinova_gen2"])
        path = tmp_path / "deploy.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(DeployConfigError) as error:
            load_deploy_settings(path)
        assert "\n" not in str(error.value)
        return str(error.value)

    assert "deploy.kinova_gen2.send_rate_hz" in bad(lambda d: d.update(send_rate_hz=0))
    assert "deploy.kinova_gen2.command_timeout" in bad(lambda d: d.update(command_timeout="2"))
    assert "deploy.kinova_gen2.speed_scale" in bad(lambda d: d.update(speed_scale=1.5))
    assert "deploy.kinova_gen2.serial" in bad(lambda d: d.update(serial=12345))
    assert "deploy.kinova_gen2.serial" in bad(lambda d: d.update(serial="X" * 25))
    assert "deploy.kinova_gen2.colour" in bad(lambda d: d.update(colour=1))
    assert "deploy.kinova_gen2.library" in bad(lambda d: d.pop("library"))
    assert "deploy.kinova_gen2.joints.jaco.sign" in bad(lambda d: d["joints"]["jaco"].update(sign=[2] * 6))
    assert "deploy.kinova_gen2.joints.jaco.offset_deg" in bad(
        lambda d: d["joints"]["jaco"].update(offset_deg=[0] * 5))
    assert "deploy.kinova_gen2.switch_interval" in bad(lambda d: d.update(switch_interval=1.0))


def test_missing_library_is_one_line_naming_the_path(tmp_path, task_config):
    settings = load_deploy_settings().kinova_gen2
    with pytest.raises(Gen2ConfigError, match=r"deploy\.kinova_gen2\.library is not set.*docs/hardware\.md"):
        check_library(settings)
    missing = tmp_path / "USBCommandLayerUbuntu.so"
    with pytest.raises(Gen2ConfigError) as error:
        KinovaGen2Arm(_robot(task_config.robot),
                      dataclasses.replace(settings, library=str(missing), serial=SERIAL), 0.1)
    message = str(error.value)
    assert str(missing) in message and "docs/hardware.md" in message and "\n" not in message


def test_serial_is_required(library, task_config):
    with pytest.raises(Gen2ConfigError, match="serial.*never the first one found"):
        KinovaGen2Arm(_robot(task_config.robot), _settings(library, serial=None), 0.1)


def test_struct_layouts_match_the_c_compiler(fake):
    """ctypes sizes = the C compiler's (the fake's structs) = the header's fields counted by hand."""
    expected = {0: (KinovaDevice, 20 + 20 + 5 * 4), 1: (AngularPosition, 7 * 4 + 3 * 4),
                2: (TrajectoryPoint, (4 + 4 + 6 * 4 + 7 * 4 + 4 + 3 * 4) + 4 + 4 + 9 * 4),
                3: (SensorsInfo, 15 * 4), 4: (SystemError, 5 * 4 + 7 + 1 + 4 + 4 + 50 * 4),
                5: (UserPosition, 4 + 4 + 6 * 4 + 7 * 4 + 4 + 3 * 4)}
    for which, (struct, size) in expected.items():
        assert ctypes.sizeof(struct) == size == fake.sizeof(which), struct.__name__
    assert SYSTEM_ERROR_TYPES[9] == "errorlog_voltage" and len(SYSTEM_ERROR_TYPES) == 18


# ------------------------------------------------------------------ conversions (pure)


def test_unit_and_joint_conventions_by_hand():
    identity = JointConvention((1,) * 6, (0.0,) * 6)
    np.testing.assert_allclose(model_positions([180, 90, 0, 360, -90, 45], identity),
                               [math.pi, math.pi / 2, 0, 2 * math.pi, -math.pi / 2, math.pi / 4])
    # kinova-ros's 2013 DH convention: (180 - k1), (k2 - 270), (90 - k3), (180 - k4), ...
    dh = JointConvention((-1, 1, -1, -1, -1, -1), (180.0, -270.0, 90.0, 180.0, 180.0, 260.0))
    kinova = np.array([275.0, 167.5, 57.5, 240.0, 82.5, 75.0])
    expected_deg = [180 - 275, 167.5 - 270, 90 - 57.5, 180 - 240, 180 - 82.5, 260 - 75]
    np.testing.assert_allclose(np.degrees(model_positions(kinova, dh)), expected_deg)
    np.testing.assert_allclose(kinova_positions(model_positions(kinova, dh), dh), kinova)
    # 0.2 rad/s = 11.459 deg/s; a negative sign flips it
    np.testing.assert_allclose(kinova_velocities([0.2, 0, 0, 0, 0, -0.1], dh),
                               [-0.2 * 180 / math.pi, 0, 0, 0, 0, 0.1 * 180 / math.pi])
    # GetAngularVelocity: half the real value; negatives as 360 - |v|
    np.testing.assert_allclose(model_velocities([5.0, 175.0, 0, 0, 0, 0], identity, 2.0),
                               np.radians([10.0, -10.0, 0, 0, 0, 0]))


@hypothesis_settings(max_examples=100, deadline=None)
@given(kinova=arrays(float, 6, elements=st.floats(-720, 720)),
       signs=st.lists(st.sampled_from([1, -1]), min_size=6, max_size=6),
       offsets=st.lists(st.floats(-360, 360), min_size=6, max_size=6),
       speeds=arrays(float, 6, elements=st.floats(-1.0, 1.0)))
def test_conventions_round_trip(kinova, signs, offsets, speeds):
    """Kinova -> model -> Kinova is the identity; a command's sign and scale survive the reported
    velocity's encoding (half, negatives as 360 - |v|) and its decoding."""
    convention = JointConvention(tuple(signs), tuple(offsets))
    np.testing.assert_allclose(kinova_positions(model_positions(kinova, convention), convention),
                               kinova, atol=1e-9)
    degrees = kinova_velocities(speeds, convention)  # deg/s on the arm
    reported = np.where(degrees < 0, degrees + 360.0, degrees) / 2.0  # the firmware's encoding
    np.testing.assert_allclose(model_velocities(reported, convention, 2.0), speeds, atol=1e-12)


def test_unwrapping_by_hand(task_config):
    robot = _robot(task_config.robot)
    q = np.radians([359.0, -150.0, 20.0, 5.0, 10.0, 0.0])
    out = unwrap_positions(q, np.radians([0.0, 200.0, 20.0, 360.0, 10.0, 0.0]), robot)
    limited = robot.limited
    expected = np.radians([-1.0, 210.0, 20.0, 365.0, 10.0, 0.0])
    np.testing.assert_allclose(out[limited], expected[limited], atol=1e-12)
    np.testing.assert_allclose(out[~limited], expected[~limited], atol=1e-12)


# ------------------------------------------------------------------ the session


def test_connect_selects_the_serial_and_disconnect_stops(fake, make_arm):
    fake.reset(serials=("PJ00000000000000001", SERIAL), position_deg=fake.state()[0])
    arm = make_arm()
    arm.connect()
    chosen = fake.calls(function="SetActiveDevice")
    assert chosen[-1].result == 1 and chosen[-1].type == 1  # the second device: ours
    assert fake.control_on
    mark = fake.call_count()
    arm.disconnect()
    names = [c.function for c in fake.calls(mark)]
    assert names[-3:] == ["EraseAllTrajectories", "StopControlAPI", "CloseAPI"]
    zero = [c for c in fake.calls(mark, "SendAdvanceTrajectory")]
    assert zero and np.all(zero[-1].values == 0)
    assert not fake.control_on and not fake.initialized
    mark = fake.call_count()
    time.sleep(0.05)
    assert fake.call_count() == mark  # the sender is gone
    arm.disconnect()  # idempotent


def test_unknown_serial_is_refused_and_the_api_closed(fake, make_arm):
    fake.reset(serials=("PJ00000000000000001", "PJ00000000000000002"))
    arm = make_arm()
    with pytest.raises(HardwareError) as error:
        arm.connect()
    assert SERIAL in str(error.value) and "PJ00000000000000001" in str(error.value)
    assert not arm.is_connected and not fake.initialized
    assert [c.function for c in fake.calls()][-2:] == ["StopControlAPI", "CloseAPI"]
    assert not fake.calls(function="SetActiveDevice")  # never "the first one found"


def test_no_arm_on_the_bus(fake, make_arm):
    fake.reset(serials=())
    with pytest.raises(HardwareError, match="ERROR_NO_DEVICE_FOUND"):
        make_arm().connect()
    assert not fake.initialized


# ------------------------------------------------------------------ 100 Hz and the watchdog


def test_sender_resends_at_100_hz_and_the_arm_keeps_full_speed(fake, make_arm):
    """A 20 Hz caller; the fake's command expires after 25 ms. With the sender the joint moves at
    the commanded speed; sending only at 20 Hz (no sender) it moves at ~25/50 of it."""
    arm = make_arm(timeout=0.1)
    arm.connect()
    speed = 0.3  # rad/s, joint 1
    start_deg = fake.state()[0][0]
    mark = fake.call_count()
    t0 = time.perf_counter()
    for _ in range(20):  # 1 s at 20 Hz
        arm.send_joint_speeds(np.array([speed, 0, 0, 0, 0, 0]))
        time.sleep(0.05)
    moved = math.radians(fake.state()[0][0] - start_deg)
    elapsed = time.perf_counter() - t0
    sends = fake.calls(mark, "SendAdvanceTrajectory")
    gaps = np.diff([c.t for c in sends])
    assert np.median(gaps) == pytest.approx(0.010, abs=0.001)
    assert len(sends) >= 0.75 * 100 * elapsed  # (a loaded machine delays some resends)
    assert moved == pytest.approx(speed * elapsed, rel=0.2)
    np.testing.assert_allclose(sends[-1].values, [math.degrees(speed), 0, 0, 0, 0, 0], rtol=1e-6)
    arm.disconnect()

    # the same caller without the sender: the joint moves about half as far
    fake.reset(position_deg=np.zeros(6))
    raw = Sdk(fake.path)
    raw.call("InitAPI")
    device = raw.devices()[0]
    raw.call("SetActiveDevice", device)
    raw.call("StartControlAPI")
    raw.call("SetAngularControl")
    t0 = time.perf_counter()
    for _ in range(20):
        raw.call("SendAdvanceTrajectory", velocity_point([math.degrees(speed), 0, 0, 0, 0, 0]))
        time.sleep(0.05)
    slow = math.radians(fake.state()[0][0]) / (time.perf_counter() - t0)
    raw.call("CloseAPI")
    assert 0.3 * speed < slow < 0.65 * speed  # ~25 ms of motion per 50 ms: about half speed


def test_watchdog_stops_a_frozen_caller_within_20_ms(fake, make_arm):
    arm = make_arm(timeout=0.1)
    arm.connect()
    for _ in range(3):
        arm.send_joint_speeds(np.array([0.2, 0.1, 0, 0, 0, 0]))
        time.sleep(0.05)
    mark = fake.call_count()
    time.sleep(0.25)  # the caller freezes
    assert len(arm.watchdog_stops) == 1
    stop = arm.watchdog_stops[0]
    assert "watchdog" in stop.reason and "100 ms" in stop.reason
    calls = fake.calls(mark)
    zero = next(c for c in calls if c.function == "SendAdvanceTrajectory" and not c.values.any())
    after = [c.function for c in calls if c.t >= zero.t]
    assert after[:2] == ["SendAdvanceTrajectory", "EraseAllTrajectories"]
    assert 0.0 <= zero.t - stop.deadline <= 0.020
    assert not any(c.values.any() for c in calls if c.function == "SendAdvanceTrajectory"
                   and c.t > zero.t)  # nothing moves the arm after it
    q_before = fake.state()[0]
    time.sleep(0.05)
    np.testing.assert_array_equal(fake.state()[0], q_before)
    assert arm.standing_command is None
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))  # a fresh command moves it again
    assert fake.state()[1][0] == pytest.approx(math.degrees(0.1), rel=1e-5)
    assert arm.standing_command is not None


def test_speed_scale_reduces_what_is_sent(fake, make_arm):
    arm = make_arm(speed_scale=0.25)
    arm.connect()
    sent = arm.send_joint_speeds(np.array([0.4, 0, 0, 0, 0, -0.4]))
    np.testing.assert_allclose(sent, [0.1, 0, 0, 0, 0, -0.1])
    recorded = fake.calls(function="SendAdvanceTrajectory")[-1].values
    np.testing.assert_allclose(recorded, np.degrees([0.1, 0, 0, 0, 0, -0.1]), rtol=1e-6)


def test_feedback_converts_units(fake, make_arm):
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, -0.3, 0, 0, 0.1, 0]))
    time.sleep(0.03)
    frame = arm.refresh_feedback()
    np.testing.assert_allclose(frame.velocity, [0.2, -0.3, 0, 0, 0.1, 0], atol=1e-6)
    arm.stop()
    frame = arm.refresh_feedback()
    q_deg, _ = fake.state()  # the arm is still: the same angles (float32 in the SDK's structs)
    np.testing.assert_allclose(np.degrees(frame.position), q_deg, atol=1e-3)


# ------------------------------------------------------------------ faults


def test_system_error_faults_the_arm_until_cleared(fake, make_arm):
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    fake.inject_error(SYSTEM_ERROR_TYPES.index("errorlog_current_Actuators"))
    frame = arm.refresh_feedback()
    assert frame.arm_state == ArmState.IN_FAULT and Fault.HARDWARE in frame.faults
    assert not frame.healthy and arm.standing_command is None
    with pytest.raises(ArmFaultError, match="errorlog_current_Actuators"):
        arm.send_joint_speeds(np.zeros(6))
    mark = fake.call_count()
    time.sleep(0.05)
    assert not fake.calls(mark, "SendAdvanceTrajectory")  # the sender holds nothing
    arm.clear_faults()
    assert arm.refresh_feedback().healthy
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))


def test_ok_entries_are_not_faults(fake, make_arm):
    arm = make_arm()
    arm.connect()
    fake.inject_error(SYSTEM_ERROR_TYPES.index("errorlog_voltageOK"))
    assert arm.refresh_feedback().healthy


def test_hardware_estop(fake, make_arm):
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    fake.set_estop(True)
    frame = arm.refresh_feedback()
    assert Fault.EMERGENCY_STOP in frame.faults and frame.arm_state == ArmState.IN_FAULT
    with pytest.raises(ArmFaultError):
        arm.send_joint_speeds(np.zeros(6))
    with pytest.raises(ArmFaultError, match="release the e-stop"):
        arm.clear_faults()
    fake.set_estop(False)
    arm.clear_faults()
    assert arm.refresh_feedback().healthy


def test_software_estop_stops_control(fake, make_arm):
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    mark = fake.call_count()
    arm.apply_emergency_stop()
    names = [c.function for c in fake.calls(mark)]
    assert names[-3:] == ["SendAdvanceTrajectory", "EraseAllTrajectories", "StopControlAPI"]
    assert not fake.control_on
    time.sleep(0.03)
    assert fake.state()[1][0] == 0.0
    with pytest.raises(ArmFaultError):
        arm.send_joint_speeds(np.zeros(6))
    arm.clear_faults()
    assert fake.control_on


def test_unplugged_is_a_lost_connection(fake, make_arm):
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    fake.set_unplugged(True)
    time.sleep(0.03)  # the sender's next resend fails
    with pytest.raises(ConnectionLostError, match="ERROR_NO_DEVICE_FOUND"):
        arm.refresh_feedback()
    assert not arm.is_connected
    with pytest.raises(NotConnectedError):
        arm.refresh_feedback()
    fake.set_unplugged(False)
    arm.connect()
    assert arm.refresh_feedback().healthy


def test_a_missing_compiler_is_a_clear_skip_reason(monkeypatch, tmp_path):
    monkeypatch.setattr(fake_module.shutil, "which", lambda name: None)
    with pytest.raises(fake_module.CompilerMissing, match="no C compiler.*make setup"):
        fake_module.build(tmp_path)
