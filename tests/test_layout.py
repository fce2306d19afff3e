"""Layouts: validation rules, the fixed layout, and random layouts that always keep a free lane."""

import numpy as np
import pytest

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.env.layout import Layout, LayoutError, LayoutSampler, free_lanes, validate_layout


def _check(cfg, layout):
    t = cfg.task
    validate_layout(layout, t.table, t.cube, t.obstacles, t.layout)


def test_fixed_layout_keeps_the_minus_x_lane(config):
    t = config.task
    sampler = LayoutSampler(t.table, t.cube, t.obstacles, t.layout)
    half = np.asarray(t.obstacles.size[:2]) / 2
    assert free_lanes(sampler.fixed, t.cube.size / 2, half, t.table, t.layout) == ["-x"]


def test_obstacle_on_the_cube_is_rejected_with_a_clear_error():
    with pytest.raises(ConfigError, match=r"obstacle 0 at \[0\.01, 0\.0\] overlaps cube"):
        _make_sampler(load_config(["task.layout.mode=fixed",
                                   "task.obstacles.fixed_layout=[[0.01, 0.0], [0.16, -0.12]]"]))


def _make_sampler(cfg):
    t = cfg.task
    return LayoutSampler(t.table, t.cube, t.obstacles, t.layout)


def test_obstacle_off_the_table_and_blocked_lanes_are_rejected(config):
    t = config.task
    with pytest.raises(LayoutError, match="not fully on the table"):
        _check(config, Layout(np.zeros(2), np.array([[0.44, 0.0]])))
    # a wall of obstacles across both lanes
    wall = np.array([[0.12, 0.0], [-0.12, 0.0]])
    with pytest.raises(LayoutError, match="no free lane"):
        _check(config, Layout(np.zeros(2), wall))
    del t


def test_lane_geometry_by_hand(config):
    t = config.task
    half = np.asarray(t.obstacles.size[:2]) / 2
    # the -x lane is |y| <= 0.06 from x = 0.025 + approach_room (0.105) down to -0.45.
    # An obstacle centred at y = 0.09 spans y in [0.06, 0.12]: touching the strip's edge, not inside.
    touching = Layout(np.zeros(2), np.array([[-0.2, 0.09]]))
    assert "-x" in free_lanes(touching, 0.025, half, t.table, t.layout)
    inside = Layout(np.zeros(2), np.array([[-0.2, 0.089]]))
    assert "-x" not in free_lanes(inside, 0.025, half, t.table, t.layout)
    # behind the cube, the +x side of the -x lane ends at x = 0.105: an obstacle from x = 0.106 is clear
    behind = Layout(np.zeros(2), np.array([[0.136, 0.0]]))
    assert "-x" in free_lanes(behind, 0.025, half, t.table, t.layout)


def test_random_layouts_are_valid_seeded_and_varied():
    cfg = load_config(["task.layout.mode=random"])
    sampler = _make_sampler(cfg)
    layouts = [sampler.sample(np.random.RandomState(seed)) for seed in range(200)]
    for layout in layouts:
        _check(cfg, layout)
        radii = np.linalg.norm(layout.obstacle_xy - layout.cube_xy, axis=1)
        lo, hi = cfg.task.layout.radial_range
        assert np.all((radii >= lo - 1e-12) & (radii <= hi + 1e-12))
    again = sampler.sample(np.random.RandomState(7))
    np.testing.assert_array_equal(again.obstacle_xy, layouts[7].obstacle_xy)
    assert len({tuple(np.round(l.obstacle_xy.ravel(), 6)) for l in layouts}) == 200


def test_fixed_mode_jitters_only_the_cube():
    config = load_config(["task.layout.mode=fixed"])
    sampler = _make_sampler(config)
    a = sampler.sample(np.random.RandomState(0))
    b = sampler.sample(np.random.RandomState(1))
    np.testing.assert_array_equal(a.obstacle_xy, b.obstacle_xy)
    assert np.all(np.abs(a.cube_xy - config.task.cube.position) <= config.task.cube.jitter)
    assert not np.array_equal(a.cube_xy, b.cube_xy)


def test_lane_choice_by_hand(config):
    """choose_lane on hand layouts around a cube at the origin (obstacles 0.06 m square, cube
    0.05 m, approach room 0.08 m: the +x strip spans x in [-0.105, 0.45], the -x strip
    [-0.45, 0.105], both |y| <= 0.025)."""
    from ahrm_stack.env.layout import choose_lane
    t = config.task
    half = np.asarray(t.obstacles.size[:2]) / 2
    assert list(t.layout.lane_directions) == ["+x", "-x"]

    def lane(obstacles, tip=(0.0, 0.3)):
        return t.layout.lane_directions[choose_lane(Layout(np.zeros(2), np.array(obstacles)),
                                                    np.array(tip), 0.025, half, t.table, t.layout)]

    # rooms: +x 0.1 - 0.03 - 0.025 = 0.045 (the obstacle beside it); -x: the one at (0.2, 0.1)
    # is 0.065 past its end in x and 0.045 off in y, hypot 0.079; the other 0.095 off in y
    assert lane([[0.2, 0.1], [-0.2, 0.15]]) == "-x"
    assert lane([[-0.2, 0.1], [0.2, 0.15]]) == "+x"  # the mirror image
    # equal rooms: the lane whose push starts on the tip's side of the cube
    assert lane([[0.2, 0.1], [-0.2, 0.1]], tip=(-0.1, 0.0)) == "+x"
    assert lane([[0.2, 0.1], [-0.2, 0.1]], tip=(0.1, 0.0)) == "-x"
    # a blocked lane is never chosen while another is free, whatever its room
    assert lane([[0.2, 0.0], [-0.2, 0.09]]) == "-x"


def test_lane_choice_observation_is_the_scripted_plan():
    """With task.observation.lane_choice the observation ends in the one-hot of the lane the
    scripted controller plans at reset, kept through the episode."""
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask

    config = load_config(["task.observation.lane_choice=true"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    pusher = ScriptedPusher(task, config.scripted)
    seen = set()
    for seed in range(8):
        runner.seed(seed)
        runner.reset()
        pusher.reset(runner.physics)
        first = runner.flat_observation()
        expected = np.eye(2)[list(config.task.layout.lane_directions).index(pusher.lane)]
        np.testing.assert_array_equal(first[-2:], expected)
        seen.add(pusher.lane)
        for _ in range(5):
            runner.step_action(np.array([0.5, -0.5, -0.5]))
        np.testing.assert_array_equal(runner.flat_observation()[-2:], expected)
    assert seen == {"+x", "-x"}  # both lanes occur over these seeds
    assert first.shape == (75,)
