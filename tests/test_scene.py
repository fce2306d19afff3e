"""Collision scene: capsules enclose the base's and every link's collision geoms; distances and
witness points agree with geometry (coal, to 1e-6 m)."""

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


def _enclosed_points(model, geom) -> np.ndarray:
    """Points of a geom in its body's frame, computed here: a mesh's vertices, or 2000 points on
    each rim of a cylinder (exactly on the circles)."""
    if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[geom]
        local = model.mesh_vert[model.mesh_vertadr[mesh]:model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
    else:
        assert model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_CYLINDER
        r, h = model.geom_size[geom][:2]
        a = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
        rim = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)], axis=1)
        local = np.concatenate([rim - [0, 0, h], rim + [0, 0, h]])
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[geom])
    return np.asarray(local) @ rot.reshape(3, 3).T + model.geom_pos[geom]


def test_capsules_enclose_the_base_and_every_links_collision_geoms(scene_and_runner):
    scene, runner = scene_and_runner
    model = runner.physics.model.ptr
    robot = runner.task.robot
    assert [c.frame for c in scene.capsules] == [robot.base_body, *robot.link_bodies]
    kinds = set()
    for capsule in scene.capsules:
        body = model.body(f"jaco/{capsule.frame}").id
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body
                 and (model.geom_contype[g] or model.geom_conaffinity[g])]
        assert geoms
        for geom in geoms:
            kinds.add(int(model.geom_type[geom]))
            local = _enclosed_points(model, geom)
            assert np.all(_segment_distance(local, capsule.start, capsule.end) <= capsule.radius + 1e-9)
    assert kinds == {mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_CYLINDER}


def test_pusher_to_table_distance_matches_mujoco_geometry(scene_and_runner):
    """Compare the scene's pusher-table distance with the pusher's lowest point from MuJoCo's pose."""
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
        inside = np.all(np.abs(geom.xpos[:2]) < np.asarray(task.config.table.half_extent) - 0.1)
        if lowest - task.config.table.height > 1e-3 and inside:  # above the top, not its edge
            assert d.distance == pytest.approx(lowest - task.config.table.height, abs=1e-6)
            assert np.linalg.norm(d.point_a - d.point_b) == pytest.approx(d.distance, abs=1e-6)
            assert d.point_b[2] == pytest.approx(task.config.table.height, abs=1e-6)
            np.testing.assert_allclose(d.normal, [0, 0, 1], atol=1e-4)
