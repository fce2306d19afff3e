"""The arm model check on connect, over the fake arm: its ProductConfiguration (model, DoF) and its
joint speed hard limits against the robot description the policy was trained on and
``kortex.models``; each refusal one line naming both, before any motion command. The ModelId
values are Kinova's (api_python/doc/markdown/enums/ProductConfiguration/ModelId.md)."""

from __future__ import annotations

import numpy as np
import pytest

from fake_kortex_api.rig import make_for, options
from ahrm_stack.hardware.kortex import KortexModel, model_name
from ahrm_stack.hardware.protocol import HardwareError


@pytest.fixture(scope="module")
def robot():
    from ahrm_stack.robot import describe, make_arm

    return describe("jaco", make_arm("jaco"))


def _refusal(robot, opts=None, **arm) -> str:
    adapter, fake = make_for(robot, opts=opts, **arm)
    with pytest.raises(HardwareError) as error:
        adapter.connect()
    assert not adapter.is_connected and fake.sessions == 0
    assert "SendJointSpeedsCommand" not in [c.name for c in fake.calls]
    assert "\n" not in str(error.value)
    return str(error.value)


def test_kinovas_model_ids():
    assert [model_name(i) for i in range(4)] == ["MODEL_ID_UNSPECIFIED", "MODEL_ID_L53",
                                                 "MODEL_ID_L31", "MODEL_ID_HDK"]
    assert model_name(9) == "MODEL_ID_9?"


def test_a_matching_arm_connects(robot):
    adapter, _ = make_for(robot)
    adapter.connect()
    assert adapter.arm_description == "MODEL_ID_L53 (Gen3), 6 DoF"
    adapter.disconnect()


def test_a_7_dof_gen3_is_refused_for_a_6_joint_policy(robot):
    """The issue's hazard the other way round: only the actuator count would not catch a
    description mapped to another DoF; here the arm reports 7 DoF and 6 actuators."""
    text = _refusal(robot, product={"model": 1, "dof": 7})
    assert text.startswith("the arm at 192.0.2.")
    assert ("is a MODEL_ID_L53 (Gen3), 7 DoF; the policy's robot 'jaco' (6 joints) is a "
            "MODEL_ID_L53 with 6 DoF (kortex.models)") in text


def test_another_model_with_the_same_dof_is_refused(robot):
    text = _refusal(robot, product={"model": 2, "dof": 6})
    assert "is a MODEL_ID_L31 (PICO), 6 DoF; the policy's robot 'jaco'" in text


def test_a_description_that_is_no_kortex_arm_is_refused(robot):
    """A description kortex.models does not map (as shipped, the JACO Gen2s: only gen3 is mapped)."""
    text = _refusal(robot, opts=options(models={}))
    assert "the policy's robot 'jaco' (6 joints) is not a Kortex arm" in text
    assert "kortex.models has no entry for 'jaco'" in text


def test_slower_joint_hard_limits_are_refused(robot):
    limits = np.degrees(robot.velocity_limit)
    slower = limits.copy()
    slower[3] *= 0.8
    text = _refusal(robot, speed_hard_limit_deg_s=slower)
    assert (f"allows joint 3 at most {slower[3]:.1f} deg/s; the policy's robot 'jaco' (6 joints) "
            f"was trained with {limits[3]:.1f} deg/s on {robot.joint_names[3]}") in text
    adapter, _ = make_for(robot, opts=options(speed_limit_tolerance=0.3, soft_limit_tolerance=0.3),
                          speed_hard_limit_deg_s=slower)  # 25 % over is within 30 % (the fake's soft
    # limits are its hard ones unless given)
    adapter.connect()
    adapter.disconnect()


def test_a_dof_that_differs_from_the_descriptions_joints_is_refused(robot):
    """kortex.models itself says 7 DoF for the 6-joint description (a config mistake): the arm
    matches the entry, yet not the description."""
    opts = options(models={"jaco": KortexModel("MODEL_ID_L53", 7)})
    text = _refusal(robot, opts=opts, product={"model": 1, "dof": 7})
    assert "has 6 actuators (MODEL_ID_L53 (Gen3), 7 DoF); the policy's robot 'jaco' (6 joints)" in text


def test_a_joint_without_a_hard_limit_is_refused(robot):
    limits = np.degrees(robot.velocity_limit)[:5]  # the arm reports joints 0..4 only
    text = _refusal(robot, speed_hard_limit_deg_s=limits)
    assert f"reports no speed hard limit for joint 5; the policy's robot 'jaco' (6 joints) needs " \
        f"{np.degrees(robot.velocity_limit[5]):.1f} deg/s on {robot.joint_names[5]}" in text


