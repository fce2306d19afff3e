"""The task distribution: the cube anywhere in its region, random start postures (every arm)."""

import numpy as np
import pytest

from ahrm_stack.config import ConfigError, arm_names, load_config
from ahrm_stack.env.layout import LayoutSampler, validate_layout
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask


def _sampler(*overrides):
    task = load_config(list(overrides)).task
    return task, LayoutSampler(task.table, task.cube, task.obstacles, task.layout)


def test_random_cubes_fill_the_region_and_every_layout_is_valid():
    task, sampler = _sampler("task.layout.mode=random")
    rng = np.random.RandomState(0)
    layouts = [sampler.sample(rng) for _ in range(200)]
    cubes = np.array([layout.cube_xy for layout in layouts])
    (x_lo, x_hi), (y_lo, y_hi) = task.layout.cube_region
    assert cubes[:, 0].min() >= x_lo and cubes[:, 0].max() <= x_hi
    assert cubes[:, 1].min() >= y_lo and cubes[:, 1].max() <= y_hi
    # spread over the region, not stuck near its centre: each quarter of x and y is visited
    for axis, (lo, hi) in enumerate(task.layout.cube_region):
        counts = np.histogram(cubes[:, axis], bins=4, range=(lo, hi))[0]
        assert counts.min() >= 20, counts
    for layout in layouts:
        validate_layout(layout, task.table, task.cube, task.obstacles, task.layout)


def test_a_moved_cube_in_random_mode_is_not_checked_against_the_unused_fixed_layout():
    # the fixed layout does not fit around this cube (obstacle 2 at [-0.02, -0.17] is too close)
    with pytest.raises(ConfigError, match="task.obstacles.fixed_layout / task.cube.position: no free lane"):
        _sampler("task.layout.mode=fixed", "task.cube.position=[0.08,-0.06]")
    _sampler("task.layout.mode=random", "task.cube.position=[0.08,-0.06]")


def test_a_cube_region_off_the_table_fails_naming_the_key():
    with pytest.raises(ConfigError, match=r"task.layout.cube_region x range \[-0.44, 0.2\]"):
        _sampler("task.layout.mode=random", "task.layout.cube_region=[[-0.44,0.2],[0.0,0.1]]")
    with pytest.raises(ConfigError, match=r"task.layout.cube_region \(y\): min 0.2 must be <= max 0.1"):
        load_config(["task.layout.cube_region=[[0.0,0.1],[0.2,0.1]]"])
    with pytest.raises(ConfigError, match=r"task.arm.start_region \(z\)"):
        load_config(["task.arm.start_region=[[0,0.1],[0,0.1],[0.8,0.6]]"])


@pytest.mark.parametrize("robot", arm_names())
def test_random_starts_put_the_tip_at_the_target_pointing_down(robot):
    """Checked with Pinocchio's forward kinematics (the IK ran on MuJoCo's model)."""
    config = load_config([f"task.robot={robot}", "task.arm.start=random"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    region = np.asarray(config.task.arm.start_region)
    phases = []
    for seed in range(12):
        runner.seed(seed)
        transition = runner.reset()
        assert task.start_target is not None, "fell back to the home posture"
        assert np.all(task.start_target >= region[:, 0]) and np.all(task.start_target <= region[:, 1])
        q, dq = task.arm_state(runner.physics)
        np.testing.assert_array_equal(dq, 0.0)
        task.kinematics.update(q)
        tip, _ = task.kinematics.frame_pose(task._tip_frame)
        _, rotation = task.kinematics.frame_pose(task._center_frame)
        assert np.linalg.norm(tip - task.start_target) < 2e-3
        assert np.arccos(np.clip(-rotation[2, 2], -1, 1)) < 0.02  # pusher axis (local z) down
        phases.append(transition.info.phase)
    assert task.start_fallbacks == 0
    assert 1 in phases and len(set(phases)) >= 2  # phase 1 (above the obstacle region) is visited


def test_home_start_is_the_jittered_home():
    config = load_config(["task.arm.start=home"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    q, _ = task.arm_state(runner.physics)
    assert np.max(np.abs(q - np.asarray(config.task.arm.home))) <= config.task.arm.joint_jitter + 1e-12
    assert task.start_target is None


def test_observation_features_relative_to_the_cube_and_lane_clearance():
    """Hand-checked: the appended features against the positions in the same vector."""
    from ahrm_stack.env.layout import lane_clearance
    config = load_config(["task.observation.lane_choice=false"])  # its own test: test_layout.py
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    obs = runner.flat_observation()
    spec = load_config(["task.observation.relative=false", "task.observation.lanes=false",
                        "task.observation.lane_choice=false"])
    plain = TaskRunner(PushOffTask(spec.task), seed=0, safety=spec.safety)
    plain.reset()
    base = plain.flat_observation()
    assert base.shape == (60,) and obs.shape == (73,)
    np.testing.assert_array_equal(obs[:60], base)
    tip, cube = obs[18:21], obs[21:24]
    obstacles = np.array([obs[27 + 6 * i: 29 + 6 * i] for i in range(4)])
    np.testing.assert_allclose(obs[60:63], tip - cube)
    np.testing.assert_allclose(obs[63:71], (obstacles - cube[:2]).ravel())
    # lane clearance by hand for one simple layout: an obstacle right in the +x lane, none in -x
    t = config.task
    clearance = lane_clearance(np.zeros(2), np.array([[0.2, 0.0], [-0.1, 0.3]]), 0.025,
                               np.array([0.03, 0.03]), t.table, t.layout, (-0.1, 0.3))
    assert clearance[0] == pytest.approx(-0.055)  # overlap: strip half-width 0.025 + 0.03 in y
    # -x: the strip spans x in [-0.45, 0.105] (approach room 0.08 behind the cube's back face),
    # y in [-0.025, 0.025]; the obstacle at (-0.1, 0.3) is 0.3 - 0.03 - 0.025 = 0.245 away in y,
    # the one at (0.2, 0) 0.2 - 0.03 - 0.105 = 0.065 in x: the nearer one counts
    assert clearance[1] == pytest.approx(0.065)
    np.testing.assert_allclose(obs[71:73], lane_clearance(cube[:2], obstacles, 0.025,
                                                          np.array([0.03, 0.03]), t.table, t.layout,
                                                          config.task.observation.lane_clip))
