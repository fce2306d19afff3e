"""The Kinova Gen2 backend (ahrm_stack/hardware/kinova_gen2/) against the fake SDK (tests/fake_kinova_sdk),
compiled here with the system C compiler: settings, struct layouts, unit and joint conventions,
device selection, the cold-boot start, the USB thread (one position read per tick, the 100 Hz
points, the status poll, the order of calls), the command watchdog, faults, the e-stop, a lost
link, and every exit path leaving the arm stopped (the FIFO empty, only valid calls after a failed
connect). The fake itself: the real SDK's codes without an arm, USB latency, the trajectory FIFO,
noisy velocity feedback, a cold boot. Real time (the USB thread is a thread); timing claims are
checked from the fake's call log and the bus's own records, with bounds a loaded machine meets.
Kinova's own binary: tests/test_kinova_gen2_vendor.py."""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import math
import threading
import time

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ahrm_stack.deploy import DEPLOY_CONFIG, DeployConfigError, load_deploy_settings
from ahrm_stack.hardware.kinova_gen2 import (SYSTEM_ERROR_TYPES, AngularPosition, Gen2ConfigError,
                                  JointConvention, KinovaDevice, KinovaGen2Arm, SensorsInfo,
                                  Sdk, SystemError, TrajectoryPoint, UserPosition, check_library,
                                  kinova_positions, kinova_velocities,
                                  model_positions, model_velocities,
                                  velocity_point)
from ahrm_stack.hardware.protocol import (ArmFaultError, ArmState, CommandRefusedError, ConnectionLostError, Fault,
                               HardwareError, NotConnectedError, ServoingMode, unwrap_positions)

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
no_arm = pytest.importorskip("fake_kinova_sdk.no_arm")
FakeSdk, SERIAL = fake_module.FakeSdk, fake_module.SERIAL

@functools.lru_cache(maxsize=None)
def _robot(name: str):
    from ahrm_stack.robot import describe, make_arm

    return describe(name, make_arm(name))


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


def test_an_arms_joint_convention_is_checked_and_named_in_its_registry_file(tmp_path):
    """deploy's kinova_gen2.joints are composed from configs/robots/<arm>.yaml: a bad value there
    is named as that file's key, in that file."""
    import shutil

    from ahrm_stack.config import ROBOTS_DIR

    robots = tmp_path / "robots"
    shutil.copytree(ROBOTS_DIR, robots)
    assert load_deploy_settings(robots_dir=robots).kinova_gen2.joints["jaco"].robot_types == (
        "JACOV2_6DOF_SERVICE", "JACOV2_6DOF_ASSISTIVE")
    for change, key in ((dict(sign=[2] * 6), "sign"), (dict(offset_deg=[0] * 5), "offset_deg")):
        entry = yaml.safe_load((ROBOTS_DIR / "jaco.yaml").read_text())
        entry["kinova_gen2"].update(change)
        (robots / "jaco.yaml").write_text(yaml.safe_dump(entry))
        with pytest.raises(DeployConfigError) as error:
            load_deploy_settings(robots_dir=robots)
        message = str(error.value)
        assert f"robots/jaco.kinova_gen2.{key}" in message and message.endswith("jaco.yaml)"), message
        assert "\n" not in message


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
    assert ("deploy.kinova_gen2.send_rate_hz must be <= 100.0 Hz: the arm executes one trajectory "
            "point per 10 ms" in bad(lambda d: d.update(send_rate_hz=101)))
    assert "comm_library" in bad(lambda d: d.update(comm_library="/x.so"))  # gone: the loader finds it
    assert "deploy.kinova_gen2.command_timeout" in bad(lambda d: d.update(command_timeout="2"))
    assert "deploy.kinova_gen2.speed_scale" in bad(lambda d: d.update(speed_scale=1.5))
    assert "deploy.kinova_gen2.serial" in bad(lambda d: d.update(serial=12345))
    assert "deploy.kinova_gen2.serial" in bad(lambda d: d.update(serial="X" * 25))
    assert "deploy.kinova_gen2.colour" in bad(lambda d: d.update(colour=1))
    assert "deploy.kinova_gen2.library" in bad(lambda d: d.pop("library"))
    assert "deploy.kinova_gen2.joints.jaco.sign" in bad(  # given in deploy.yaml: named there
        lambda d: d.update(joints={"jaco": {"sign": [2] * 6, "offset_deg": [0] * 6,
                                            "robot_types": ["JACOV2_6DOF_SERVICE"]}}))
    assert "deploy.kinova_gen2.switch_interval" in bad(lambda d: d.update(switch_interval=1.0))
    assert "deploy.kinova_gen2.status_rate_hz must be <= 10.0 Hz" in bad(lambda d: d.update(status_rate_hz=20))
    assert "deploy.kinova_gen2.status_rate_hz" in bad(lambda d: d.update(status_rate_hz=0))
    assert "deploy.kinova_gen2.send_ahead must be <= 0.05 s" in bad(lambda d: d.update(send_ahead=0.1))
    assert "deploy.kinova_gen2.send_ahead" in bad(lambda d: d.pop("send_ahead"))
    assert "deploy.kinova_gen2.check_calls" in bad(lambda d: d.update(check_calls=5))
    assert "deploy.kinova_gen2.velocity_window" in bad(lambda d: d.update(velocity_window=0))


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
    identity = JointConvention((1,) * 6, (0.0,) * 6, ("JACOV2_6DOF_SERVICE",))
    np.testing.assert_allclose(model_positions([180, 90, 0, 360, -90, 45], identity),
                               [math.pi, math.pi / 2, 0, 2 * math.pi, -math.pi / 2, math.pi / 4])
    # kinova-ros's 2013 DH convention: (180 - k1), (k2 - 270), (90 - k3), (180 - k4), ...
    dh = JointConvention((-1, 1, -1, -1, -1, -1), (180.0, -270.0, 90.0, 180.0, 180.0, 260.0),
                         ("JACOV2_6DOF_SERVICE",))
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
    convention = JointConvention(tuple(signs), tuple(offsets), ("JACOV2_6DOF_SERVICE",))
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
    assert fake.call_count() == mark  # the USB thread is gone
    arm.disconnect()  # idempotent