def test_models_come_from_the_config(robot):
    opts = options(models={"jaco": KortexModel("MODEL_ID_L31", 6)})
    adapter, _ = make_for(robot, opts=opts, product={"model": 2, "dof": 6})
    adapter.connect()
    assert adapter.arm_description == "MODEL_ID_L31 (PICO), 6 DoF"
    adapter.disconnect()


# ---------------------------------------------------------------------------------------------
# Soft limits (ControlConfig.GetAllKinematicSoftLimits), read on connect
# ---------------------------------------------------------------------------------------------


def _soft(robot, speed=None, acceleration=(), modes=("ANGULAR_JOYSTICK", "ANGULAR_TRAJECTORY")):
    speed = np.degrees(robot.velocity_limit) if speed is None else speed
    return [{"control_mode": mode, "joint_speed": list(speed), "joint_acceleration": list(acceleration)}
            for mode in modes]


def test_the_soft_limits_are_read_on_connect(robot):
    adapter, fake = make_for(robot, soft_limits=_soft(robot))
    adapter.connect()
    assert [e["control_mode"] for e in adapter.soft_limits] == ["ANGULAR_JOYSTICK", "ANGULAR_TRAJECTORY"]
    names = [c.name for c in fake.calls]
    assert names.index("GetAllKinematicSoftLimits") < names.index("SetServoingMode")
    assert [c.timeout_ms for c in fake.calls if c.name == "GetAllKinematicSoftLimits"] == [
        options().session_rpc_timeout_ms]
    adapter.disconnect()


def test_a_soft_limit_below_the_policy_is_refused_in_one_line(robot):
    """The lowest soft limit over kortex.soft_limit_modes counts (here ANGULAR_TRAJECTORY's), by
    model_refusal's rule: the description's velocity limit over the arm's limit times 1 + the
    tolerance."""
    limits = np.degrees(robot.velocity_limit)
    soft = _soft(robot)
    soft[1]["joint_speed"][3] = 0.75 * limits[3]
    text = _refusal(robot, soft_limits=soft)
    assert text == (f"the arm at {text.split()[3]} (MODEL_ID_L53 (Gen3), 6 DoF) has a joint speed soft limit "
                    f"of {0.75 * limits[3]:.1f} deg/s on joint 3 (ANGULAR_TRAJECTORY); the policy's robot "
                    f"'jaco' (6 joints) was trained with {limits[3]:.1f} deg/s on {robot.joint_names[3]} "
                    "(kortex.soft_limit_tolerance 0): raise the arm's soft limit or deploy a policy within it")
    adapter, _ = make_for(robot, opts=options(soft_limit_tolerance=0.4), soft_limits=soft)
    adapter.connect()  # 33 % over is within 40 %
    adapter.disconnect()
    adapter, _ = make_for(robot, opts=options(soft_limit_modes=("ANGULAR_JOYSTICK",)), soft_limits=soft)
    adapter.connect()  # the trajectory mode's limit is not the policy's when not listed
    adapter.disconnect()


def test_a_missing_mode_or_joint_is_refused(robot):
    text = _refusal(robot, soft_limits=_soft(robot, modes=("CARTESIAN_JOYSTICK",)))
    assert "reports no soft limits for control mode ANGULAR_JOYSTICK" in text
    assert "kortex.soft_limit_modes" in text
    text = _refusal(robot, soft_limits=_soft(robot, speed=np.degrees(robot.velocity_limit)[:5]))
    assert "reports no joint speed soft limit for joint 5" in text


def test_acceleration_soft_limits_are_checked_where_reported(robot):
    """With the policy's acceleration limits (the safety filter's, rad/s^2) given: an arm reporting
    a lower acceleration soft limit is refused; one reporting none is not."""
    from fake_kortex_api.rig import fake_api
    from ahrm_stack.hardware.kortex import Credentials, KortexArm

    accel = np.array([4.0, 4.0, 4.0, 6.0, 6.0, 6.0])  # configs/robots/jaco.yaml
    for reported, refused in (((), False), (np.degrees(accel) * 2, False), (np.degrees(accel) * 0.5, True)):
        _, fake = make_for(robot, soft_limits=_soft(robot, acceleration=reported))
        address = next(a for (a, _), arm in fake_api()["_fake_arm"].FakeArm._registry.items() if arm is fake)
        adapter = KortexArm(robot, address, Credentials("admin", "pw"), options(), api=fake_api(),
                            acceleration_limit=accel)
        if refused:
            with pytest.raises(HardwareError, match="joint acceleration soft limit of 114.6 deg/s\\^2 on joint 0"):
                adapter.connect()
        else:
            adapter.connect()
            adapter.disconnect()
