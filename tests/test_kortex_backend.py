"""The Kortex backend over the fake ``kortex_api`` (tests/fake_kortex_api): explicit per-call
timeouts, staleness from the adapter's clock and repeated frames (never from ``frame_id``), the
command watchdog against a frozen client, ArmFaultError in fault, ros2_kortex's fault-reset
sequence, the deploy wiring and the deploy.yaml numbers. The contract suite
(tests/test_hardware_contract.py) and the fault suite (tests/test_hardware_faults.py) run this
backend too.

``python tests/test_kortex_backend.py --trials 200`` measures the watchdog's stop time at full size
(the test runs 12 trials)."""

from __future__ import annotations

import functools
import logging
import os
import sys
import time

if __name__ == "__main__":  # run as a script: this checkout's packages, not an installed copy
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fake_kortex_api.rig import PASSWORD, fake_api, make_for, options  # noqa: E402
from ahrm_stack.hardware.kortex import (CommandWatchdog, Credentials,  # noqa: E402
                             KortexArm, kortex_deploy_blocker, kortex_options,
                             make_kortex_backend)
from ahrm_stack.hardware.protocol import (ArmFaultError, ArmState, ConnectionLostError,  # noqa: E402
                               Fault, FeedbackTimeoutError, HardwareError, ServoingMode)

PERIOD = 0.05  # s: configs/deploy.yaml's rate_hz 20 (checked below)


@functools.lru_cache(maxsize=1)
def _robot():
    from ahrm_stack.robot import describe, make_arm

    return describe("jaco", make_arm("jaco"))


def _settings(**kortex):
    import dataclasses

    from ahrm_stack.deploy import load_deploy_settings

    settings = load_deploy_settings()
    return dataclasses.replace(settings, kortex=dataclasses.replace(settings.kortex, **kortex))


@pytest.fixture
def rig():
    adapter, arm = make_for(_robot())
    adapter.connect()
    yield adapter, arm
    adapter.disconnect()


def _speeds(joint: int, value: float) -> np.ndarray:
    command = np.zeros(6)
    command[joint] = value
    return command


# ---------------------------------------------------------------------------------------------
# The configured numbers
# ---------------------------------------------------------------------------------------------


def test_the_numbers_come_from_deploy_yaml():
    settings = _settings()
    assert settings.rate_hz == 1 / PERIOD
    opts = kortex_options(settings)
    k = settings.kortex
    assert opts.rpc_timeout_ms == k.rpc_timeout_ms and opts.port == k.port
    assert opts.watchdog_timeout == pytest.approx(k.watchdog_periods * PERIOD)
    assert opts.watchdog_poll == pytest.approx(k.watchdog_poll_periods * PERIOD)
    assert opts.reset_wait == pytest.approx(k.reset_wait_ms / 1e3)
    assert opts.lost_link_stop_timeout_ms == k.lost_link_stop_timeout_ms
    assert opts.lost_link_stop_timeout_ms < k.connection_inactivity_timeout_ms
    # the watchdog stops within its timeout plus one poll: under two periods
    assert k.watchdog_periods + k.watchdog_poll_periods < 2.0


