"""The filter's fast path (``SafetyFilter._filter_fast``: every input finite and sane, the per-joint
work in plain floats, the rows written into a preallocated work space) gives, bit for bit, what its
general path (``SafetyFilter._filter_general``, the routine before it, which every other input still
takes) gives: the same command, status, active and violated constraints, ``modified``, worst margin,
rows and stored previous command, in joint and Cartesian mode, with and without a given previous
command, with the table/workspace rows alone, with the default distance rows and with obstacle rows
in a crowded scene, on states within, near and past the joint limits and requests beyond the
velocity limits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.config import load_config
from ahrm_stack.env.control_step import make_task_filter
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety.filter import SANE


class Filters:
    """Filters of one arm with three row sets over one collision scene whose obstacles can be
    moved next to the arm."""

    def __init__(self, robot: str) -> None:
        config = load_config([f"task.robot={robot}"])
        runner = TaskRunner(PushOffTask(config.task), seed=0)
        runner.reset()
        self.task = runner.task
        self.robot = self.task.robot
        self.scene = self.task.make_collision_scene(runner.physics)
        safety = config.safety
        self.filters = {
            "table+ws": make_task_filter(self.task, dataclasses.replace(
                safety, table_distance_rows=False, self_collision_rows=False)),
            "default": make_task_filter(self.task, safety, scene=self.scene),
        }
        self.half = np.asarray(config.task.obstacles.size) / 2

    def crowd(self, rng: np.random.Generator, q: np.ndarray) -> None:
        """The obstacles within 12 cm of the pusher tip at ``q``, turned about z at random."""
        safety = self.filters["default"]
        safety._snapshot.update(q)
        tip = safety._snapshot.positions([safety._frames[0]])[0]
        count = len(safety.distances.object_names) - 1
        centers = tip + rng.uniform(-0.12, 0.12, (count, 3))
        angles = rng.uniform(-np.pi, np.pi, count)
        rotations = np.array([[[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
                              for a in angles])
        self.scene.update_objects(np.array([3.0, 3.0, 0.0]), np.eye(3), centers, rotations)


@pytest.fixture(scope="module", params=["jaco", "j2s6s200"])
def filters(request) -> Filters:
    return Filters(request.param)


def _state(robot, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Joint angles within the limits widened by 0.1 rad (some past them, some on them), joint
    velocities, a joint request up to 1.5 x the velocity limits (some joints at 0), a previous
    command within the limits."""
    limit = robot.velocity_limit
    lower = np.where(robot.limited, robot.position_lower - 0.1, -np.pi)
    upper = np.where(robot.limited, robot.position_upper + 0.1, np.pi)
    q = rng.uniform(lower, upper)
    edge = rng.random(q.shape) < 0.2
    q = np.where(edge & robot.limited, np.where(rng.random(q.shape) < 0.5, robot.position_lower,
                                                 robot.position_upper), q)
    dq = rng.uniform(-1, 1, q.shape) * limit
    u_nom = rng.uniform(-1.5, 1.5, q.shape) * limit * (rng.random(q.shape) < 0.9)
    previous = rng.uniform(-1, 1, q.shape) * limit
    return q, dq, u_nom, previous


def _both(safety, q, dq, request, previous, given_previous, cartesian, obstacles):
    """The fast and the general path's results from the same stored previous command, and the
    previous command each leaves."""
    outcomes = []
    for general in (False, True):
        safety._previous = previous.copy()
        u_prev = previous.copy() if given_previous else None
        if general:
            result = safety._filter_general(q, dq, request, cartesian, obstacles, u_prev)
        else:
            result = (safety.cartesian if cartesian else safety)(q, dq, request, obstacles=obstacles, u_prev=u_prev)
        outcomes.append((result, safety.last_rows, safety.previous_command))
    return outcomes


def _assert_same(fast, general) -> None:
    (got, got_rows, got_previous), (want, want_rows, want_previous) = fast, general
    np.testing.assert_array_equal(got.command, want.command)
    assert (got.status, got.active, got.violated, got.modified, got.fallback) == \
        (want.status, want.active, want.violated, want.modified, want.fallback)
    assert got.worst_margin == want.worst_margin
    assert got_rows == want_rows
    np.testing.assert_array_equal(got_previous, want_previous)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.sampled_from(["table+ws", "default", "obstacles"]),
       cartesian=st.booleans(), given_previous=st.booleans())
def test_the_fast_path_gives_what_the_general_path_gives(filters, seed, rows, cartesian, given_previous):
    rng = np.random.default_rng(seed)
    robot = filters.robot
    obstacles = rows == "obstacles"
    safety = filters.filters["table+ws" if rows == "table+ws" else "default"]
    for _ in range(4):
        q, dq, u_nom, previous = _state(robot, rng)
        if obstacles:
            filters.crowd(rng, q)
        request = rng.uniform(-0.6, 0.6, 3) if cartesian else u_nom
        _assert_same(*_both(safety, q, dq, request, previous, given_previous, cartesian, obstacles))