def test_unknown_serial_is_refused_and_the_api_closed(fake, make_arm):
    fake.reset(serials=("PJ00000000000000001", "PJ00000000000000002"))
    arm = make_arm()
    with pytest.raises(HardwareError) as error:
        arm.connect()
    assert SERIAL in str(error.value) and "PJ00000000000000001" in str(error.value)
    assert not arm.is_connected and not fake.initialized
    # before StartControlAPI only CloseAPI is valid
    assert [c.function for c in fake.calls()] == ["InitAPI", "GetDevices", "CloseAPI"]
    assert not fake.calls(function="SetActiveDevice")  # never "the first one found"


def test_another_kind_of_arm_is_refused_before_control_starts(fake, make_arm):
    """A spherical-wrist, 7-DoF or MICO arm on the bus, with the policy of a curved-wrist JACO2: one
    line naming what was found and the setting, the API closed, control never started."""
    fake.set_robot_type(8)  # SPHERICAL_7DOF_SERVICE
    arm = make_arm()
    with pytest.raises(HardwareError) as error:
        arm.connect()
    message = str(error.value)
    assert "\n" not in message and "SPHERICAL_7DOF_SERVICE" in message and "JACOV2_6DOF_SERVICE" in message
    assert "robot_types" in message and not arm.is_connected and not fake.initialized
    assert [c.function for c in fake.calls()] == ["InitAPI", "GetDevices", "SetActiveDevice", "GetQuickStatus",
                                                  "CloseAPI"]
    fake.set_robot_type(6)  # JACOV2_6DOF_ASSISTIVE: the same arm, another edition
    arm = make_arm()
    arm.connect()
    arm.disconnect()


def test_no_arm_on_the_bus(fake, make_arm):
    fake.reset(serials=())
    arm = make_arm()
    for _ in range(2):  # again: CloseAPI was called, so InitAPI does not "succeed" the second time
        with pytest.raises(HardwareError) as error:
            arm.connect()
        message = str(error.value)
        assert message.startswith("no Kinova arm found on USB (InitAPI failed: "
                                  "ERROR_NO_DEVICE_FOUND (1015))") and "\n" not in message
    assert [c.function for c in fake.calls()] == ["InitAPI", "CloseAPI"] * 2
    assert not fake.initialized and fake.crashes() == 0