@pytest.mark.parametrize("key, value, expected", [
    ("rpc_timeout_ms", 0, "deploy.kortex.rpc_timeout_ms must be > 0"),
    ("rpc_timeout_ms", 2.5, "deploy.kortex.rpc_timeout_ms: expected an integer, got 2.5"),
    ("session_rpc_timeout_ms", None,
     "deploy.kortex.session_rpc_timeout_ms: expected an integer, got None"),
    ("watchdog_periods", 1.0, "deploy.kortex.watchdog_periods must be > 1"),
    ("watchdog_periods", "2", "deploy.kortex.watchdog_periods: expected a number, got '2'"),
    ("watchdog_poll_periods", 1.0, "deploy.kortex.watchdog_poll_periods must be <= half"),
    ("reset_wait_ms", -1, "deploy.kortex.reset_wait_ms must be > 0"),
    ("reset_poll_ms", 5000, "deploy.kortex.reset_poll_ms must be <= deploy.kortex.reset_wait_ms"),
    ("reset_estop_repeats", True, "deploy.kortex.reset_estop_repeats: expected an integer, got True"),
    ("lost_link_stop_timeout_ms", 0, "deploy.kortex.lost_link_stop_timeout_ms must be > 0"),
    ("python", "  ", "deploy.kortex.python must be null (this interpreter) or a path"),
    ("process_margin_ms", -5, "deploy.kortex.process_margin_ms must be > 0"),
    ("models", {"gen3": {"model": "MODEL_ID_GEN9", "dof": 7}}, "deploy.kortex.models.gen3.model"),
    ("models", {"gen3": {"model": "MODEL_ID_L53", "dof": 9}}, "deploy.kortex.models.gen3.dof must be <= 7"),
    ("speed_limit_tolerance", 1.5, "deploy.kortex.speed_limit_tolerance must be <= 1"),
    ("refuse_zones_in_workspace", "yes",
     "deploy.kortex.refuse_zones_in_workspace: expected true/false, got 'yes'"),
    ("workspace_height", 0.0, "deploy.kortex.workspace_height must be > 0"),
    ("soft_limit_modes", ["ANGULAR_JOYSTICK", "WARP_DRIVE"], "deploy.kortex.soft_limit_modes"),
    ("soft_limit_modes", [], "deploy.kortex.soft_limit_modes"),
    ("soft_limit_tolerance", 1.5, "deploy.kortex.soft_limit_tolerance must be <= 1"),
    ("action_rpc_timeout_ms", 0, "deploy.kortex.action_rpc_timeout_ms must be > 0"),
    ("check_ticks", 5, "deploy.kortex.check_ticks must be >= 10"),
    ("home", {"speed_deg_s": 25.0}, "deploy.kortex.home.speed_deg_s must be <= 20"),
])
def test_bad_kortex_numbers_are_one_line_errors_naming_the_key(tmp_path, key, value, expected):
    import yaml

    from ahrm_stack.deploy import DEPLOY_CONFIG, DeployConfigError, load_deploy_settings

    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kortex"][key] = value
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(DeployConfigError) as error:
        load_deploy_settings(path)
    assert expected in str(error.value) and "\n" not in str(error.value)
    del data["kortex"][key]
    path.write_text(yaml.safe_dump(data))
    if key == "models":  # composed from the arm registry (configs/robots/<arm>.yaml's kortex)
        assert set(load_deploy_settings(path).kortex.models) == {"gen3"}  # the one Kortex arm
        return
    with pytest.raises(DeployConfigError, match=f"missing config key 'deploy.kortex.{key}'"):
        load_deploy_settings(path)


# ---------------------------------------------------------------------------------------------
# Explicit per-call timeouts
# ---------------------------------------------------------------------------------------------


def test_every_rpc_carries_an_explicit_timeout(rig):
    adapter, arm = rig
    opts = options()
    adapter.refresh_feedback()
    adapter.send_joint_speeds(_speeds(0, 0.1))
    adapter.stop()
    adapter.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING)
    adapter.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
    adapter.apply_emergency_stop()
    adapter.clear_faults()
    adapter.send_joint_speeds(_speeds(1, -0.1))
    time.sleep(0.2)  # the watchdog stops the arm: its Stop carries a timeout too
    adapter.disconnect()
    names = {c.name for c in arm.calls}
    assert {"CreateSession", "RefreshFeedback", "SendJointSpeedsCommand", "Stop",
            "SetServoingMode", "ApplyEmergencyStop", "ClearFaults", "CloseSession"} <= names
    for call in arm.calls:
        slow = ("CreateSession", "CloseSession", "GetProductConfiguration",
                "GetAllJointsSpeedHardLimitation", "GetAllKinematicSoftLimits",
                "ReadAllProtectionZones")  # once, on connect
        expected = opts.session_rpc_timeout_ms if call.name in slow else opts.rpc_timeout_ms
        assert call.timeout_ms == expected, call  # never None (the vendor's 10 s default)
    assert adapter.watchdog.trips == 1


def test_a_hung_rpc_fails_within_its_timeout(rig):
    adapter, arm = rig
    arm.delay_next("RefreshFeedback", 5.0)  # the vendor default would block 10 s
    start = time.perf_counter()
    with pytest.raises(FeedbackTimeoutError, match="RefreshFeedback: no answer within 40 ms"):
        adapter.refresh_feedback()
    elapsed = time.perf_counter() - start
    assert 0.035 <= elapsed < 0.5
    arm.delay_next("SendJointSpeedsCommand", 5.0)
    with pytest.raises(FeedbackTimeoutError, match="SendJointSpeedsCommand"):
        adapter.send_joint_speeds(_speeds(0, 0.1))
    assert adapter.refresh_feedback().healthy  # the link itself is fine



