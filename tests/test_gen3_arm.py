"""The Kinova Gen3 (7 DoF) of the arm registry (configs/robots/gen3.yaml), built from the URDF and
meshes vendored in ahrm_stack/arms/vendor/kinova_gen3/ (from robosuite 1.5.2's PyPI wheel).

Expected values come from Kinova's published numbers written here (joint limits of Kinova's URDF,
joint speeds of the Gen3 user guide) and from robosuite's own model of the arm
(tests/data/robosuite_kinova3/robot.xml, compiled with plain MuJoCo) — never from the code under test.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest
from dm_control import mjcf

from ahrm_stack.arms.assets import resolve_uri
from ahrm_stack.config import load_arm, load_config
from ahrm_stack.deploy import load_deploy_settings
from ahrm_stack.deploy.safety_settings import merge_safety
from ahrm_stack.env.episode_loop import scripted_episode
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.hardware.kortex.arm_model import model_refusal
from ahrm_stack.hardware.kortex.settings import KortexModel
from ahrm_stack.kinematics.model import UrdfArmKinematics
from ahrm_stack.robot import describe, make_arm, robot_urdf
from ahrm_stack.schema import FrozenDict

ROBOSUITE_XML = Path(__file__).resolve().parent / "data" / "robosuite_kinova3" / "robot.xml"
VENDOR = Path(__file__).resolve().parents[1] / "ahrm_stack" / "arms" / "vendor" / "kinova_gen3"
# Our link bodies and robosuite's bodies of the same links, joint 1's link first.
LINKS = {"shoulder_link": "shoulder_link", "half_arm_1_link": "HalfArm1_Link", "half_arm_2_link": "HalfArm2_Link",
         "forearm_link": "forearm_link", "spherical_wrist_1_link": "SphericalWrist1_Link",
         "spherical_wrist_2_link": "SphericalWrist2_Link", "bracelet_link": "Bracelet_Link"}
# Kinova's Gen3 user guide, maximum joint speeds: large actuators (joints 1-4) 79.64 deg/s, small
# actuators (joints 5-7) 69.91 deg/s. Kinova's URDF: joints 2, 4, 6 limited, 1, 3, 5, 7 continuous.
SPEED_DEG = np.array([79.64] * 4 + [69.91] * 3)
LIMITS = {1: 2.41, 3: 2.66, 5: 2.23}


@pytest.fixture(scope="module")
def arm():
    return make_arm("gen3")


@pytest.fixture(scope="module")
def reference():
    model = mujoco.MjModel.from_xml_path(str(ROBOSUITE_XML))
    return model, mujoco.MjData(model)


def test_the_gen3_builds_with_kinovas_limits_from_vendored_files(arm):
    entry = load_arm("gen3")
    robot = describe("gen3", arm)
    physics = mjcf.Physics.from_mjcf_model(arm.mjcf_model)  # compiles
    assert robot.num_joints == 7 and physics.model.nu == 7 and len(entry.home_deg) == 7
    assert robot.joint_names == tuple(f"joint_{i}" for i in range(1, 8))
    assert robot.link_bodies == tuple(LINKS) and robot.base_body == "base_link"
    for i in range(7):
        if i in LIMITS:
            assert (robot.position_lower[i], robot.position_upper[i]) == (-LIMITS[i], LIMITS[i])
        else:
            assert robot.position_lower[i] == -np.inf and robot.position_upper[i] == np.inf
    # Kinova's speeds, never above them (deploy refuses a description faster than the arm's hard limit)
    speed = np.degrees(robot.velocity_limit)
    assert np.all(speed <= SPEED_DEG) and np.all(speed > SPEED_DEG - 1e-4)
    assert robot.commanded_joints == (0, 1, 2, 3, 4, 5)  # joint 7 spins the pusher only
    assert entry.kinova_gen2 is None and entry.kortex == {"model": "MODEL_ID_L53", "dof": 7}
    assert load_deploy_settings().kortex.models["gen3"].dof == 7
    # every file comes from the package itself, none from example-robot-data
    urdf = robot_urdf("gen3")
    assert urdf.path == VENDOR / "gen3.urdf"
    meshes = {m.uri for link in urdf.links.values() for m in (*link.visuals, *link.collisions)}
    assert len(meshes) == 8 and all(resolve_uri(uri).parent == VENDOR / "meshes" for uri in meshes)
    assert {p.name for p in VENDOR.iterdir()} >= {"LICENSE", "LICENSE-kortex", "README.md"}
    # the pusher is mounted on Kinova's tool flange, pointing out of the arm along the bracelet's -z
    mount = arm.wrist_site
    assert mount.parent.name == "end_effector_link" and mount.parent.parent.name == "bracelet_link"


def test_a_kortex_gen3_at_its_hard_limits_is_accepted_by_deploy(arm):
    robot = describe("gen3", arm)
    limits = [{"joint": i, "type": 3, "value": float(v)} for i, v in enumerate(SPEED_DEG)]
    models = {"gen3": KortexModel("MODEL_ID_L53", 7)}
    assert model_refusal(robot, {"model": 1, "dof": 7}, limits, models, tolerance=0.0, actuators=7,
                         where="192.168.1.10") is None
    assert "7 DoF" in model_refusal(robot, {"model": 1, "dof": 6}, limits, models, tolerance=0.0, actuators=6,
                                    where="192.168.1.10")


def test_a_checkpoint_trained_before_the_gen3_was_registered_deploys_without_a_safety_note():
    """Its safety.self_collision_pairs lacks gen3's: no difference (deploy's pairs are used either way)."""
    ours = load_config().safety
    before = FrozenDict({arm: pairs for arm, pairs in ours.self_collision_pairs.items() if arm != "gen3"})
    assert merge_safety(ours, dataclasses.replace(ours, self_collision_pairs=before)) == (ours, [])
    changed = FrozenDict({**before, "jaco": before["jaco"][1:]})
    _, notes = merge_safety(ours, dataclasses.replace(ours, self_collision_pairs=changed))
    assert [(n.key, n.kind) for n in notes] == [("self_collision_pairs", "other")]


def test_forward_kinematics_match_robosuites_gen3(arm, reference):
    """Our MuJoCo entity and our Pinocchio model (both from the vendored URDF) against robosuite's
    robot.xml at random joint vectors: every link frame, the bracelet's included, to 1e-6 m
    (robosuite writes Kinova's rotations as quaternions rounded to 6 digits: measured 8e-7 m at most
    over 5000 draws) and 1e-5 in rotation; masses, centres of mass and inertias as robosuite's."""
    model, data = reference
    robot = describe("gen3", arm)
    physics = mjcf.Physics.from_mjcf_model(arm.mjcf_model)
    kinematics = UrdfArmKinematics(robot.urdf, arm.mjcf_model, [0.0, 0.0, 0.0], 0.0)
    assert model.nq == 7 and [model.joint(i).name for i in range(7)] == [f"Actuator{i}" for i in range(1, 8)]
    limited = model.jnt_limited.astype(bool)
    np.testing.assert_array_equal(limited, robot.limited)
    np.testing.assert_array_equal(model.jnt_range[limited, 1], robot.position_upper[limited])
    ours = {name: physics.model.body(name).id for name in LINKS}
    for name, theirs in LINKS.items():
        b, t = ours[name], model.body(theirs).id
        assert physics.model.body_mass[b] == pytest.approx(model.body_mass[t], abs=1e-12)
        np.testing.assert_allclose(physics.model.body_ipos[b], model.body_ipos[t], atol=1e-12)
        np.testing.assert_allclose(_inertia(physics.model, b), _inertia(model, t), rtol=1e-5,
                                   atol=1e-8)  # robosuite: 6 digits
    rng = np.random.default_rng(0)
    lower = np.where(robot.limited, robot.position_lower, -np.pi)
    upper = np.where(robot.limited, robot.position_upper, np.pi)
    worst = 0.0
    for q in [np.zeros(7), *rng.uniform(lower, upper, (40, 7))]:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        physics.bind(arm.joints).qpos = q
        physics.forward()
        kinematics.update(q)
        for name, theirs in LINKS.items():
            position, rotation = data.body(theirs).xpos, data.body(theirs).xmat.reshape(3, 3)
            p_pin, r_pin = kinematics.frame_pose(kinematics.frame_id(name))
            p_mj = physics.data.xpos[ours[name]]
            worst = max(worst, np.linalg.norm(p_pin - position), np.linalg.norm(p_mj - position))
            np.testing.assert_allclose(r_pin, rotation, atol=1e-5)
            np.testing.assert_allclose(physics.data.xmat[ours[name]].reshape(3, 3), rotation, atol=1e-5)
            np.testing.assert_allclose(p_pin, p_mj, atol=1e-9)  # our two models agree exactly
    assert worst < 1e-6, worst