def test_communication_layer_not_loaded_is_one_line_and_no_crash(fake, make_arm):
    """InitAPI's 2002 (the real SDK then crashes in SendAdvanceTrajectory): only CloseAPI follows."""
    fake.set_comm_missing(True)
    with pytest.raises(HardwareError) as error:
        make_arm().connect()
    message = str(error.value)
    assert "ERROR_LOAD_COMM_DLL (2002)" in message and "LD_LIBRARY_PATH" in message
    assert "\n" not in message
    assert [c.function for c in fake.calls()] == ["InitAPI", "CloseAPI"] and fake.crashes() == 0


def test_a_failure_after_start_control_stops_the_arm_and_closes(fake, make_arm):
    fake.fail_next("SetAngularControl", 1016)
    with pytest.raises(HardwareError, match="SetAngularControl failed: ERROR_OPERATION_INCOMPLETED"):
        make_arm().connect()
    names = [c.function for c in fake.calls()]
    assert names == ["InitAPI", "GetDevices", "SetActiveDevice", "GetQuickStatus", "StartControlAPI", "StopControlAPI",
                     "StartControlAPI", "SetAngularControl", "SendAdvanceTrajectory",
                     "EraseAllTrajectories", "StopControlAPI", "CloseAPI"]
    assert fake.fifo_count() == 0 and not fake.control_on and fake.crashes() == 0


def test_connect_kick_starts_the_control_api_after_a_cold_boot(fake, make_arm):
    """After power-up the arm may ignore the first StartControlAPI (kinova-ros starts, stops and
    starts it); the fake models that (a lone start leaves control off), connect() does the three."""
    fake.set_cold_boot(True)
    raw = Sdk(fake.path)
    raw.call("InitAPI")
    raw.call("SetActiveDevice", raw.devices()[0])
    raw.call("StartControlAPI")
    assert not fake.control_on  # ignored: the cold boot
    raw.call("CloseAPI")
    fake.reset(position_deg=fake.state()[0])
    fake.set_cold_boot(True)
    arm = make_arm()
    arm.connect()
    assert [c.function for c in fake.calls()][4:7] == ["StartControlAPI", "StopControlAPI",
                                                       "StartControlAPI"]
    assert fake.control_on
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))  # from rest: returns once the point is out
    assert fake.state()[1][0] == pytest.approx(math.degrees(0.1), rel=1e-5)


@pytest.mark.parametrize("name", sorted(no_arm.SEQUENCES))
def test_the_fake_answers_as_the_real_sdk_without_an_arm(fake, name):
    """The codes Kinova's real binary returned without an arm (fake_kinova_sdk/no_arm.py; the same
    table is replayed on the real binary in tests/test_kinova_gen2_vendor.py)."""
    comm, calls = no_arm.SEQUENCES[name]
    fake.reset(serials=(), latency=0.0)
    fake.set_comm_missing(not comm)
    lib = no_arm.bind(fake.path)
    got = [(c, no_arm.call(lib, c)) for c, _ in calls]
    assert no_arm.matches(got, calls), got
    assert fake.crashes() == 0


@pytest.mark.parametrize("name", sorted(no_arm.CRASHES))
def test_the_fake_counts_where_the_real_sdk_crashes(fake, name):
    comm, calls = no_arm.CRASHES[name]
    fake.reset(serials=(), latency=0.0)
    fake.set_comm_missing(not comm)
    lib = no_arm.bind(fake.path)
    for index, call in enumerate(calls):
        no_arm.call(lib, call)
        assert fake.crashes() == (1 if index == len(calls) - 1 else 0)


# ------------------------------------------------------------------ the USB thread and the watchdog


def _until(predicate, timeout: float = 3.0, what: str = "") -> None:
    """Wait (polling every 5 ms) until ``predicate()``; fail after ``timeout`` s."""
    give_up = time.perf_counter() + timeout
    while not predicate():
        assert time.perf_counter() < give_up, f"timed out waiting for {what or predicate}"
        time.sleep(0.005)


def _loop(arm, ticks: int, speed: float = 0.1, period: float = 0.05) -> float:
    """A 20 Hz control loop's adapter calls (one feedback, one command per tick); its s."""
    t0 = time.perf_counter()
    for k in range(ticks):
        time.sleep(max(0.0, t0 + k * period - time.perf_counter()))
        arm.refresh_feedback()
        arm.send_joint_speeds(np.array([speed, 0, 0, 0, 0, 0]))
    return time.perf_counter() - t0