# ---------------------------------------------------------------------------------------------
# Staleness without an arm clock (ahrm_stack/hardware/kortex/freshness.py)
# ---------------------------------------------------------------------------------------------


def test_frame_freshness_by_hand():
    from ahrm_stack.hardware.kortex import FrameFreshness

    fresh = FrameFreshness()
    from ahrm_stack.hardware.kortex import fingerprint

    def frame(*position):  # each call builds new float objects, as each decoded answer does
        return fingerprint({"position": [float(str(p)) for p in position], "torque": [0.5]})

    assert fresh.update(frame(1.0, 2.0), sent=10.0) == (1, 10.0)
    assert fresh.update(frame(1.0, 2.0), sent=10.5) == (1, 10.0)  # the same readings: a repeat
    assert fresh.update(frame(1.0, 2.5), sent=11.0) == (2, 11.0) and fresh.repeats == 1
    assert fresh.update(frame("nan", 2.5), sent=12.0) == (3, 12.0)
    assert fresh.update(frame("nan", 2.5), sent=13.0) == (3, 12.0)  # NaN repeated: a repeat too
    assert fresh.update(frame(-0.0, 2.5), sent=14.0) == (4, 14.0)
    assert fresh.update(frame(0.0, 2.5), sent=15.0) == (5, 15.0)  # a sign bit differs: new


def test_frame_id_is_not_read_as_the_arms_counter(rig):
    """The fake, like the real arm, leaves Feedback.frame_id at the client's value (0: no cyclic
    command is sent); fresh frames still get increasing ids and fresh stamps."""
    adapter, arm = rig
    first = adapter.refresh_feedback()
    time.sleep(0.02)
    second = adapter.refresh_feedback()
    assert arm._previous.frame_id == 0
    assert second.frame_id == first.frame_id + 1 and second.timestamp > first.timestamp
    assert adapter.clock.now() - second.timestamp < 0.01


def test_a_repeated_frame_keeps_its_id_and_stamp(rig):
    adapter, arm = rig
    fresh = adapter.refresh_feedback()
    arm.freeze_next()  # the arm answers with the previous frame
    time.sleep(0.05)
    repeated = adapter.refresh_feedback()
    assert repeated.frame_id == fresh.frame_id and repeated.timestamp == fresh.timestamp
    assert adapter.clock.now() - repeated.timestamp >= 0.05
    assert adapter.freshness.repeats == 1
    assert adapter.refresh_feedback().frame_id == fresh.frame_id + 1  # a new frame again


def test_a_slow_answer_is_stamped_when_it_was_asked_for(rig):
    """The frame was measured after its request left: its age includes the whole round trip."""
    adapter, arm = rig
    arm.delay_next("RefreshFeedback", 0.03)  # within rpc_timeout_ms (40)
    frame = adapter.refresh_feedback()
    assert adapter.clock.now() - frame.timestamp >= 0.03


def test_the_deploy_loop_stops_on_a_late_frame(config):
    """Through DeployLoop on the fake arm (virtual clock): a frame whose answer took 40 ms is
    older than watchdog.max_feedback_age (25 ms) when it arrives; the loop stops in that tick."""
    from fake_kortex_api.rig import DeployRig

    rig = DeployRig(config)
    try:
        for _ in range(5):
            assert rig.loop.tick(), rig.loop.stop_reason
        rig.fake.delay_next("RefreshFeedback", 0.035)  # within rpc_timeout_ms (40)
        assert not rig.loop.tick()
        assert "stale feedback" in rig.loop.stop_reason and "age 35.0 ms" in rig.loop.stop_reason
        np.testing.assert_array_equal(rig.command, 0.0)
    finally:
        rig.adapter.disconnect()


def test_the_deploy_loop_stops_on_the_latched_command_watchdog(config):
    """The loop stalls (virtual time jumps a second with no command) while the arm moves: the
    watchdog stops the arm and latches Fault.WATCHDOG, so the next tick stops the run saying why
    instead of moving again."""
    from fake_kortex_api.rig import DeployRig

    rig = DeployRig(config)
    try:
        for _ in range(5):
            assert rig.loop.tick(), rig.loop.stop_reason
        assert rig.command.any()  # moving
        rig.adapter.clock.sleep(1.0)  # the loop stalls
        deadline = time.perf_counter() + 2.0
        while rig.command.any() and time.perf_counter() < deadline:
            time.sleep(0.005)  # the watchdog thread polls in real time
        np.testing.assert_array_equal(rig.command, 0.0)
        assert rig.adapter.watchdog.trips == 1
        assert not rig.loop.tick()
        assert "WATCHDOG" in rig.loop.stop_reason, rig.loop.stop_reason
        np.testing.assert_array_equal(rig.command, 0.0)
    finally:
        rig.adapter.disconnect()


