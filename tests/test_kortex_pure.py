"""The Kortex backend's pure parts: units, unwrapping, messages, state mapping, credentials — and
that a password never reaches an error message or the log."""

from __future__ import annotations

import logging
import math
import types

import numpy as np
import pytest

from ahrm_stack.hardware.kortex import (INSTALL_HINT, Credentials, CredentialsError, KortexArm,
                             KortexNotInstalledError, arm_state_from_kortex, degrees_to_radians,
                             faults_from_banks, feedback_from_values, import_kortex_api,
                             joint_speeds_message, load_credentials, radians_to_degrees, scrub,
                             servoing_mode_name, unwrap_positions)
from fake_kortex_api.rig import fake_api, options, standin_control_config, standin_frame, standin_reply
from ahrm_stack.hardware.protocol import ArmState, Fault, HardwareError, NotConnectedError, ServoingMode

PASSWORD = "s3cr3t-Pa55word!"


def test_degree_conversion_round_trips():
    np.testing.assert_allclose(radians_to_degrees([math.pi, -math.pi / 2, 0.0]), [180.0, -90.0, 0.0])
    np.testing.assert_allclose(degrees_to_radians([90.0, 360.0]), [math.pi / 2, 2 * math.pi])
    values = np.linspace(-7, 7, 11)
    np.testing.assert_allclose(degrees_to_radians(radians_to_degrees(values)), values)


def test_continuous_joints_unwrap_to_the_previous_reading():
    continuous = np.array([True, False])
    # 359° read as 1° a moment later: one more turn, not a jump back to 0.
    previous = np.array([math.radians(359.0), 0.2])
    measured = np.array([math.radians(1.0), 0.25])
    np.testing.assert_allclose(unwrap_positions(measured, previous, continuous),
                               [math.radians(361.0), 0.25])
    # A limited joint reported as 270° is -90°.
    np.testing.assert_allclose(unwrap_positions(np.array([0.0, math.radians(270.0)]), None,
                                                continuous), [0.0, -math.pi / 2])
    # The JACO home (275°) stays 275° for a continuous joint with no reference.
    assert unwrap_positions(np.array([math.radians(275.0)]), None, np.array([True]))[0] == \
        pytest.approx(math.radians(275.0))


@pytest.mark.parametrize("robot", ["jaco", "j2s6s200"])
def test_limited_joints_read_inside_their_range_past_180_degrees(robot):
    """JACO's joints 2 and 3 (and the j2s6s200's joint 5) span more than 180°: Kortex's
    (-180°, 180°] reading of every angle in the range must come back as that angle."""
    from ahrm_stack.robot import describe, make_arm
    description = describe(robot, make_arm(robot))
    limited = description.limited
    centre = np.where(limited, 0.5 * (np.where(limited, description.position_lower, 0.0)
                                      + np.where(limited, description.position_upper, 0.0)), 0.0)
    for index in np.flatnonzero(limited):
        lower, upper = description.position_lower[index], description.position_upper[index]
        for angle in np.linspace(lower, upper, 37):
            reading = np.zeros(description.num_joints)
            reading[index] = np.radians((np.degrees(angle) + 180.0) % 360.0 - 180.0)  # Kortex
            position = unwrap_positions(reading, None, ~limited, centre)
            assert position[index] == pytest.approx(angle, abs=1e-12)
    # Hand-computed: JACO's joint 2 (47°..313°) read as -150° is at 210°.
    assert math.degrees(unwrap_positions(np.array([math.radians(-150.0)]), None,
                                         np.array([False]), np.array([math.radians(180.0)]))[0]) \
        == pytest.approx(210.0)


def test_kortex_arm_reads_limited_joints_past_180_degrees():
    """The backend passes each limited joint's range centre: a fake feedback frame with joint 2
    at -150° (Kortex's reading of 210°) comes back as 210°."""
    from ahrm_stack.robot import describe, make_arm
    description = describe("jaco", make_arm("jaco"))
    arm = KortexArm(description, "192.0.2.1", Credentials("admin", PASSWORD), options(), api={})
    assert math.degrees(arm._range_centre[1]) == pytest.approx(180.0)
    assert math.degrees(arm._range_centre[2]) == pytest.approx(180.0)
    frame = feedback_from_values(timestamp=0.0, frame_id=1,
                                 positions_deg=[275.0, -150.0, 60.0, 243.0, 83.0, 75.0],
                                 velocities_deg_s=[0.0] * 6, torques_nm=[0.0] * 6,
                                 arm_state_name="ARMSTATE_SERVOING_READY",
                                 continuous=~description.limited, range_centre=arm._range_centre)
    np.testing.assert_allclose(np.degrees(frame.position), [275.0, 210.0, 60.0, 243.0, 83.0, 75.0])


