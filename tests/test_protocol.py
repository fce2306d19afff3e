"""The arm adapter protocol's own code (``ahrm_stack/hardware/protocol.py``), without a backend: the command
check every backend runs before sending (every bad command is a :class:`CommandRefusedError`, on
which the backends e-stop; the velocity limit is inclusive), unwrapping against its closed form,
range centres, the feedback and pose checks, the clocks and the adapter base classes.

The fast tests of ``tools/mutate.py --suite`` for ``ahrm_stack/hardware/protocol.py``; the backends' shared
contract is ``tests/test_hardware_contract.py``.
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

import ahrm_stack.hardware.protocol as protocol
from ahrm_stack.hardware.protocol import (ArmAdapter, ArmFaultError, ArmState, CommandRefusedError, DescribedArm,
                                          FastClock, Fault, Feedback, ObjectPoses, ServoingMode, WallClock,
                                          check_joint_speeds, range_centres, unwrap_positions)

LIMIT = np.array([0.5, 1.0, 2.0])  # rad/s


# ------------------------------------------------------------------------------------ command check


def test_a_good_command_comes_back_as_a_float_vector():
    sent = check_joint_speeds([0.1, -1, 2], LIMIT)
    assert sent.dtype == np.float64 and sent.shape == (3,)
    np.testing.assert_array_equal(sent, [0.1, -1.0, 2.0])
    np.testing.assert_array_equal(check_joint_speeds(np.float32([0.25, 0.5, -0.75]), LIMIT), [0.25, 0.5, -0.75])
    np.testing.assert_array_equal(check_joint_speeds(np.uint8([0, 1, 2]), LIMIT), [0.0, 1.0, 2.0])


@pytest.mark.parametrize("joint", range(3))
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_speed_exactly_at_its_limit_is_accepted_and_a_hair_over_is_refused(joint, sign):
    at = np.zeros(3)
    at[joint] = sign * LIMIT[joint]
    np.testing.assert_array_equal(check_joint_speeds(at, LIMIT), at)
    over = at.copy()
    over[joint] = np.nextafter(at[joint], sign * np.inf)  # the next float beyond the limit
    with pytest.raises(CommandRefusedError, match=rf"^joint speed \[{joint}\] is .* rad/s, beyond its limit"):
        check_joint_speeds(over, LIMIT)


def test_the_first_joint_over_its_limit_is_named():
    with pytest.raises(CommandRefusedError, match=r"^joint speed \[1\] is -1\.5 rad/s, beyond its limit 1 rad/s$"):
        check_joint_speeds([0.5, -1.5, 2.5], LIMIT)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_speed_is_refused_naming_the_first(bad):
    with pytest.raises(CommandRefusedError, match=rf"^joint speed \[1\] is {bad} \(non-finite\)$"):
        check_joint_speeds([0.0, bad, math.nan], LIMIT)


@pytest.mark.parametrize("speeds", [
    "abc", "0.1", ["0.1", "0.2", "0.3"], [b"1", b"0", b"0"],  # text is not a speed
    [True, False, False],  # nor a flag
    [1j, 0, 0],  # nor a complex number
    [10 ** 400, 0, 0],  # an integer no float can hold (OverflowError in NumPy's conversion)
    [None, 0.0, 0.0], {}, None, object(), (s for s in [0.0, 0.0, 0.0]),
    [np.timedelta64(1, "s")] * 3,
], ids=lambda v: type(v).__name__ if type(v) in (object, type(s for s in ())) else repr(v))
def test_anything_but_real_numbers_is_refused_never_another_error(speeds):
    with pytest.raises(CommandRefusedError, match=r"^joint speeds are not real numbers: .* \(NumPy dtype "):
        check_joint_speeds(speeds, LIMIT)


def test_a_command_numpy_cannot_read_is_refused_never_another_error():
    class Unreadable:
        def __array__(self, dtype=None, copy=None):
            raise RuntimeError("sensor bus gone")

    for speeds in ([0.0, [1.0, 2.0], 0.0], Unreadable()):
        with pytest.raises(CommandRefusedError, match=r"^joint speeds are not numbers: "):
            check_joint_speeds(speeds, LIMIT)


@pytest.mark.parametrize("speeds, message", [
    (np.zeros(2), r"^joint speeds have 2 entries; the arm has 3 joints$"),
    (np.zeros(4), r"^joint speeds have 4 entries; the arm has 3 joints$"),
    (np.zeros((1, 3)), r"^joint speeds must be one flat vector of 3 entries, got shape \(1, 3\)$"),
    (np.zeros((3, 1)), r"^joint speeds must be one flat vector of 3 entries, got shape \(3, 1\)$"),
    (0.0, r"^joint speeds must be one flat vector of 3 entries, got shape \(\)$"),
])
def test_a_command_of_another_shape_is_refused(speeds, message):
    with pytest.raises(CommandRefusedError, match=message):
        check_joint_speeds(speeds, LIMIT)


def test_a_long_refused_command_is_shortened_in_the_message():
    with pytest.raises(CommandRefusedError) as refused:
        check_joint_speeds(["x" * 200, "y", "z"], LIMIT)
    shown = str(refused.value).split(": ", 1)[1].split(" (NumPy")[0]
    assert len(shown) == 80 and shown.endswith("...")
    with pytest.raises(CommandRefusedError, match=r"^joint speeds are not real numbers: \['x', 'y', 'z'\] \("):
        check_joint_speeds(["x", "y", "z"], LIMIT)


# ------------------------------------------------------------------------------------ unwrapping


def _closed_form(measured: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The angle congruent to ``measured`` (mod 2π) within π of ``reference``."""
    return reference + np.mod(measured - reference + np.pi, 2 * np.pi) - np.pi