def _inertia(model: mujoco.MjModel, body: int) -> np.ndarray:
    """The body's inertia tensor about its centre of mass, in its frame (kg m^2)."""
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, model.body_iquat[body])
    rotation = rotation.reshape(3, 3)
    return rotation @ np.diag(model.body_inertia[body]) @ rotation.T


def test_the_task_runs_the_gen3_and_the_scripted_controller_pushes_the_cube_off():
    config = load_config(["task.robot=gen3", "task.arm.start=home", "task.arm.joint_jitter=0",
                          "task.layout.mode=fixed", "task.action.mode=joint"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    assert runner.control.action_size == 6 and len(runner.filter.distances.self_pairs) == 12
    # the home posture: pusher vertical, tip 0.2 m above the table at (0.1, 0.2), jaco's home tip
    q, _ = task.arm_state(runner.physics)
    np.testing.assert_allclose(q, np.radians(load_arm("gen3").home_deg), atol=1e-12)
    task.kinematics.update(q)
    tip, _ = task.kinematics.frame_pose(task._tip_frame)
    _, rotation = task.kinematics.frame_pose(task._center_frame)
    assert np.linalg.norm(tip - [0.1, 0.2, config.task.table.height + 0.2]) < 1e-3
    assert np.degrees(np.arccos(np.clip(-rotation[2, 2], -1, 1))) < 0.01
    pusher = ScriptedPusher(task, config.scripted)
    for seed in (0, 1):
        steps = list(scripted_episode(runner, pusher, seed))
        assert steps[-1].terminated, f"seed {seed}: the cube stayed on the table"
        assert not any(s.sent is not None and s.info.touched for s in steps), f"seed {seed} touched"
