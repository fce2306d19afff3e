"""The second arm, the spherical-wrist JACO2 j2s6s200 of example-robot-data, and the config choice
between the two arms. Expected values come from the URDF parsed here with xml.etree, from MuJoCo,
or from dm_control's own JACO — never from the code under test."""

import importlib.metadata
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

import numpy as np
import pytest
import yaml
from dm_control import mjcf
from dm_control.entities.manipulators.kinova import jaco_arm
from scipy.spatial.transform import Rotation

from ahrm_stack.arms.assets import RobotAssetError, robot_file
from ahrm_stack.config import ConfigError, arm_names, config_from_dict, load_arm, load_config, load_raw
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.kinematics.model import UrdfArmKinematics
from ahrm_stack.hardware import FastClock
from ahrm_stack.sim_arm import SimArm

URDF = "robots/kinova_description/robots/kinova.urdf"
LINKS = [f"j2s6s200_link_{i}" for i in range(1, 7)]
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.fixture(scope="module")
def config():
    return load_config(["task.robot=j2s6s200"])


@pytest.fixture(scope="module")
def runner(config):
    runner = TaskRunner(PushOffTask(config.task), seed=0, safety=config.safety)
    runner.reset()
    return runner


def _urdf_joints() -> dict[str, ET.Element]:
    """The URDF's joints by name, read straight from the installed file."""
    dist = importlib.metadata.distribution("example-robot-data")
    entry = next(f for f in dist.files if str(f).endswith("share/example-robot-data/" + URDF))
    root = ET.parse(dist.locate_file(entry)).getroot()
    return {j.get("name"): j for j in root.findall("joint")}


def _robot_yaml() -> dict:
    """configs/robots/j2s6s200.yaml, read with PyYAML alone."""
    return yaml.safe_load((CONFIGS / "robots" / "j2s6s200.yaml").read_text())