@pytest.mark.parametrize("jump", [0.0, 0.3, 0.8, 0.99, 1.01, 1.2, 1.8, 2.2, 3.5, -0.3, -0.8, -1.2, -1.8, -2.2, -3.5])
@pytest.mark.parametrize("turns", [-2, 0, 1, 3])
def test_continuous_joints_unwrap_to_the_closed_form(jump, turns):
    """A reading ``jump`` π away from the previous position, on a joint ``turns`` turns out: the
    result is the reading moved by whole turns to within π of the previous position (a 1.2π jump
    is really a 0.8π step the other way)."""
    reference = np.array([0.4 + 2 * np.pi * turns, -2.9 + 2 * np.pi * turns])
    measured = np.mod(reference + jump * np.pi, 2 * np.pi)  # as Kortex reads it: [0, 2π)
    out = unwrap_positions(measured, reference, np.array([True, True]))
    np.testing.assert_allclose(out, _closed_form(measured, reference), rtol=0, atol=1e-12)
    assert np.all(np.abs(out - reference) < np.pi)
    np.testing.assert_allclose(np.mod(out - measured + 0.1, 2 * np.pi), 0.1, atol=1e-9)  # whole turns only


def test_a_jump_of_one_point_two_pi_is_a_step_of_minus_zero_point_eight_pi():
    out = unwrap_positions(np.array([1.2 * np.pi, -1.2 * np.pi]), np.zeros(2), np.array([True, True]))
    np.testing.assert_allclose(out, [-0.8 * np.pi, 0.8 * np.pi], rtol=0, atol=1e-12)


def test_limited_joints_go_to_minus_pi_pi_or_within_pi_of_their_range_centre():
    readings = np.array([0.5, 3 * np.pi, -np.pi, 1.2 * np.pi, -1.2 * np.pi, 2 * np.pi + 0.1])
    limited = np.zeros(readings.size, dtype=bool)
    # no centre: (-π, π], -π itself read as π
    out = unwrap_positions(readings, None, limited)
    np.testing.assert_allclose(out, [0.5, np.pi, np.pi, -0.8 * np.pi, 0.8 * np.pi, 0.1], rtol=0, atol=1e-12)
    assert unwrap_positions(np.array([-np.pi]), None, np.array([False]))[0] == np.pi
    # a centre: within π of it, the reference (previous reading) plays no part for a limited joint
    centre = np.full(readings.size, 3.0)
    for reference in (None, np.full(readings.size, -20.0)):
        out = unwrap_positions(readings, reference, limited, centre)
        np.testing.assert_allclose(out, _closed_form(readings, centre), rtol=0, atol=1e-12)


def test_without_a_reference_continuous_joints_stay_as_read():
    readings = np.array([4.8, 7.0, -0.5])
    np.testing.assert_array_equal(unwrap_positions(readings, None, np.array([True, True, True])), readings)
    mixed = unwrap_positions(readings, None, np.array([True, False, True]))
    np.testing.assert_allclose(mixed, [4.8, 7.0 - 2 * np.pi, -0.5], rtol=0, atol=1e-12)


def test_range_centres_are_the_middle_of_each_limited_range_and_zero_for_a_continuous_joint():
    robot = types.SimpleNamespace(position_lower=np.array([0.8, -1.0, -np.inf]),
                                  position_upper=np.array([5.4, 3.0, np.inf]),
                                  limited=np.array([True, True, False]))
    np.testing.assert_array_equal(range_centres(robot), [3.1, 1.0, 0.0])


# ------------------------------------------------------------------------------------ frames and poses