# ---------------------------------------------------------------------------------------------
# The command watchdog
# ---------------------------------------------------------------------------------------------


def test_watchdog_by_hand():
    now = [0.0]
    fired = []
    dog = CommandWatchdog(0.075, 0.005, fired.append, clock=lambda: now[0])
    assert not dog.check()  # nothing commanded
    assert dog.commanded(moving=True)
    now[0] = 0.075
    assert not dog.check()  # exactly at the limit: not yet
    now[0] = 0.0751
    assert dog.check() and fired == [pytest.approx(0.0751)] and dog.tripped
    assert not dog.check()  # once
    assert not dog.commanded(moving=True)  # latched: refuse
    dog.reset()
    assert dog.commanded(moving=False)  # a zero command does not arm it
    now[0] = 10.0
    assert not dog.check()
    assert dog.commanded(moving=True)
    dog.disarm()  # stopped
    now[0] = 20.0
    assert not dog.check() and dog.trips == 1


def measure_watchdog(trials: int) -> np.ndarray:
    """Seconds from the last (moving) command reaching the fake arm to the watchdog's stop reaching
    it, the client frozen in between (it sends nothing), over ``trials`` runs on the wall clock."""
    adapter, arm = make_for(_robot())
    adapter.connect()
    delays = []
    try:
        for trial in range(trials):
            adapter.send_joint_speeds(_speeds(trial % 6, 0.3))
            sent = arm.speed_log[-1][0]
            deadline = time.perf_counter() + 1.0
            while np.any(arm.command != 0) and time.perf_counter() < deadline:
                time.sleep(0.002)  # frozen: no command, no feedback request
            assert not np.any(arm.command != 0), "the watchdog did not stop the arm in 1 s"
            delays.append(arm.speed_log[-1][0] - sent)
            with pytest.raises(ArmFaultError, match="watchdog"):
                adapter.send_joint_speeds(_speeds(0, 0.1))  # latched until cleared
            assert Fault.WATCHDOG in adapter.refresh_feedback().faults
            adapter.clear_faults()
    finally:
        adapter.disconnect()
    return np.asarray(delays)


def test_the_watchdog_stops_a_frozen_client_within_two_periods():
    delays = measure_watchdog(12)
    opts = options()
    assert (delays > opts.watchdog_timeout).all()  # never early
    assert delays.max() < 2 * PERIOD, delays  # configured: 1.5 periods + a 0.1-period poll


def test_without_the_watchdog_the_arm_keeps_moving():
    """The hazard itself: Kortex joint speeds never expire (the fake arm, like the real one, holds
    them), so a frozen client with no watchdog leaves the arm moving."""
    adapter, arm = make_for(_robot(), opts=options(watchdog_timeout=60.0))
    adapter.connect()
    try:
        adapter.send_joint_speeds(_speeds(0, 0.3))
        start = arm.read_positions()[0]
        time.sleep(0.3)
        assert np.degrees(0.3) == pytest.approx(arm.command[0])
        assert arm.read_positions()[0] - start == pytest.approx(np.degrees(0.3) * 0.3, rel=0.3)
    finally:
        adapter.disconnect()


def test_a_command_in_flight_when_the_watchdog_fires_is_stopped_again():
    """The command RPC takes longer than the watchdog's timeout (it trips while the command is on
    its way); the adapter stops the arm again once the command landed, and refuses."""
    adapter, arm = make_for(_robot(), opts=options(rpc_timeout_ms=500))
    adapter.connect()
    try:
        adapter.send_joint_speeds(_speeds(0, 0.2))
        arm.delay_next("SendJointSpeedsCommand", 0.15)  # > 75 ms
        with pytest.raises(ArmFaultError, match="watchdog"):
            adapter.send_joint_speeds(_speeds(0, 0.3))
        np.testing.assert_array_equal(arm.command, 0.0)
    finally:
        adapter.disconnect()


# ---------------------------------------------------------------------------------------------
# ArmFaultError in fault, and the reset sequence
# ---------------------------------------------------------------------------------------------