def _urdf_transform(joint: ET.Element, angle: float = 0.0) -> np.ndarray:
    """4 x 4 child-in-parent transform of a URDF joint at ``angle`` (rad) about its axis."""
    origin = joint.find("origin")
    xyz = [float(v) for v in origin.get("xyz").split()]
    rpy = [float(v) for v in origin.get("rpy").split()]
    transform = np.eye(4)
    transform[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # extrinsic x-y-z = URDF rpy
    transform[:3, 3] = xyz
    if joint.get("type") != "fixed":
        axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
        spin = np.eye(4)
        spin[:3, :3] = Rotation.from_rotvec(angle * axis).as_matrix()
        transform = transform @ spin
    return transform


def test_the_urdf_comes_from_the_installed_package_not_a_fixed_path():
    path = robot_file(URDF)
    dist = importlib.metadata.distribution("example-robot-data")
    assert dist.version == "6.0.0"
    assert path.is_file() and "cmeel.prefix" in path.parts
    assert path == dist.locate_file(next(f for f in dist.files if str(f).endswith(URDF)))
    with pytest.raises(RobotAssetError, match=r"'robots/none\.urdf' is not a file of the installed"):
        robot_file("robots/none.urdf")


def test_pinocchio_stores_the_three_continuous_joints_as_cos_sin(runner):
    kin, robot = runner.task.kinematics, runner.task.robot
    assert isinstance(kin, UrdfArmKinematics)
    assert (kin.model.nq, kin.model.nv) == (9, 6)
    continuous = [i for i, name in enumerate(robot.joint_names)
                  if _urdf_joints()[name].get("type") == "continuous"]
    assert continuous == [0, 3, 5] == list(kin.joint_map.continuous)
    q = np.array([7.0, 1.2, 2.0, -4.0, 3.0, 0.5])
    configuration = kin.configuration(q)
    assert configuration.shape == (9,)
    np.testing.assert_allclose(configuration[0:2], [np.cos(7.0), np.sin(7.0)])
    np.testing.assert_allclose(configuration[2:4], [1.2, 2.0])
    back = kin.joint_map.from_pinocchio(configuration)
    np.testing.assert_allclose(np.cos(back), np.cos(q), atol=1e-15)
    np.testing.assert_allclose(np.sin(back), np.sin(q), atol=1e-15)


def _elements(task):
    arm = task.arm.mjcf_model
    elements = [arm.find("body", name) for name in ("base", "j2s6s200_link_base", *LINKS)]
    return elements + [task.arm.wrist_site, task.pusher.tip_site, task.pusher.center_site,
                       task.pusher.mjcf_model.find("body", "pusher")]


def test_pinocchio_from_the_urdf_matches_mujoco_on_1000_random_configurations(runner):
    task, physics = runner.task, runner.physics
    kin, robot = task.kinematics, task.robot
    elements = _elements(task)
    frames = [kin.element_frame_id(e) for e in elements]
    qpos = physics.bind(task.arm.joints).qposadr
    rng = np.random.default_rng(0)
    worst_position = worst_rotation = 0.0
    for _ in range(1000):
        q = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        limited = robot.limited
        q[limited] = rng.uniform(robot.position_lower[limited], robot.position_upper[limited])
        physics.data.qpos[qpos] = q
        physics.forward()
        kin.update(q)
        for element, frame in zip(elements, frames):
            bound = physics.bind(element)
            position, rotation = kin.frame_pose(frame)
            worst_position = max(worst_position, np.abs(position - bound.xpos).max())
            worst_rotation = max(worst_rotation,
                                 np.abs(rotation - np.reshape(bound.xmat, (3, 3))).max())
    assert worst_position <= 1e-9, worst_position
    assert worst_rotation <= 1e-9, worst_rotation


def test_frames_1_to_4_of_both_arms_agree_after_a_90_degree_base_yaw():
    """dm_control's JACO (MuJoCo, base at the origin) against the j2s6s200 URDF chain composed here
    with its root frame yawed by -90 degrees: link frames 1-4 coincide for the same joint angles."""
    jaco = jaco_arm.JacoArm()
    physics = mjcf.Physics.from_mjcf_model(jaco.mjcf_model)
    joints = _urdf_joints()
    chain = ["jaco_mounting_block_to_j2s6s200_link_base"] + [f"j2s6s200_joint_{i}" for i in range(1, 5)]
    yaw = np.eye(4)
    yaw[:3, :3] = Rotation.from_euler("z", -np.pi / 2).as_matrix()
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(200):
        q = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        q[1:3] = rng.uniform([0.9, 0.4], [5.4, 5.9])
        physics.bind(jaco.joints).qpos = q
        physics.forward()
        transform = yaw
        for i, name in enumerate(chain):
            transform = transform @ _urdf_transform(joints[name], q[i - 1] if i else 0.0)
            if i == 0:
                continue
            body = physics.bind(jaco.mjcf_model.find("body", f"b_{i}"))
            worst = max(worst, np.abs(transform[:3, 3] - body.xpos).max(),
                        np.abs(transform[:3, :3] - np.reshape(body.xmat, (3, 3))).max())
    assert worst <= 1e-9, worst


def test_the_two_arms_differ_from_the_wrist_on():
    jaco = PushOffTask(load_config().task)
    j2 = PushOffTask(load_config(["task.robot=j2s6s200"]).task)
    q = np.radians([275, 175, 78, 243, 83, 75])
    jaco.kinematics.update(q)
    j2.kinematics.update(q + np.radians([90, 0, 0, 0, 0, 0]))  # the same base yaw for joints 1-4
    p4, _ = jaco.kinematics.frame_pose(jaco.kinematics.frame_id("b_4"))
    q4, _ = j2.kinematics.frame_pose(j2.kinematics.frame_id("j2s6s200_link_4"))
    p6, _ = jaco.kinematics.frame_pose(jaco.kinematics.frame_id("b_6"))
    q6, _ = j2.kinematics.frame_pose(j2.kinematics.frame_id("j2s6s200_link_6"))
    assert np.abs(p4 - q4).max() < 1e-9
    assert np.linalg.norm(p6 - q6) > 0.01


def test_safety_filter_and_actuators_take_their_limits_from_the_urdf(runner, config):
    joints = _urdf_joints()
    names = [f"j2s6s200_joint_{i}" for i in range(1, 7)]
    lower = np.array([float(joints[n].find("limit").get("lower")) if joints[n].get("type") == "revolute"
                      else -np.inf for n in names])
    upper = np.array([float(joints[n].find("limit").get("upper")) if joints[n].get("type") == "revolute"
                      else np.inf for n in names])
    velocity = np.array([float(joints[n].find("limit").get("velocity")) for n in names])
    effort = np.array([float(joints[n].find("limit").get("effort")) for n in names])
    assert np.isfinite(lower).tolist() == [False, True, True, False, True, False]  # joint 5 limited
    safety = runner.filter
    assert safety.robot.joint_names == tuple(names)
    np.testing.assert_array_equal(safety.robot.position_lower, lower)
    np.testing.assert_array_equal(safety.robot.position_upper, upper)
    np.testing.assert_array_equal(safety.robot.velocity_limit, velocity)
    margin = config.safety.position_margin
    np.testing.assert_array_equal(safety.position.lower, np.where(np.isfinite(lower), lower + margin, -np.inf))
    np.testing.assert_array_equal(safety.position.upper, np.where(np.isfinite(upper), upper - margin, np.inf))
    margin = max(config.safety.velocity_margin, _robot_yaml()["min_velocity_margin"])
    np.testing.assert_allclose(safety.velocity.limit, velocity * (1 - margin), rtol=1e-15)
    actuators = runner.physics.bind(runner.task.arm.actuators)
    np.testing.assert_array_equal(np.asarray(actuators.ctrlrange)[:, 1], velocity)
    np.testing.assert_array_equal(np.asarray(actuators.forcerange)[:, 1], effort)


@pytest.mark.parametrize("robot, joint_prefix, nq", [("jaco", "joint_", 6), ("j2s6s200", "j2s6s200_joint_", 9)])
def test_the_robot_choice_reaches_task_kinematics_filter_and_hardware(robot, joint_prefix, nq):
    config = load_config([f"task.robot={robot}"])
    arm = SimArm(config.task, clock=FastClock())
    task = arm.task
    assert task.robot.name == robot
    assert task.robot.joint_names == tuple(f"{joint_prefix}{i}" for i in range(1, 7))
    assert task.kinematics.model.nq == nq and task.kinematics.model.nv == 6
    assert arm.joint_names == task.robot.joint_names
    np.testing.assert_array_equal(arm.velocity_limit, task.robot.velocity_limit)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    assert runner.filter.robot is task.robot
    np.testing.assert_allclose(task.config.arm.home,
                               np.radians(load_raw()["task"]["arm"]["home_deg"][robot]))


def test_home_pose_holds_the_pusher_above_the_table(runner, config):
    """The default home: pusher vertical, tip above the obstacles' tops (phase 2); the paper
    profile's Kinova-like home: tip above the obstacle region (phase 1)."""
    fresh = TaskRunner(PushOffTask(config.task), seed=0, safety=config.safety)
    fresh.reset()  # the module's runner has been stepped by earlier tests
    tip = fresh.task.step_info.tip
    top = config.task.table.height + config.task.obstacles.size[2]
    axis = np.reshape(fresh.physics.bind(fresh.task.pusher.tip_site).xmat, (3, 3))[:, 2]
    assert tip[2] > top + 0.05 and axis[2] < -0.99
    paper = load_config(["task.robot=j2s6s200", "profile=paper"])
    home = TaskRunner(PushOffTask(paper.task), seed=0, safety=paper.safety)
    home.reset()
    assert home.task.step_info.tip[2] > paper.task.table.height + paper.task.regions.obstacle_height
    assert home.task.step_info.phase == 1


def test_the_pusher_replaces_the_hand_and_points_toward_the_end_effector(runner):
    """The hand's mesh is not built; the pusher's axis is the flange-to-end-effector direction."""
    physics, task = runner.physics, runner.task
    meshes = {physics.model.mesh(i).name.rsplit("/", 1)[-1] for i in range(physics.model.nmesh)}
    assert "hand_2finger" not in meshes and {"arm", "forearm", "wrist_spherical_1"} <= meshes
    joints = _urdf_joints()
    to_end_effector = _urdf_transform(joints["j2s6s200_joint_end_effector"])[:3, 3]
    flange = physics.bind(task.arm.mjcf_model.find("body", "j2s6s200_link_6"))
    expected = np.reshape(flange.xmat, (3, 3)) @ to_end_effector / np.linalg.norm(to_end_effector)
    axis = np.reshape(physics.bind(task.pusher.tip_site).xmat, (3, 3))[:, 2]
    np.testing.assert_allclose(axis, expected, atol=1e-12)
    np.testing.assert_allclose(physics.bind(task.arm.wrist_site).xpos, flange.xpos, atol=1e-12)


def test_every_link_gets_a_collision_capsule_and_the_scene_sees_them(runner):
    scene = runner.task.make_collision_scene(runner.physics)
    assert set(LINKS[:5]) <= set(scene.robot)
    assert all(c.radius > 0.02 for c in scene.capsules)


def test_an_unknown_robot_is_named_with_the_choices():
    with pytest.raises(ConfigError, match=r"task\.robot: no arm 'ur5'; registered \(configs/robots/\): "
                                          r"\['gen3', 'j2s6s200', 'jaco'\]"):
        load_config(["task.robot=ur5"])
    assert arm_names() == ("gen3", "j2s6s200", "jaco")


def test_a_home_pose_per_robot_is_checked():
    raw = load_raw()
    del raw["task"]["arm"]["home_deg"]["j2s6s200"]
    raw["task"]["robot"] = "j2s6s200"
    with pytest.raises(ConfigError, match=r"task\.arm\.home_deg has no entry for robot 'j2s6s200'"):
        config_from_dict(raw)
    raw = load_raw()
    raw["task"]["arm"]["home_deg"]["ur5"] = [0] * 6
    with pytest.raises(ConfigError, match=r"task\.arm\.home_deg\.ur5: no arm 'ur5'; registered"):
        config_from_dict(raw)
    with pytest.raises(ConfigError, match=r"task\.arm\.home_deg 5: both give one value per joint"):
        PushOffTask(load_config(["task.robot=j2s6s200", "task.arm.home_deg=[0, 90, 90, 0, 90]"]).task)


# ----------------------------------------------------------------------------------------------
# The velocity margin: the j2s6s200's servo lags more under gravity than safety.velocity_margin
# ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def jaco():
    config = load_config()
    runner = TaskRunner(PushOffTask(config.task), seed=0, safety=config.safety)
    runner.reset()
    return runner


def test_the_velocity_bound_takes_the_arms_larger_margin_and_the_jacos_is_unchanged(runner, config, jaco):
    """j2s6s200: |u| <= (1 - max(safety margin, the robot yaml's)) v_max with v_max from the URDF,
    and the braking horizon from the same speed; jaco: (1 - safety.yaml's margin) times dm_control's
    own actuator range, as before."""
    shared = yaml.safe_load((CONFIGS / "safety.yaml").read_text())["velocity_margin"]
    own = _robot_yaml()["min_velocity_margin"]
    assert own > shared  # else the key would change nothing
    joints = _urdf_joints()
    urdf_v = np.array([float(joints[f"j2s6s200_joint_{i}"].find("limit").get("velocity")) for i in range(1, 7)])
    accel = np.asarray(_robot_yaml()["acceleration_limit"], dtype=float)
    dt = config.task.episode.control_period
    safety = runner.filter
    np.testing.assert_allclose(safety.velocity.limit, urdf_v * (1 - own), rtol=1e-15)
    assert safety.horizon == pytest.approx(max(dt, float(np.max(urdf_v * (1 - own) / accel))), rel=1e-12)
    result = safety(runner.task.config.arm.home, np.zeros(6), 2 * urdf_v, u_prev=urdf_v * (1 - own))
    assert np.all(np.abs(result.command) <= urdf_v * (1 - own) * (1 + 1e-9))

    arm = jaco_arm.JacoArm()
    physics = mjcf.Physics.from_mjcf_model(arm.mjcf_model)
    ctrl = np.asarray(physics.bind(arm.actuators).ctrlrange)[:, 1]
    assert jaco.task.robot.min_velocity_margin == 0.0
    np.testing.assert_allclose(jaco.filter.velocity.limit, ctrl * (1 - shared), rtol=1e-15)
    assert jaco.filter.horizon == pytest.approx(max(dt, float(np.max(ctrl * (1 - shared) / accel))), rel=1e-12)


def _gravity_lag(runner, samples: int = 3000) -> np.ndarray:
    """Per joint, the largest steady servo lead under gravity over random joint vectors within the
    limits, as a fraction of the velocity limit: (|gravity torque| - frictionloss)^+ / kv / v_max,
    with the torques from MuJoCo at rest (qfrc_bias, qvel = 0) and kv, frictionloss from the model."""
    physics, task = runner.physics, runner.task
    model, data = physics.model.ptr, mujoco.MjData(physics.model.ptr)
    joints = physics.bind(task.arm.joints)
    qadr, dofadr = np.asarray(joints.qposadr), np.asarray(joints.dofadr)
    kv = np.asarray(physics.bind(task.arm.actuators).gainprm)[:, 0]
    limit = np.asarray(physics.bind(task.arm.actuators).ctrlrange)[:, 1]
    data.qpos[:] = physics.data.qpos
    lower = np.where(task.robot.limited, task.robot.position_lower, -np.pi)
    upper = np.where(task.robot.limited, task.robot.position_upper, np.pi)
    worst = np.zeros(len(qadr))
    for q in np.random.default_rng(0).uniform(lower, upper, (samples, len(qadr))):
        data.qpos[qadr] = q
        mujoco.mj_forward(model, data)
        worst = np.maximum(worst, np.abs(data.qfrc_bias[dofadr]))
    return np.maximum(worst - model.dof_frictionloss[dofadr], 0.0) / kv / limit


def test_each_arms_margin_covers_its_servo_lag_under_gravity(runner, config, jaco):
    """The filter's margin exceeds the lag (gravity torque / gain) of every joint on both arms; on
    the j2s6s200 joint 2 alone would exceed safety.velocity_margin (why the robot carries its own)."""
    lag = _gravity_lag(runner)
    margin = 1 - runner.filter.velocity.limit / runner.task.robot.velocity_limit
    assert lag[1] > config.safety.velocity_margin
    assert np.all(lag < margin - 0.01), (lag, margin)
    jaco_lag = _gravity_lag(jaco)
    assert np.all(jaco_lag < 1 - jaco.filter.velocity.limit / jaco.task.robot.velocity_limit - 0.01)


@pytest.mark.parametrize("value", [-0.1, 1.0])
def test_a_bad_robot_velocity_margin_is_named(tmp_path, value):
    robots = tmp_path / "robots"
    robots.mkdir()
    data = _robot_yaml()
    data["min_velocity_margin"] = value
    (robots / "j2s6s200.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=rf"robots/j2s6s200\.min_velocity_margin must be in \[0, 1\), got {value}"):
        load_arm("j2s6s200", robots)