def _frame(**changes) -> Feedback:
    values = dict(timestamp=1.0, frame_id=3, position=np.zeros(2), velocity=np.zeros(2), torque=np.zeros(2),
                  arm_state=ArmState.SERVOING_READY, faults=Fault.NONE)
    values.update(changes)
    return Feedback(**values)


@pytest.mark.parametrize("changes", [
    {"faults": Fault.LIMIT}, {"faults": Fault.COMMUNICATION}, {"arm_state": ArmState.IN_FAULT},
    {"position": np.array([0.0, np.nan])}, {"velocity": np.array([np.inf, 0.0])},
    {"torque": np.array([0.0, -np.inf])},
], ids=lambda c: next(iter(c)))
def test_a_frame_is_healthy_only_without_faults_and_with_finite_readings(changes):
    assert _frame().healthy
    assert not _frame(**changes).healthy


def test_object_poses_are_finite_only_when_every_array_is():
    values = dict(timestamp=0.0, cube_position=np.zeros(3), cube_quaternion=np.array([1.0, 0, 0, 0]),
                  cube_velocity=np.zeros(3), obstacle_positions=np.zeros((2, 3)),
                  obstacle_quaternions=np.tile([1.0, 0, 0, 0], (2, 1)), obstacle_velocities=np.zeros((2, 3)))
    assert ObjectPoses(**values).finite
    for key, value in values.items():
        if key == "timestamp":
            continue
        broken = np.array(value, dtype=float)
        broken.reshape(-1)[-1] = np.nan
        assert not ObjectPoses(**{**values, key: broken}).finite, key


# ------------------------------------------------------------------------------------ clocks


def test_the_fast_clock_moves_only_when_slept_on_and_never_back():
    clock = FastClock(start=2.0)
    assert clock.now() == 2.0
    clock.sleep(0.5)
    clock.sleep(-1.0)
    clock.sleep(0.0)
    assert clock.now() == 2.5
    clock.sleep_until(2.25)  # in the past: no change
    assert clock.now() == 2.5
    clock.sleep_until(3)
    assert clock.now() == 3.0 and isinstance(clock.now(), float)
    assert FastClock().now() == 0.0