def test_joint_speeds_message_is_plain_degrees_per_second():
    message = joint_speeds_message([math.pi / 4, 0.0, -math.pi])
    assert message == [{"joint_identifier": 0, "value": pytest.approx(45.0), "duration": 0},
                       {"joint_identifier": 1, "value": 0.0, "duration": 0},
                       {"joint_identifier": 2, "value": pytest.approx(-180.0), "duration": 0}]


@pytest.mark.parametrize("name, state", [
    ("ARMSTATE_SERVOING_READY", ArmState.SERVOING_READY), ("ARMSTATE_IN_FAULT", ArmState.IN_FAULT),
    ("ARMSTATE_IDLE", ArmState.IDLE), ("ARMSTATE_SERVOING_LOW_LEVEL", ArmState.SERVOING_LOW_LEVEL),
    ("ARMSTATE_RESERVED", ArmState.IN_FAULT), ("nonsense", ArmState.IN_FAULT)])
def test_arm_state_mapping_never_reads_unknown_as_ready(name, state):
    assert arm_state_from_kortex(name) == state


def test_servoing_mode_names():
    assert servoing_mode_name(ServoingMode.SINGLE_LEVEL_SERVOING) == "SINGLE_LEVEL_SERVOING"
    assert servoing_mode_name(ServoingMode.LOW_LEVEL_SERVOING) == "LOW_LEVEL_SERVOING"


def test_fault_banks():
    assert faults_from_banks(0, 0, [0, 0], ArmState.SERVOING_READY) == Fault.NONE
    assert faults_from_banks(0, 0, [0, 4], ArmState.SERVOING_READY) == Fault.HARDWARE
    assert faults_from_banks(2, 0, [], ArmState.IN_FAULT) == Fault.HARDWARE
    assert faults_from_banks(0, 0, [0], ArmState.IN_FAULT) == Fault.EMERGENCY_STOP


def test_feedback_from_values_is_si():
    frame = feedback_from_values(timestamp=1.5, frame_id=7, positions_deg=[90.0, -45.0],
                                 velocities_deg_s=[180.0, 0.0], torques_nm=[1.0, -2.0],
                                 arm_state_name="ARMSTATE_SERVOING_READY",
                                 continuous=np.array([True, False]))
    np.testing.assert_allclose(frame.position, [math.pi / 2, -math.pi / 4])
    np.testing.assert_allclose(frame.velocity, [math.pi, 0.0])
    np.testing.assert_allclose(frame.torque, [1.0, -2.0])
    assert frame.healthy and frame.frame_id == 7 and frame.timestamp == 1.5


def test_missing_kortex_api_says_how_to_install(monkeypatch):
    import builtins
    real_import = builtins.__import__

    def no_kortex(name, *args, **kwargs):
        if name.startswith("kortex_api"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_kortex)
    with pytest.raises(KortexNotInstalledError) as error:
        import_kortex_api()
    assert str(error.value) == INSTALL_HINT
    # Kinova's instructions (Kinova-kortex2_Gen3_G3L api_python/examples/readme.md) and, for
    # Python >= 3.10, the maintainer's workaround (issue 191).
    assert "not on PyPI" in INSTALL_HINT
    assert ("artifactory.kinovaapps.com:443/artifactory/generic-public/kortex/API/2.6.0/"
            "kortex_api-2.6.0.post3-py3-none-any.whl") in INSTALL_HINT
    assert "python3 -m pip install kortex_api-2.6.0.post3-py3-none-any.whl" in INSTALL_HINT
    assert "protobuf==3.5.1" in INSTALL_HINT and "Python >= 3.10" in INSTALL_HINT
    assert "pip install protobuf==3.20 deprecated==1.2.7" in INSTALL_HINT
    assert "pip install kortex_api-2.6.0.post3-py3-none-any.whl --no-deps" in INSTALL_HINT
    assert "\n" not in INSTALL_HINT  # one line


def test_credentials_from_environment_and_file(tmp_path):
    env = {"KORTEX_USERNAME": "admin", "KORTEX_PASSWORD": PASSWORD}
    assert load_credentials(env=env) == Credentials("admin", PASSWORD)
    file = tmp_path / "kortex.txt"
    file.write_text(f"operator\n{PASSWORD}\n")
    assert load_credentials(file, env={}, repository_root=tmp_path / "repo") == \
        Credentials("operator", PASSWORD)
    with pytest.raises(CredentialsError, match="KORTEX_PASSWORD"):
        load_credentials(env={"KORTEX_USERNAME": "admin"})