def test_a_tick_costs_one_position_read_and_the_arm_gets_its_points(fake, make_arm):
    """A 20 Hz loop over 3 ms calls: one GetAngularPosition per tick and no velocity read; the status
    (sensors, error log, torques) at status_rate_hz; trajectory points at up to 100 Hz that never pile
    up in the arm's FIFO (a running point and at most two waiting); every caller's call waited for at
    most two calls (the one in progress and an urgent point). Structural, so a loaded machine holds
    it; only the points' count has slack for resends the OS delayed (and the watchdog is set far
    off: a stop, which goes first, would be two more calls)."""
    arm = make_arm(timeout=1.0)
    arm.connect()
    mark, polls, waits = fake.call_count(), arm.bus.status_polls, len(arm.bus.waits)
    elapsed = _loop(arm, 40)
    arm.stop()
    calls = fake.calls(mark)
    names = [c.function for c in calls]
    assert names.count("GetAngularPosition") == 40 and "GetAngularVelocity" not in names
    polled = arm.bus.status_polls - polls
    assert abs(polled - elapsed * 2.0) <= 1.5, (polled, elapsed)
    assert names.count("GetSensorsInfo") in (polled - 1, polled)  # the last poll may be under way
    points = [c for c in calls if c.function == "SendAdvanceTrajectory" and c.values.any()]
    assert 0.75 * 100 * elapsed <= len(points) <= 100 * elapsed + 2
    assert fake.fifo_peak() <= 3 and fake.dropped() == 0
    assert max(w.calls_ahead for w in list(arm.bus.waits)[waits:]) <= 2


def test_sender_resends_at_100_hz_and_the_arm_keeps_full_speed(fake, make_arm):
    """A 20 Hz caller: with the USB thread's points the joint moves at the commanded speed; sending
    only at 20 Hz (no thread) it moves at a fifth of it (each point is 10 ms of motion)."""
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

    # the same caller without the USB thread: each point moves the arm for 10 ms of every 50 ms
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
    assert 0.1 * speed < slow < 0.35 * speed  # ~10 ms of motion per 50 ms: a fifth of the speed


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
    assert arm.faults == Fault.WATCHDOG and "watchdog" in arm.fault_reason  # latched
    with pytest.raises(ArmFaultError, match="WATCHDOG"):
        arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))
    assert arm.standing_command is None and fake.state()[1][0] == 0.0
    arm.clear_faults()
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))  # cleared: a command moves it again
    assert fake.state()[1][0] == pytest.approx(math.degrees(0.1), rel=1e-5)
    assert arm.standing_command is not None


def test_speed_scale_reduces_what_is_sent(fake, make_arm):
    arm = make_arm(speed_scale=0.25)
    arm.connect()
    sent = arm.send_joint_speeds(np.array([0.4, 0, 0, 0, 0, -0.4]))
    np.testing.assert_allclose(sent, [0.1, 0, 0, 0, 0, -0.1])
    recorded = fake.calls(function="SendAdvanceTrajectory")[-1].values
    np.testing.assert_allclose(recorded, np.degrees([0.1, 0, 0, 0, 0, -0.1]), rtol=1e-6)


def test_feedback_is_one_stamped_read_and_velocity_its_position_difference(fake, make_arm):
    """Each frame is one GetAngularPosition, stamped when it returned (between the call's end in the
    fake's log and refresh_feedback returning), in rad; its velocity is the position difference
    since the previous read over the stamps' difference: the commanded speed while moving (no
    latency here, so the arm is fed without gaps), zero at rest."""
    fake.set_latency(0.0)
    arm = make_arm(timeout=0.5)
    arm.connect()
    command = np.array([0.2, -0.3, 0, 0, 0.1, 0])
    arm.send_joint_speeds(command)
    first = arm.refresh_feedback()
    time.sleep(0.1)
    arm.send_joint_speeds(command)
    mark = fake.call_count()
    second = arm.refresh_feedback()
    returned = time.perf_counter()
    assert second.timestamp - first.timestamp >= arm.settings.velocity_window
    read = fake.calls(mark, "GetAngularPosition")
    assert len(read) == 1 and read[0].t <= second.timestamp <= returned
    np.testing.assert_allclose(np.degrees(second.position), read[0].values, atol=1e-3)  # float32
    assert second.frame_id == first.frame_id + 1
    np.testing.assert_allclose(second.velocity, (second.position - first.position)
                               / (second.timestamp - first.timestamp))
    np.testing.assert_allclose(second.velocity, command, rtol=0.15, atol=1e-9)
    arm.stop()
    arm.refresh_feedback()
    time.sleep(0.06)  # > velocity_window: the reference is the read after the stop
    still = arm.refresh_feedback()
    np.testing.assert_array_equal(still.velocity, 0.0)
    q_deg, _ = fake.state()  # the arm is still: the same angles (float32 in the SDK's structs)
    np.testing.assert_allclose(np.degrees(still.position), q_deg, atol=1e-3)


