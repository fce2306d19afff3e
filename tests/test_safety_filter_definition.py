"""SafetyFilter's construction (issue 57, item 7: what mutation testing found untested): each
refusal is one SafetyFilterError naming the value, each edge value is accepted, the braking
horizon is its closed form, and ``max_rows`` counts exactly the row families switched on."""

from __future__ import annotations

import dataclasses

import pytest

from ahrm_stack.config import load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety.filter import SafetyFilter, SafetyFilterError, braking_time


@pytest.fixture(scope="module")
def setting():
    config = load_config([])
    runner = TaskRunner(PushOffTask(config.task), seed=0)
    runner.reset()
    task = runner.task
    scene = task.make_collision_scene(runner.physics)
    kin = task.kinematics
    frames = dict(tip_frame=kin.element_frame_id(task.pusher.tip_site),
                  wrist_frame=kin.element_frame_id(task.arm.wrist_site))
    return config, task, scene, frames


def _make(setting, safety=None, dt=0.05, scene="task", robot=None, **frames):
    config, task, task_scene, task_frames = setting
    return SafetyFilter(robot or task.robot, task.kinematics, safety or config.safety, dt=dt,
                        table_height=config.task.table.height, **{**task_frames, **frames},
                        scene=task_scene if scene == "task" else scene)


def test_the_braking_time_is_the_slowest_joints_stop_from_its_commandable_speed(setting):
    """max_i (1 - margin) v_i / a_i, with the largest ratio on a joint other than the first."""
    config, task, _, _ = setting
    robot = task.robot
    accel = [40.0] * robot.num_joints
    accel[2] = 0.5  # joint 3 stops slowest
    safety = dataclasses.replace(config.safety, acceleration_limit=accel, velocity_margin=0.25)
    margin = max(0.25, robot.min_velocity_margin)
    expected = (1.0 - margin) * robot.velocity_limit[2] / 0.5
    assert braking_time(robot, safety) == pytest.approx(expected, rel=1e-12)
    assert _make(setting, dataclasses.replace(safety, braking_horizon=True)).horizon == pytest.approx(expected)
    assert _make(setting, dataclasses.replace(safety, braking_horizon=False)).horizon == 0.05
    fast = dataclasses.replace(safety, acceleration_limit=[1e6] * robot.num_joints, braking_horizon=True)
    assert _make(setting, fast).horizon == 0.05  # never shorter than one control period


def test_each_bad_setting_is_refused_naming_it_and_the_edges_are_accepted(setting):
    config, task, scene, frames = setting
    count = len(task.kinematics.model.frames)
    for name in ("tip_frame", "wrist_frame"):
        for bad in (-1, count):
            with pytest.raises(SafetyFilterError, match=rf"{name}={bad} is not a frame of the kinematics model"):
                _make(setting, **{name: bad})
        for edge in (0, count - 1):
            _make(setting, **{name: edge})
    for bad in (0.0, -0.05, float("nan"), float("inf")):
        with pytest.raises(SafetyFilterError, match="dt must be a finite control period > 0 s"):
            _make(setting, dt=bad)
    assert _make(setting, dt=1e-9).dt == 1e-9
    with pytest.raises(SafetyFilterError, match="safety.solver is 'qpoases'; choose daqp or osqp"):
        _make(setting, dataclasses.replace(config.safety, solver="qpoases"))
    fewer = dataclasses.replace(task.robot, joint_names=task.robot.joint_names[:-1])
    message = rf"the kinematics model has nq=\d+, nv=6; {task.robot.name} has 5 joints"
    with pytest.raises(SafetyFilterError, match=message):
        _make(setting, robot=fewer)
    other = load_config(["task.robot=j2s6s200"])
    runner = TaskRunner(PushOffTask(other.task), seed=0)
    runner.reset()
    foreign = runner.task.make_collision_scene(runner.physics)
    if foreign.kinematics.model.nq != task.kinematics.model.nq:
        with pytest.raises(SafetyFilterError, match="the collision scene was built on another kinematics model"):
            _make(setting, scene=foreign)


def test_max_rows_counts_exactly_the_families_switched_on(setting):
    config, task, scene, _ = setting
    moving, pairs = len(scene.moving_parts), len(_make(setting).distances.self_pairs)
    off = dict(table_rows=False, workspace_rows=False, table_distance_rows=False, obstacle_rows=False,
               self_collision_rows=False)
    assert _make(setting, dataclasses.replace(config.safety, **off), scene=None).max_rows == 0
    only_table = _make(setting, dataclasses.replace(config.safety, **{**off, "table_rows": True}), scene=None)
    assert only_table.max_rows == 2  # the tip and the wrist
    distances = _make(setting, dataclasses.replace(config.safety, **{**off, "self_collision_rows": True}))
    assert distances.max_rows == config.safety.max_obstacle_rows + pairs
    with_table = _make(setting, dataclasses.replace(config.safety, **{**off, "table_distance_rows": True}))
    assert with_table.max_rows == config.safety.max_obstacle_rows + moving