def test_credentials_file_inside_the_repository_is_refused(tmp_path):
    repo = tmp_path / "repo"
    (repo / "configs").mkdir(parents=True)
    inside = repo / "configs" / "kortex.txt"
    inside.write_text(f"admin\n{PASSWORD}\n")
    with pytest.raises(CredentialsError, match="inside the repository") as error:
        load_credentials(inside, env={}, repository_root=repo)
    assert PASSWORD not in str(error.value)


def test_password_never_in_repr_or_scrubbed_text():
    credentials = Credentials("admin", PASSWORD)
    assert PASSWORD not in repr(credentials) and PASSWORD not in str(credentials)
    assert f"{credentials}" == "Credentials(username='admin', password='***')"
    assert scrub(f"login {PASSWORD} refused", [PASSWORD]) == "login *** refused"



class SendOptions:
    """kortex_api.RouterClient.RouterClientSendOptions: the vendor default timeout is 10 s."""

    def __init__(self):
        self.andForget, self.delay_ms, self.timeout_ms = False, 0, 10000

def _fake_api(fail_with: Exception | None = None, actuators: int = 6) -> dict:
    """Stand-ins for the vendor modules; the session refuses the login with ``fail_with``."""

    class Transport:
        def connect(self, address, port):
            self.address = address

        def disconnect(self):
            pass

    class Session:
        def __init__(self, router):
            pass

        def CreateSession(self, info, **options):
            if fail_with is not None:
                raise fail_with

        def CloseSession(self, **options):
            pass

    class Info:
        pass

    class Base:
        def __init__(self, router):
            self.calls = []

        def __getattr__(self, name):
            return lambda *args, **options: standin_reply(name, 6)

    class Cyclic:
        def __init__(self, router):
            pass

        def RefreshFeedback(self, **options):
            return standin_frame(actuators)

    return {"TCPTransport": types.SimpleNamespace(TCPTransport=Transport),
            "RouterClient": types.SimpleNamespace(RouterClient=lambda t, cb: object(),
                                                RouterClientSendOptions=SendOptions),
            "SessionManager": types.SimpleNamespace(SessionManager=Session),
            "BaseClientRpc": types.SimpleNamespace(BaseClient=Base),
            "BaseCyclicClientRpc": types.SimpleNamespace(BaseCyclicClient=Cyclic),
            "Session_pb2": types.SimpleNamespace(CreateSessionInfo=Info),
            "Base_pb2": types.SimpleNamespace(ServoingModeInformation=Info, SINGLE_LEVEL_SERVOING=2,
                                              LOW_LEVEL_SERVOING=3),
            "Common_pb2": fake_api()["Common_pb2"], **standin_control_config()}


def test_password_never_appears_in_errors_or_logs(task_config, caplog):
    from ahrm_stack.env.task import PushOffTask

    robot = PushOffTask(task_config).robot
    # The vendor's exception echoes the request, password included.
    api = _fake_api(RuntimeError(f"login refused for admin/{PASSWORD}"))
    arm = KortexArm(robot, "192.0.2.10", Credentials("admin", PASSWORD), options(), api=api)
    assert PASSWORD not in repr(arm.__dict__.get("_credentials"))
    with caplog.at_level(logging.DEBUG), pytest.raises(HardwareError) as error:
        arm.connect()
    assert PASSWORD not in str(error.value) and "***" in str(error.value)
    assert error.value.__cause__ is None and error.value.__context__ is None  # not chained
    assert "192.0.2.10" in str(error.value)
    assert caplog.records and all(PASSWORD not in r.getMessage() for r in caplog.records)
    assert not arm.is_connected


def test_kortex_arm_needs_an_explicit_address_and_matching_arm(task_config):
    from ahrm_stack.env.task import PushOffTask

    robot = PushOffTask(task_config).robot
    for address in (None, "", "  "):
        with pytest.raises(HardwareError, match="address"):
            KortexArm(robot, address, Credentials("admin", PASSWORD), options(),
                      api=_fake_api())
    arm = KortexArm(robot, "192.0.2.10", Credentials("admin", PASSWORD), options(),
                    api=_fake_api(actuators=7))
    with pytest.raises(HardwareError, match="7 actuators") as error:
        arm.connect()
    assert PASSWORD not in str(error.value) and not arm.is_connected
    with pytest.raises(NotConnectedError):
        arm.refresh_feedback()