# ------------------------------------------------------------------ faults


def test_each_frame_is_stamped_when_its_read_returned_at_3_ms_per_call(fake, make_arm):
    """With the fake's USB latency (3 ms per call, one at a time) and the USB thread busy (points at
    100 Hz, the status poll): each frame's timestamp is when its own GetAngularPosition returned,
    after the call's end in the fake's log and before refresh_feedback returned, at least the
    latency after the call began; never the request's time nor another call's."""
    assert fake_module.LATENCY == 0.003
    arm = make_arm(timeout=0.5)
    arm.connect()
    command = np.array([0.05, 0, 0, 0, 0, 0])
    for _ in range(20):
        arm.send_joint_speeds(command)
        mark = fake.call_count()
        asked = time.perf_counter()
        frame = arm.refresh_feedback()
        returned = time.perf_counter()
        reads = fake.calls(mark, "GetAngularPosition")
        assert len(reads) == 1, reads
        read = reads[0]
        assert asked <= read.start and read.t <= frame.timestamp <= returned
        assert frame.timestamp - read.start >= fake_module.LATENCY
        # the fake samples the angles inside the call: the frame carries that read's values
        np.testing.assert_allclose(np.degrees(frame.position), read.values, atol=1e-3)
        time.sleep(0.02)
    assert len(fake.calls(function="SendAdvanceTrajectory")) > 20  # the thread was busy meanwhile


def test_back_to_back_reads_take_their_velocity_over_the_window(fake, make_arm):
    """Two reads a few ms apart: the second's velocity is not their difference (a real arm's angle
    noise over 3 ms would be tens of deg/s) but the difference to the latest read at least
    velocity_window (40 ms) older."""
    arm = make_arm(timeout=0.5)
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    early = arm.refresh_feedback()
    time.sleep(0.06)
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    middle = arm.refresh_feedback()
    last = arm.refresh_feedback()  # right after the previous one (unless the OS held this thread)
    window = arm.settings.velocity_window
    reference = middle if last.timestamp - middle.timestamp >= window else early
    np.testing.assert_allclose(last.velocity, (last.position - reference.position)
                               / (last.timestamp - reference.timestamp))


def test_system_error_faults_the_arm_until_cleared(fake, make_arm):
    arm = make_arm(timeout=5.0)  # the command watchdog (it latches) out of the way
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    fake.inject_error(SYSTEM_ERROR_TYPES.index("errorlog_current_Actuators"))
    _until(lambda: arm.faults != Fault.NONE, what="the status poll")  # within 1 / status_rate_hz
    frame = arm.refresh_feedback()
    assert frame.arm_state == ArmState.IN_FAULT and Fault.HARDWARE in frame.faults
    assert not frame.healthy and arm.standing_command is None
    with pytest.raises(ArmFaultError, match="errorlog_current_Actuators"):
        arm.send_joint_speeds(np.zeros(6))
    mark = fake.call_count()
    time.sleep(0.05)
    assert not fake.calls(mark, "SendAdvanceTrajectory")  # no command stands
    arm.clear_faults()
    assert arm.refresh_feedback().healthy
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))


def test_ok_entries_are_not_faults(fake, make_arm):
    arm = make_arm()
    arm.connect()
    fake.inject_error(SYSTEM_ERROR_TYPES.index("errorlog_voltageOK"))
    polls = arm.bus.status_polls
    _until(lambda: arm.bus.status_polls >= polls + 2, what="two status polls")
    assert arm.refresh_feedback().healthy and not arm.fault_stops


