"""The planner-free start curriculum's starts (issue 56): ``task.arm.near_cube.bearing: behind_free``
places a near-cube start behind the cube for a lane drawn uniformly among the free ones
(:func:`~ahrm_stack.env.layout.free_lanes`), with no call to the planner's lane choice."""

from __future__ import annotations

import numpy as np

from ahrm_stack.config import load_config
from ahrm_stack.env import task as task_module
from ahrm_stack.env.layout import free_lanes
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask


def _starts(bearing: str, episodes: int) -> list[tuple[str, list[str]]]:
    """(the lane the start is behind, the free lanes) per episode at the curriculum's level 0."""
    config = load_config(["profile=scratch-own-lane", f"task.arm.near_cube.bearing={bearing}"])
    task = PushOffTask(config.task)
    task.near_cube_share = 1.0  # level 0: every start near the cube
    runner = TaskRunner(task, seed=0, safety=config.safety)
    out = []
    for seed in range(episodes):
        runner.seed(500 + seed)
        runner.reset()
        assert task.start_target is not None
        cube = np.asarray(task.layout.cube_xy)
        offset = task.start_target[:2] - cube
        spread = np.deg2rad(config.task.arm.near_cube.behind_spread_deg)
        # behind a +x lane: the tip on the -x side, within the spread of the -x axis
        lane = "+x" if offset[0] < 0 else "-x"
        angle = np.arctan2(abs(offset[1]), abs(offset[0]))
        assert angle <= spread + 1e-9, (seed, np.rad2deg(angle))
        free = free_lanes(task.layout, config.task.cube.size / 2, task._obstacle_half_sizes[0, :2],
                          config.task.table, config.task.layout)
        out.append((lane, free))
    return out


def test_behind_free_starts_behind_a_free_lane_drawn_without_the_planner(monkeypatch):
    def no_planner(*args, **kwargs):
        raise AssertionError("behind_free must not ask the planner")

    monkeypatch.setattr(task_module, "choose_lane", no_planner)
    starts = _starts("behind_free", 60)
    assert all(lane in free for lane, free in starts if free)
    both = [lane for lane, free in starts if len(free) == 2]
    assert len(both) >= 10
    share = both.count("+x") / len(both)
    assert 0.2 <= share <= 0.8, share  # uniform between the two free lanes, not the planner's one
