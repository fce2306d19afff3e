"""Pinocchio forward kinematics against MuJoCo on the very model the simulator compiles."""

import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from dm_control import mjcf

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.kinematics.model import ArmKinematics, relative_name


@pytest.fixture(scope="module")
def runner(task_config):
    runner = TaskRunner(PushOffTask(task_config), seed=0)
    runner.reset()
    return runner


def _frames(task):
    """(MJCF element, kind) for every link body, the wrist site and the pusher's sites and body."""
    arm = task.arm.mjcf_model
    elements = [arm.find("body", name) for name in ("b_base", *task.robot.link_bodies)]
    elements += [task.arm.wrist_site, task.pusher.tip_site, task.pusher.center_site,
                 task.pusher.mjcf_model.find("body", "pusher")]
    return elements


def _mujoco_pose(physics, element):
    bound = physics.bind(element)
    return np.array(bound.xpos), np.array(bound.xmat).reshape(3, 3)


def test_pinocchio_matches_mujoco_on_1000_random_configurations(runner):
    task, physics = runner.task, runner.physics
    kin = task.kinematics
    elements = _frames(task)
    frame_ids = [kin.element_frame_id(e) for e in elements]
    qpos = physics.bind(task.arm.joints).qposadr
    rng = np.random.default_rng(0)
    worst_pos = worst_rot = 0.0
    for _ in range(1000):
        q = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        q[1:3] = rng.uniform(task.robot.position_lower[1:3], task.robot.position_upper[1:3])
        physics.data.qpos[qpos] = q
        physics.forward()
        kin.update(q)
        for element, fid in zip(elements, frame_ids):
            p_mj, r_mj = _mujoco_pose(physics, element)
            p_pin, r_pin = kin.frame_pose(fid)
            worst_pos = max(worst_pos, np.abs(p_pin - p_mj).max())
            worst_rot = max(worst_rot, np.abs(r_pin - r_mj).max())
    assert worst_pos <= 1e-9, worst_pos
    assert worst_rot <= 1e-9, worst_rot


def test_raw_pinocchio_parser_misplaces_the_pusher_sites_and_the_fix_repairs_them(runner):
    """Pinocchio 4.1.0 misplaces sites on nested bodies without joints: show it, then the fix."""
    task, physics = runner.task, runner.physics
    with tempfile.TemporaryDirectory() as tmp:
        mjcf.export_with_assets(task.arm.mjcf_model, tmp, "arm.xml")
        raw = pin.buildModelFromMJCF(str(Path(tmp) / "arm.xml"))
    raw_data = raw.createData()
    q = np.asarray(task.config.arm.home)
    physics.data.qpos[physics.bind(task.arm.joints).qposadr] = q
    physics.forward()
    pin.framesForwardKinematics(raw, raw_data, q)
    name = relative_name(task.pusher.tip_site, task.arm.mjcf_model)
    raw_tip = (task.kinematics.base * raw_data.oMf[raw.getFrameId(name)]).translation
    p_mj, _ = _mujoco_pose(physics, task.pusher.tip_site)
    assert np.linalg.norm(raw_tip - p_mj) > 1e-2  # the parser's defect is real ...
    task.kinematics.update(q)
    fixed_tip, _ = task.kinematics.frame_pose(task.kinematics.element_frame_id(task.pusher.tip_site))
    assert np.abs(fixed_tip - p_mj).max() < 1e-12  # ... and repaired


def test_top_level_body_pose_is_folded_into_the_base():
    """Pinocchio 4.1.0 drops the pose of a top-level body without a joint; ArmKinematics keeps it."""
    root = mjcf.RootElement(model="toy")
    base = root.worldbody.add("body", name="base", pos=[0.1, -0.2, 0.3], quat=[0.5, 0.5, 0.5, 0.5])
    link = base.add("body", name="link", pos=[0, 0, 0.2])
    link.add("joint", name="hinge", type="hinge", axis=[0, 1, 0])
    link.add("geom", type="capsule", size=[0.02, 0.1], mass=1)
    link.add("site", name="end", pos=[0.3, 0, 0])
    kin = ArmKinematics(root, base_position=[1.0, 2.0, 0.5], base_yaw=0.7)
    physics = mjcf.Physics.from_mjcf_model(root)
    for angle in (0.0, 0.4, -1.3):
        physics.data.qpos[0] = angle
        physics.forward()
        kin.update(np.array([angle]))
        p, r = kin.frame_pose(kin.frame_id("end"))
        # expected by hand: world = base placement (yaw about z, then translate) * MuJoCo's pose
        c, s = np.cos(0.7), np.sin(0.7)
        yaw = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        expected_p = yaw @ physics.named.data.site_xpos["end"] + [1.0, 2.0, 0.5]
        expected_r = yaw @ physics.named.data.site_xmat["end"].reshape(3, 3)
        np.testing.assert_allclose(p, expected_p, atol=1e-12)
        np.testing.assert_allclose(r, expected_r, atol=1e-12)


def test_jacobian_matches_finite_differences(runner):
    kin = runner.task.kinematics
    tip = kin.element_frame_id(runner.task.pusher.tip_site)
    q = np.asarray(runner.task.config.arm.home) + 0.1
    kin.update(q)
    jac = kin.frame_jacobian(tip)[:3]
    eps = 1e-6
    numeric = np.zeros((3, 6))
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = eps
        kin.update(q + dq)
        plus, _ = kin.frame_pose(tip)
        kin.update(q - dq)
        minus, _ = kin.frame_pose(tip)
        numeric[:, i] = (plus - minus) / (2 * eps)
    np.testing.assert_allclose(jac, numeric, atol=1e-7)