def test_a_fault_seen_by_the_status_poll_stops_the_arm_at_once(fake, make_arm):
    """The control thread makes no call (busy elsewhere): the USB thread's status poll sees the logged
    error and stops the arm itself. By design the zero point and the erase are the very next calls
    after the read that saw it (and the entry's GetSystemError), whatever the load."""
    arm = make_arm(timeout=5.0)  # the command watchdog out of the way
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    mark = fake.call_count()
    fake.inject_error(SYSTEM_ERROR_TYPES.index("errorlog_Actuator_Temperature"))
    _until(lambda: arm.fault_stops, what="the status poll's stop")
    stop = arm.fault_stops[0]
    assert "errorlog_Actuator_Temperature" in stop.reason and stop.stopped_at is not None
    calls = fake.calls(mark)
    seen = next(i for i, c in enumerate(calls) if c.function == "GetSystemErrorCount" and c.type == 1)
    assert [c.function for c in calls[seen + 1:seen + 4]] == ["GetSystemError", "SendAdvanceTrajectory",
                                                              "EraseAllTrajectories"]
    assert not calls[seen + 2].values.any()
    assert calls[seen].t <= stop.detected_at <= stop.stopped_at
    assert fake.fifo_count() == 0 and fake.state()[1][0] == 0.0
    assert arm.standing_command is None
    frame = arm.refresh_feedback()
    assert Fault.HARDWARE in frame.faults and frame.arm_state == ArmState.IN_FAULT


def test_a_fault_halt_holds_off_commands_until_cleared(fake, make_arm):
    """The status poll's stop holds the arm: a command that passed the adapter's fault check just
    before it (the race) is refused by the USB thread instead of slipping in after the stop."""
    arm = make_arm()
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    arm.bus.halt(hold=True)  # what the status poll does on a fault, here without the fault's flags
    with pytest.raises(ArmFaultError, match="clear_faults"):
        arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    assert arm.standing_command is None and fake.fifo_count() == 0
    arm.clear_faults()
    arm.send_joint_speeds(np.array([0.1, 0, 0, 0, 0, 0]))
    assert arm.standing_command is not None


def test_hardware_estop(fake, make_arm):
    arm = make_arm(timeout=5.0)  # the command watchdog (it latches) out of the way
    arm.connect()
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    fake.set_estop(True)
    _until(lambda: arm.faults != Fault.NONE, what="the status poll")
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
    time.sleep(0.03)  # the USB thread's next point fails
    with pytest.raises(ConnectionLostError, match="JACO_COMM_FAILED|ERROR_NO_DEVICE_FOUND"):
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


# ------------------------------------------------------------------ the fake behaves like the arm


def _connected_raw(fake) -> Sdk:
    """The fake's SDK driven directly (no USB thread): initialised, control started."""
    raw = Sdk(fake.path)
    raw.call("InitAPI")
    raw.call("SetActiveDevice", raw.devices()[0])
    raw.call("StartControlAPI")
    raw.call("SetAngularControl")
    return raw


def test_points_sent_faster_than_100_hz_pile_up_and_keep_the_arm_moving(fake):
    """The trajectory FIFO: one point per 10 ms; 100 points sent at once are 1 s of motion, after
    the sender has stopped; EraseAllTrajectories stops it. A full FIFO drops points."""
    fake.reset(position_deg=np.zeros(6), latency=0.0, velocity_noise=0.0)
    raw = _connected_raw(fake)
    for _ in range(100):
        raw.call("SendAdvanceTrajectory", velocity_point([10.0, 0, 0, 0, 0, 0]))
    time.sleep(0.2)  # no point sent since
    queued = fake.fifo_count()
    q, dq = fake.state()
    assert 70 <= queued <= 81 and dq[0] == 10.0  # still moving, 10 ms per point
    assert 1.9 <= q[0] <= 3.0  # deg: 10 deg/s for the ~0.2 s since
    raw.call("EraseAllTrajectories")
    assert fake.fifo_count() == 0 and fake.state()[1][0] == 0.0
    q_stopped = fake.state()[0]
    time.sleep(0.03)
    np.testing.assert_array_equal(fake.state()[0], q_stopped)
    for _ in range(fake_module.FIFO_SIZE + 50):
        raw.call("SendAdvanceTrajectory", velocity_point([1.0, 0, 0, 0, 0, 0]))
    assert fake.fifo_count() <= fake_module.FIFO_SIZE and fake.dropped() >= 45
    raw.call("EraseAllTrajectories")
    raw.call("CloseAPI")