def test_motion_in_fault_raises_arm_fault_error(rig):
    adapter, arm = rig
    # The arm faults (an actuator bank) and the adapter has seen it in feedback.
    arm.fault()
    frame = adapter.refresh_feedback()
    assert frame.arm_state == ArmState.IN_FAULT and Fault.HARDWARE in frame.faults
    with pytest.raises(ArmFaultError):
        adapter.send_joint_speeds(_speeds(0, 0.1))
    adapter.clear_faults()
    adapter.send_joint_speeds(_speeds(0, 0.1))
    # The arm faults and the adapter has not read feedback since: the arm refuses the command
    # (KServerException ROBOT_IN_FAULT), which is an ArmFaultError too.
    arm.fault()
    with pytest.raises(ArmFaultError, match="ROBOT_IN_FAULT|refused it in fault"):
        adapter.send_joint_speeds(_speeds(0, 0.1))
    with pytest.raises(ArmFaultError):  # and stays refused until cleared
        adapter.send_joint_speeds(np.zeros(6))
    adapter.stop()  # stopping is always allowed
    adapter.clear_faults()
    np.testing.assert_array_equal(adapter.send_joint_speeds(_speeds(0, 0.1)), _speeds(0, 0.1))


def test_reset_sequence_order(rig):
    adapter, arm = rig
    adapter.apply_emergency_stop()
    start = len(arm.calls)
    adapter.clear_faults()
    names = [c.name for c in arm.calls[start:]]
    opts = options()
    # ros2_kortex: single-level servoing, ApplyEmergencyStop x2, ClearFaults; then wait for the
    # arm to leave fault (the fake clears 50 ms after ClearFaults), then stop.
    head = ["SetServoingMode"] + ["ApplyEmergencyStop"] * opts.reset_estop_repeats + ["ClearFaults"]
    assert names[:len(head)] == head
    polls = names[len(head):-1]
    assert set(polls) == {"RefreshFeedback"} and len(polls) >= 2  # waited, polling
    assert names[-1] == "Stop"
    frame = adapter.refresh_feedback()
    assert frame.healthy and frame.arm_state == ArmState.SERVOING_READY
    assert adapter.servoing_mode == ServoingMode.SINGLE_LEVEL_SERVOING


def test_reset_restores_low_level_servoing_and_gives_up_in_time():
    adapter, arm = make_for(_robot(), opts=options(reset_wait=0.2), clear_delay_s=60.0)
    adapter.connect()
    try:
        adapter.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING)
        arm.fault()
        start = time.perf_counter()
        with pytest.raises(ArmFaultError, match="still in fault after 200 ms"):
            adapter.clear_faults()
        assert 0.2 <= time.perf_counter() - start < 1.0
        arm.clear_delay_s = 0.0
        adapter.clear_faults()
        assert [c.name for c in arm.calls[-2:]] == ["SetServoingMode", "Stop"]
        assert arm.mode == fake_api()["Base_pb2"].LOW_LEVEL_SERVOING
    finally:
        adapter.disconnect()


def test_lost_link_is_connection_lost_and_reconnects(rig):
    adapter, arm = rig
    adapter.send_joint_speeds(_speeds(0, 0.2))
    arm.lose_connection()
    with pytest.raises(ConnectionLostError):
        adapter.refresh_feedback()
    assert not adapter.is_connected
    np.testing.assert_array_equal(arm.command, 0.0)  # the arm's own connection watchdog
    adapter.connect()
    assert adapter.refresh_feedback().healthy


# ---------------------------------------------------------------------------------------------
# Credentials and deploy wiring
# ---------------------------------------------------------------------------------------------


def test_no_credential_in_logs_over_a_whole_session(caplog):
    adapter, arm = make_for(_robot())
    with caplog.at_level(logging.DEBUG):
        adapter.connect()
        adapter.send_joint_speeds(_speeds(0, 0.2))
        time.sleep(0.2)  # watchdog stop, logged
        arm.delay_next("RefreshFeedback", 1.0)
        with pytest.raises(FeedbackTimeoutError) as timeout:
            adapter.refresh_feedback()
        adapter.clear_faults()
        adapter.disconnect()
    assert arm.session_info.password == PASSWORD  # the login itself carries it, nothing else
    texts = [r.getMessage() for r in caplog.records] + [str(timeout.value)]
    assert any("WATCHDOG" in t for t in texts)
    assert not any(PASSWORD in t for t in texts)