class _FakeTime:
    """``time`` for WallClock: perf_counter advances 1e-5 s per read; sleep advances it exactly."""

    def __init__(self) -> None:
        self.t, self.sleeps = 100.0, []

    def perf_counter(self) -> float:
        self.t += 1e-5
        return self.t

    def sleep(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("sleep length must be non-negative")
        self.sleeps.append(seconds)
        self.t += seconds


def test_the_wall_clock_sleeps_coarsely_then_spins_the_last_half_millisecond(monkeypatch):
    fake = _FakeTime()
    monkeypatch.setattr(protocol, "time", fake)
    clock = WallClock()
    start = clock.now()
    clock.sleep_until(start + 0.01)
    assert fake.t >= start + 0.01  # never early
    assert fake.t < start + 0.01 + 1e-4  # and only a spin late
    assert len(fake.sleeps) == 1 and fake.sleeps[0] == pytest.approx(0.01 - 5e-4, abs=3e-5)
    fake.sleeps.clear()
    clock.sleep_until(fake.t + 4e-4)  # under half a millisecond: spun, not slept
    clock.sleep_until(fake.t - 1.0)  # in the past: returns at once
    assert fake.sleeps == []
    clock.sleep(0.002)
    clock.sleep(0.0)
    clock.sleep(-1.0)
    assert fake.sleeps == [0.002]


def test_the_wall_clock_is_real_time():
    clock = WallClock()
    before = clock.now()
    clock.sleep_until(before + 2e-3)
    assert clock.now() >= before + 2e-3


# ------------------------------------------------------------------------------------ adapter bases


class _Arm(DescribedArm):
    """The smallest adapter: the abstract methods do nothing but record what was called."""

    def __init__(self) -> None:
        self._robot = types.SimpleNamespace(joint_names=("a", "b"), velocity_limit=np.array([1.0, 2.0]))
        self._clock = FastClock()
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self.calls: list[str] = []
        self.faults, self.reason = Fault.NONE, ""

    def _require(self) -> None:
        if not self._connected:
            raise protocol.NotConnectedError("not connected")

    def _fault_state(self) -> tuple[Fault, str]:
        return self.faults, self.reason

    def _add_fault(self, flag: Fault, reason: str) -> None:
        self.faults, self.reason = self.faults | flag, reason

    def connect(self) -> None:
        self.calls.append("connect")
        self._connected = True

    def disconnect(self) -> None:
        self.calls.append("disconnect")
        self._connected = False

    def refresh_feedback(self) -> Feedback:
        raise NotImplementedError

    def _send(self, command: np.ndarray) -> np.ndarray:
        self.calls.append("send")
        return command

    def stop(self) -> None:
        pass

    def apply_emergency_stop(self) -> None:
        self.calls.append("e-stop")
        self._add_fault(Fault.EMERGENCY_STOP, "emergency stop applied")

    def clear_faults(self) -> None:
        pass

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self._mode = mode


def test_a_described_arm_answers_from_its_description_and_a_context_manager_closes_it():
    arm = _Arm()
    assert arm.joint_names == ("a", "b") and arm.num_joints == 2 and not arm.is_connected
    limit = arm.velocity_limit
    limit[0] = 99.0  # a copy: the description is not changed through it
    np.testing.assert_array_equal(arm.velocity_limit, [1.0, 2.0])
    assert arm.clock is arm._clock
    with pytest.raises(protocol.NotConnectedError):
        _ = arm.servoing_mode
    with arm as entered:
        assert entered is arm and arm.is_connected
        assert arm.servoing_mode == ServoingMode.SINGLE_LEVEL_SERVOING
    assert arm.calls == ["connect", "disconnect"] and not arm.is_connected


def test_the_gate_sends_a_command_at_its_limit_and_e_stops_on_one_beyond_it():
    arm = _Arm()
    arm.connect()
    np.testing.assert_array_equal(arm.send_joint_speeds([1.0, -2.0]), [1.0, -2.0])
    assert arm.calls == ["connect", "send"] and arm.faults == Fault.NONE
    with pytest.raises(CommandRefusedError, match=r"joint speed \[1\]"):
        arm.send_joint_speeds([0.0, np.nextafter(2.0, 3.0)])
    assert arm.calls == ["connect", "send", "e-stop"]  # e-stopped, nothing sent
    assert arm.faults == Fault.EMERGENCY_STOP | Fault.LIMIT
    assert arm.reason.startswith("refused command: joint speed [1]")


@pytest.mark.parametrize("state", ["not connected", "in fault", "low-level servoing"])
def test_the_gate_checks_the_session_the_fault_and_the_mode_before_the_command(state):
    """A bad command meets the earlier refusals first: none of them sends or e-stops."""
    arm = _Arm()
    if state != "not connected":
        arm.connect()
    if state == "in fault":
        arm.faults, arm.reason = Fault.HARDWARE, "an actuator is hot"
    if state == "low-level servoing":
        arm.set_servoing_mode(ServoingMode.LOW_LEVEL_SERVOING)
    error = {"not connected": protocol.NotConnectedError, "in fault": ArmFaultError,
             "low-level servoing": ArmFaultError}[state]
    with pytest.raises(error) as refused:
        arm.send_joint_speeds([np.nan, 99.0])
    assert "send" not in arm.calls and "e-stop" not in arm.calls
    assert Fault.LIMIT not in arm.faults
    if state == "in fault":
        assert "HARDWARE" in str(refused.value) and "an actuator is hot" in str(refused.value)


def test_the_session_is_checked_before_the_fault_flags():
    """Faults left from before a disconnect do not hide that there is no session."""
    arm = _Arm()
    arm.faults, arm.reason = Fault.EMERGENCY_STOP, "emergency stop applied"
    with pytest.raises(protocol.NotConnectedError):
        arm.send_joint_speeds([0.0, 0.0])


def test_the_adapter_base_defaults_to_the_wall_clock():
    assert type(ArmAdapter.clock.fget(_Arm())) is WallClock  # type: ignore[attr-defined]


def test_fault_flags_are_distinct_bits_so_that_any_combination_reads_back():
    assert [flag.value for flag in (Fault.EMERGENCY_STOP, Fault.LIMIT, Fault.HARDWARE, Fault.COMMUNICATION,
                                    Fault.WATCHDOG)] == [1, 2, 4, 8, 16]
    both = Fault.EMERGENCY_STOP | Fault.LIMIT
    assert Fault.EMERGENCY_STOP in both and Fault.LIMIT in both and Fault.HARDWARE not in both
    assert not Fault.NONE


def test_frames_and_poses_cannot_be_changed():
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        _frame().faults = Fault.LIMIT  # type: ignore[misc]
    poses = ObjectPoses(0.0, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros((0, 3)),
                        np.zeros((0, 4)), np.zeros((0, 3)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        poses.timestamp = 1.0  # type: ignore[misc]


def test_a_refused_command_is_shown_whole_up_to_80_characters():
    for length, shown in ((80, 80), (81, 80)):
        text = "x" * (length - 2)  # repr adds the quotes
        with pytest.raises(CommandRefusedError) as refused:
            check_joint_speeds(text, LIMIT)
        message = str(refused.value)
        assert len(message.split(": ", 1)[1].split(" (NumPy")[0]) == shown
        assert message.count("...") == (length > 80)