def test_every_sdk_call_takes_a_usb_round_trip_one_at_a_time(fake):
    """Each call blocks for the latency (3 ms by default); two threads' calls queue on the bus."""
    assert fake_module.LATENCY == 0.003
    raw = _connected_raw(fake)
    mark = fake.call_count()

    def read(count: int) -> None:
        for _ in range(count):
            raw.lib.GetAngularPosition(ctypes.byref(AngularPosition()))  # bypasses Sdk's lock

    t0 = time.perf_counter()
    other = threading.Thread(target=read, args=(10,))
    other.start()
    read(10)
    other.join()
    elapsed = time.perf_counter() - t0
    calls = fake.calls(mark)
    assert len(calls) == 20 and elapsed >= 20 * fake_module.LATENCY  # serialised, not parallel
    ends = sorted(c.t for c in calls)
    assert np.min(np.diff(ends)) >= 0.9 * fake_module.LATENCY
    raw.call("CloseAPI")


def test_velocity_feedback_is_noisy_and_decodes_around_zero(fake, make_arm):
    """At rest the fake reports N(0, 1 deg/s) through the firmware's encoding (half, negatives as
    360 - |v|); the adapter decodes it (``raw_velocities``, the --check's reading: the loop itself
    derives velocities from positions) to small values of both signs, never ~360 deg/s."""
    fake.set_latency(0.0)
    arm = make_arm()
    arm.connect()
    degrees = np.degrees(arm.raw_velocities(150))
    assert np.abs(degrees).max() < 6.0  # 6 sigma: no wrapped 360 slipped through
    assert 0.7 < degrees.std() < 1.3 and abs(degrees.mean()) < 0.3
    assert (degrees < 0).any() and (degrees > 0).any()


def _fill(arm, fake, count: int = 30) -> None:
    """A standing command, and ``count`` more points in the arm's FIFO (sent past the adapter, as a
    FIFO that piled up would hold them)."""
    arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
    for _ in range(count):
        fake.lib.SendAdvanceTrajectory(velocity_point([10.0, 0, 0, 0, 0, 0]))
    assert fake.fifo_count() >= count // 2  # the points pile up (no latency here)


def _fault_stop(arm) -> None:
    _until(lambda: arm.fault_stops, what="the status poll's stop")


STOP_PATHS = {
    "stop": lambda arm, fake: arm.stop(),
    "emergency stop": lambda arm, fake: arm.apply_emergency_stop(),
    "refused command": lambda arm, fake: pytest.raises(CommandRefusedError, arm.send_joint_speeds,
                                                       np.full(6, np.nan)),
    "system error": lambda arm, fake: (fake.inject_error(
        SYSTEM_ERROR_TYPES.index("errorlog_current_Actuators")), _fault_stop(arm)),
    "e-stop pressed": lambda arm, fake: (fake.set_estop(True), _fault_stop(arm)),
    "servoing mode": lambda arm, fake: arm.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING),
    "disconnect": lambda arm, fake: arm.disconnect(),
    "watchdog": lambda arm, fake: time.sleep(0.1 + 0.05),
    "failed point": lambda arm, fake: (fake.fail_next("SendAdvanceTrajectory", 2100),
                                         time.sleep(0.05)),
}


@pytest.mark.parametrize("path", sorted(STOP_PATHS))
def test_every_stop_empties_the_fifo(fake, make_arm, path):
    fake.reset(position_deg=fake.state()[0], latency=0.0)
    arm = make_arm(timeout=0.1)
    arm.connect()
    _fill(arm, fake)
    STOP_PATHS[path](arm, fake)
    assert fake.fifo_count() == 0, path
    assert fake.state()[1][0] == 0.0
    if path == "watchdog":
        assert len(arm.watchdog_stops) == 1


def test_a_lost_link_leaves_at_most_a_few_points_at_100_hz(fake, make_arm):
    """The stop path that cannot reach the arm: the USB thread keeps send_ahead (10 ms) of motion
    queued behind the running point, so the arm holds at most 2-3 points (10 ms each) when the link
    goes and stops by itself within tens of ms."""
    arm = make_arm(timeout=0.1)
    arm.connect()
    for _ in range(8):
        arm.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
        time.sleep(0.05)
    fake.set_unplugged(True)
    assert fake.fifo_count() <= 5
    time.sleep(0.08)
    with pytest.raises(ConnectionLostError):
        arm.refresh_feedback()
    assert fake.fifo_count() == 0 and fake.state()[1][0] == 0.0