def test_the_comparison_exercises_the_fast_path_and_every_outcome(filters, monkeypatch):
    """Over 150 draws (a fifth of the joints on or past a limit) the fast path answers many calls
    itself (the general path takes those where a position bound is out of reach), and the draws
    give active hard bounds, active and violated coupled rows, obstacle rows and solver fallbacks."""
    safety = filters.filters["default"]
    general_calls = []
    original = safety._filter_general

    def counted(*args):
        general_calls.append(1)
        return original(*args)

    rng = np.random.default_rng(3)
    fast_answers, seen = 0, set()
    for k in range(150):
        q, dq, u_nom, previous = _state(filters.robot, rng)
        filters.crowd(rng, q)
        cartesian = k % 3 == 0
        request = rng.uniform(-0.6, 0.6, 3) if cartesian else u_nom
        monkeypatch.setattr(safety, "_filter_general", counted)
        before = len(general_calls)
        safety._previous = previous.copy()
        result = (safety.cartesian if cartesian else safety)(q, dq, request, obstacles=True)
        fast_answers += len(general_calls) == before
        monkeypatch.setattr(safety, "_filter_general", original)
        _assert_same(*_both(safety, q, dq, request, previous, False, cartesian, True))
        seen |= {name.split("[")[0].split(":")[0] for name in result.active}
        seen |= {"violated"} if result.violated else set()
        seen |= {"fallback"} if result.fallback else set()
    assert fast_answers >= 50
    assert {"velocity", "acceleration", "position", "obstacle"} <= seen
    assert {"violated", "fallback"} & seen


def test_absurd_or_non_finite_inputs_take_the_general_path(filters):
    """Inputs of magnitude SANE or more, NaN or inf never reach the fast path, whose float
    arithmetic assumes finite, sane values; the general path answers them as before."""
    safety = filters.filters["table+ws"]
    nv = filters.robot.num_joints
    calls = []
    original = safety._filter_general
    safety._filter_general = lambda *args: calls.append(1) or original(*args)
    try:
        for bad in (np.nan, np.inf, -np.inf, SANE, -2 * SANE):
            for position in range(4):
                inputs = [np.zeros(nv), np.zeros(nv), np.zeros(nv), np.zeros(nv)]
                inputs[position][1] = bad
                before = len(calls)
                result = safety(inputs[0], inputs[1], inputs[2], u_prev=inputs[3])
                assert len(calls) == before + 1
                assert np.all(np.isfinite(result.command))
        robot = filters.robot
        middle = np.where(robot.limited, (np.where(robot.limited, robot.position_lower, 0.0)
                                          + np.where(robot.limited, robot.position_upper, 0.0)) / 2, 0.0)
        result = safety(middle, np.zeros(nv), np.full(nv, 0.1 * SANE))  # large but sane: the fast path
        assert len(calls) == 20 and result.modified
        assert np.all(np.abs(result.command) <= np.minimum(safety.acceleration.step, safety.velocity.limit))
    finally:
        del safety._filter_general


def test_the_work_space_helpers_give_the_numbers_of_the_allocating_ones(filters):
    """``ArmSnapshot.place``/``world_rotation``/``positions_into`` give :meth:`placements`' and
    :meth:`positions`' numbers bit for bit, and ``CoordinateRows.write`` gives :meth:`rows`'."""
    from ahrm_stack.safety.constraints import ControlPoints

    safety = filters.filters["default"]
    snapshot, distances = safety._snapshot, safety.distances
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = _state(filters.robot, rng)[0]
        snapshot.update(q)
        frames = distances._part_frames
        centers, rotations = snapshot.placements(frames)
        out = np.empty((len(frames), 3))
        placed = snapshot.place(frames, out)
        np.testing.assert_array_equal(out, centers)
        for k, local in enumerate(placed):
            np.testing.assert_array_equal(snapshot.world_rotation(local), rotations[k])
        points = np.empty((2, 3))
        snapshot.positions_into(safety._frames, points)
        np.testing.assert_array_equal(points, snapshot.positions(safety._frames))
        jacobians = np.concatenate([snapshot.jacobian(f)[:3] for f in safety._frames])
        rows = safety._point_rows.rows(ControlPoints(safety._point_rows.points, points.ravel(), jacobians))
        matrix, bound = np.empty_like(rows.matrix), np.empty_like(rows.bound)
        safety._point_rows.write(jacobians, points.ravel(), matrix, bound)
        np.testing.assert_array_equal(matrix, rows.matrix)
        np.testing.assert_array_equal(bound, rows.bound)
