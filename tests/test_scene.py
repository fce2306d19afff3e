"""FCL scene: capsules enclose the link meshes; distances and witness points agree with geometry."""

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.kinematics.scene import fit_capsule


def _segment_distance(points, start, end):
    axis = end - start
    length2 = float(axis @ axis)
    t = np.zeros(len(points)) if length2 == 0 else np.clip((points - start) @ axis / length2, 0, 1)
    return np.linalg.norm(points - (start + np.outer(t, axis)), axis=1)


@settings(max_examples=300, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(2, 40), st.just(3)),
              elements=st.floats(-1.0, 1.0, allow_nan=False)))
def test_fitted_capsule_encloses_every_point(points):
    capsule = fit_capsule(points, "frame")
    assert np.all(_segment_distance(points, capsule.start, capsule.end) <= capsule.radius + 1e-9)


def test_capsule_of_a_cylinder_point_cloud_by_hand():
    # points on two circles of radius 0.05 at z = 0 and z = 0.3: the tight capsule has radius 0.05
    # and its segment shrinks to the circles' planes (each rim point is then exactly at distance r)
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    ring = np.stack([0.05 * np.cos(angles), 0.05 * np.sin(angles), np.zeros_like(angles)], axis=1)
    points = np.concatenate([ring, ring + [0, 0, 0.3]])
    capsule = fit_capsule(points, "f")
    assert capsule.radius == pytest.approx(0.05, abs=1e-12)
    assert capsule.length == pytest.approx(0.3, abs=1e-9)


@pytest.fixture(scope="module")
def scene_and_runner(task_config):
    runner = TaskRunner(PushOffTask(task_config), seed=0)
    runner.reset()
    return runner.task.make_collision_scene(runner.physics), runner


def test_link_capsules_enclose_the_compiled_link_meshes(scene_and_runner):
    scene, runner = scene_and_runner
    model = runner.physics.model.ptr
    assert len(scene.capsules) == 5
    for capsule in scene.capsules:
        body = model.body(f"jaco/{capsule.frame}").id
        for geom in range(model.ngeom):
            if model.geom_bodyid[geom] != body or model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH:
                continue
            mesh = model.geom_dataid[geom]
            verts = model.mesh_vert[model.mesh_vertadr[mesh]:model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
            local = verts @ rot.reshape(3, 3).T + model.geom_pos[geom]
            assert np.all(_segment_distance(local, capsule.start, capsule.end) <= capsule.radius + 1e-9)


def test_pusher_to_table_distance_matches_mujoco_geometry(scene_and_runner):
    """Compare FCL's pusher-table distance with the pusher's lowest point from MuJoCo's pose."""
    scene, runner = scene_and_runner
    task, physics = runner.task, runner.physics
    rng = np.random.default_rng(1)
    qadr = physics.bind(task.arm.joints).qposadr
    for _ in range(50):
        q = np.asarray(task.config.arm.home) + rng.uniform(-0.6, 0.6, 6)
        physics.data.qpos[qadr] = q
        physics.forward()
        task.kinematics.update(q)
        scene.update_robot()
        geom = physics.bind(task.pusher.geom)
        axis = np.array(geom.xmat).reshape(3, 3)[:, 2]
        # lowest point of a cylinder: centre - h |a_z| - r sqrt(1 - a_z^2) in z
        lowest = geom.xpos[2] - task.pusher.half_length * abs(axis[2]) - task.pusher.radius * np.sqrt(1 - axis[2] ** 2)
        d = scene.distance("pusher", "table")
        if lowest - task.config.table.height > 1e-3:  # well above: FCL GJK accuracy ~2e-4 m
            assert d.distance == pytest.approx(lowest - task.config.table.height, abs=5e-4)
            assert np.linalg.norm(d.point_a - d.point_b) == pytest.approx(d.distance, abs=5e-4)
            assert d.point_b[2] == pytest.approx(task.config.table.height, abs=5e-4)