def test_make_kortex_backend(monkeypatch):
    with pytest.raises(HardwareError, match="deploy.kortex.address is not set"):
        make_kortex_backend(_settings(), _robot(), credentials=Credentials("a", "b"))
    from ahrm_stack.hardware.kortex import CredentialsError

    with pytest.raises(CredentialsError, match="KORTEX_PASSWORD"):
        make_kortex_backend(_settings(address="192.0.2.77"), _robot(), env={"KORTEX_USERNAME": "a"})
    settings = _settings(address="192.0.2.77")
    adapter = make_kortex_backend(settings, _robot(), api=fake_api(),
                                  env={"KORTEX_USERNAME": "admin",
                                       "KORTEX_PASSWORD": PASSWORD})
    assert isinstance(adapter, KortexArm) and not adapter.is_connected
    assert adapter.watchdog.timeout == pytest.approx(1.5 * PERIOD)
    FakeArm = fake_api()["_fake_arm"].FakeArm
    arm = FakeArm.register("192.0.2.77", settings.kortex.port,
                           FakeArm(np.zeros(6), ~_robot().limited))
    arm.positions[1:3] = 180.0
    # configs/deploy.yaml maps no robot to a Kortex arm: the JACO policy is refused, naming both
    with pytest.raises(HardwareError) as refused:
        adapter.connect()
    assert str(refused.value) == (
        "the arm at 192.0.2.77 is a MODEL_ID_L53 (Gen3), 6 DoF; the policy's robot 'jaco' (6 "
        "joints) is not a Kortex arm (configs/deploy.yaml kortex.models has no entry for 'jaco'): "
        "the trained arm model must match the arm")
    assert not adapter.is_connected and arm.sessions == 0
    assert [c.name for c in arm.calls[-2:]] == ["Stop", "CloseSession"]
    from ahrm_stack.deploy.settings import KortexModelSection

    settings = _settings(address="192.0.2.77",
                         models={"jaco": KortexModelSection(model="MODEL_ID_L53", dof=6)})
    adapter = make_kortex_backend(settings, _robot(), api=fake_api(),
                                  env={"KORTEX_USERNAME": "admin", "KORTEX_PASSWORD": PASSWORD})
    adapter.connect()
    assert adapter.arm_description == "MODEL_ID_L53 (Gen3), 6 DoF"
    assert arm.session_info.username == "admin" and arm.session_info.connection_inactivity_timeout \
        == settings.kortex.connection_inactivity_timeout_ms
    adapter.disconnect()


def test_deploy_backend_kortex_refuses_with_one_line(tmp_path, capsys, monkeypatch):
    import yaml

    from ahrm_stack.deploy import DEPLOY_CONFIG, main

    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    data["telemetry"] = str(telemetry)
    path = tmp_path / "deploy.yaml"

    def run(**kortex):
        data["kortex"].update(kortex)
        path.write_text(yaml.safe_dump(data))
        code = main(["--backend", "kortex", "--config", str(path)])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "\n" not in err
        assert err.startswith("python -m ahrm_stack.deploy: error:")
        return err

    monkeypatch.delenv("KORTEX_USERNAME", raising=False)
    monkeypatch.delenv("KORTEX_PASSWORD", raising=False)
    monkeypatch.delenv("KORTEX_CREDENTIALS_FILE", raising=False)
    assert "deploy.kortex.address is not set" in run()
    assert "no Kortex credentials" in run(address="192.0.2.99")
    monkeypatch.setenv("KORTEX_USERNAME", "admin")
    monkeypatch.setenv("KORTEX_PASSWORD", PASSWORD)
    err = run()
    assert "has no deploy.kortex.models entry" in err and PASSWORD not in err
    assert not telemetry.exists() and not telemetry.parent.exists()  # nothing written
    assert "deploy.kortex.rpc_timeout_ms must be > 0" in run(rpc_timeout_ms=0)


def test_blocker_names_fast_mode():
    import dataclasses

    settings = dataclasses.replace(_settings(address="192.0.2.5"), realtime=False)
    assert "sim backend only" in kortex_deploy_blocker(
        settings, env={"KORTEX_USERNAME": "a", "KORTEX_PASSWORD": "b"})


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trials", type=int, default=200)
    args = parser.parse_args()
    delays = measure_watchdog(args.trials) * 1e3
    print(f"watchdog stop after the last command, {args.trials} trials (ms): "
          f"min {delays.min():.1f}, median {np.median(delays):.1f}, p99 "
          f"{np.percentile(delays, 99):.1f}, max {delays.max():.1f}; limit 2 periods = "
          f"{2 * PERIOD * 1e3:.0f} ms; over it: {(delays >= 2 * PERIOD * 1e3).sum()}")
