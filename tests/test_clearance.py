"""The avoid margin (task.rewards.avoid_margin): the clearance against closed forms, and f1 in the task."""

import math

import coal
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.config import load_config
from ahrm_stack.env.clearance import Clearance
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask

CUBE_HALF = np.array([0.025, 0.025, 0.025])
OBSTACLE_HALF = np.array([[0.03, 0.05, 0.04]])
EYE = np.eye(3)


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _clearance(reach: float = 1.0) -> Clearance:
    return Clearance(CUBE_HALF, OBSTACLE_HALF, pusher_radius=0.01, pusher_half_length=0.05, reach=reach)


def test_face_to_face_boxes():
    cube, _ = _clearance().distances(np.zeros(3), EYE, np.array([[0.2, 0.0, 0.0]]), EYE[None])
    assert cube == pytest.approx(0.2 - 0.025 - 0.03, abs=1e-9)


def test_cube_turned_45_degrees_meets_the_face_with_its_edge():
    cube, _ = _clearance().distances(np.zeros(3), _rot_z(math.pi / 4), np.array([[0.2, 0.0, 0.0]]), EYE[None])
    assert cube == pytest.approx(0.2 - 0.025 * math.sqrt(2) - 0.03, abs=1e-9)


def test_obstacle_turned_90_degrees_swaps_its_half_sizes():
    cube, _ = _clearance().distances(np.zeros(3), EYE, np.array([[0.2, 0.0, 0.0]]), _rot_z(math.pi / 2)[None])
    assert cube == pytest.approx(0.2 - 0.025 - 0.05, abs=1e-9)


def test_upright_pusher_beside_an_obstacle():
    # a vertical cylinder (axis = local z) 0.2 m from the obstacle's centre along y
    _, pusher = _clearance().distances(np.array([5.0, 5.0, 0.0]), EYE, np.array([[0.0, 0.2, 0.0]]), EYE[None],
                                       np.zeros(3), EYE)
    assert pusher == pytest.approx(0.2 - 0.01 - 0.05, abs=1e-6)  # GJK on a curved shape: coal's 1e-6 tolerance


def test_penetration_is_negative():
    cube, _ = _clearance().distances(np.zeros(3), EYE, np.array([[0.05, 0.0, 0.0]]), EYE[None])
    assert cube == pytest.approx(0.05 - 0.025 - 0.03, abs=1e-6)


def test_beyond_reach_the_spheres_gap_stands_in_and_is_a_lower_bound():
    position = np.array([[0.3, 0.1, 0.0]])
    exact, _ = _clearance(reach=1.0).distances(np.zeros(3), EYE, position, EYE[None])
    bound, _ = _clearance(reach=0.01).distances(np.zeros(3), EYE, position, EYE[None])
    gap = np.linalg.norm(position) - np.linalg.norm(CUBE_HALF) - np.linalg.norm(OBSTACLE_HALF)
    assert bound == pytest.approx(gap) and bound <= exact


def test_without_a_pusher_its_entry_is_infinite():
    _, pusher = _clearance().distances(np.zeros(3), EYE, np.array([[0.2, 0.0, 0.0]]), EYE[None])
    assert pusher == math.inf


coordinate = st.floats(-0.4, 0.4)


@settings(max_examples=200, deadline=None)
@given(st.tuples(coordinate, coordinate, coordinate),
       st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=1, max_size=4))
def test_axis_aligned_boxes_match_the_closed_form(cube, obstacles):
    """Separated axis-aligned boxes: the distance is the norm of the per-axis gaps (closed form);
    the smallest over the obstacles."""
    cube, obstacles = np.array(cube), np.array(obstacles)
    halves = np.repeat(OBSTACLE_HALF, len(obstacles), axis=0)
    gaps = np.maximum(np.abs(obstacles - cube) - CUBE_HALF - halves, 0.0)
    if not (gaps > 1e-4).any(axis=1).all():
        return  # touching or overlapping: no closed form here
    expected = float(np.linalg.norm(gaps, axis=1).min())
    clearance = Clearance(CUBE_HALF, halves, pusher_radius=0.01, pusher_half_length=0.05, reach=10.0)
    got, _ = clearance.distances(cube, EYE, obstacles, np.repeat(EYE[None], len(obstacles), axis=0))
    # coal stops GJK at its tolerance (DistanceRequest().gjk_tolerance, 1e-6 m): the answer is that close
    assert got == pytest.approx(expected, abs=2 * coal.DistanceRequest().gjk_tolerance)


def _place_obstacle_beside_the_cube(runner: TaskRunner, gap: float) -> None:
    """Obstacle 0 ``gap`` m from the cube's +x face (both axis-aligned), the others far away."""
    task, physics = runner.task, runner.physics
    addresses = task.addresses
    qpos = physics.data.qpos
    cube = qpos[addresses.cube_qpos[:3]].copy()
    qpos[addresses.cube_qpos[3:7]] = [1.0, 0.0, 0.0, 0.0]
    for i, rows in enumerate(addresses.obstacle_qpos):
        qpos[rows[3:7]] = [1.0, 0.0, 0.0, 0.0]
        if i == 0:
            offset = task.config.cube.size / 2 + task.config.obstacles.size[0] / 2 + gap
            qpos[rows[:2]] = [cube[0] + offset, cube[1]]
        else:
            qpos[rows[:2]] = [-0.4, 0.3 - 0.3 * i]  # a corner of the table, away from cube and arm
    physics.forward()


@pytest.mark.parametrize("margin, gap, f1", [(0.02, 0.01, -1.0), (0.02, 0.03, 1.0), (0.0, 0.01, 1.0)])
def test_the_margin_sets_f1_without_a_touch(margin, gap, f1):
    cfg = load_config([f"task.rewards.avoid_margin={margin}", "task.rewards.obstacle_speed_threshold=1000.0"])
    runner = TaskRunner(PushOffTask(cfg.task), seed=0)
    runner.reset()
    _place_obstacle_beside_the_cube(runner, gap)
    info, _, _ = runner.step_only(np.zeros(6))
    assert not info.touched
    assert info.f[0] == f1 and info.g[0] == (f1 - 1.0) / 2
    if margin > 0:  # the cube has not moved: the clearance is the placed gap (or the pusher's, if nearer)
        assert info.clearance <= gap + 1e-4
    else:
        assert info.clearance == math.inf  # not measured at the spec's f1
