"""The distance rows' fast path gives, bit for bit, the rows of the routine it replaced.

``tests/distance_rows_reference.py`` keeps that routine (one ``signed_distance`` per candidate
pair, a fresh coal result each, the rows assembled pair by pair). On random configurations of both
arms, random obstacle poses crowding the arm and every combination of the row switches, both give
the same matrix, bounds, names and number of queries (less the obstacle candidates that could not
be among the ``max_obstacle_rows`` nearest, which the fast path leaves unmeasured); the filter gives
the same commands with either; the self-collision pre-test's bound never exceeds the distance; and
when coal fails (raises, answers NaN) the fast path takes the
same guarded answer. One prepared coal query (functor and result reused) answers what
``signed_distance`` answers, bit for bit.
"""

from __future__ import annotations

import coal
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from distance_rows_reference import ReferenceDistanceLimit
from ahrm_stack.config import load_config
from ahrm_stack.env.control_step import make_task_filter
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.kinematics import scene as scene_module
from ahrm_stack.kinematics.scene import GUARD, capsule_distance, placed_signed_distance, signed_distance
from ahrm_stack.safety.constraints import ArmSnapshot, DistanceLimit
from ahrm_stack.safety.constraints.distance import _segment_bound


class Pair:
    """The fast and the reference distance rows of one arm, each on its own kinematics snapshot,
    over one collision scene."""

    def __init__(self, robot: str) -> None:
        config = load_config([f"task.robot={robot}"])
        self.runner = TaskRunner(PushOffTask(config.task), seed=0)
        self.runner.reset()
        task = self.runner.task
        self.task, self.config = task, config
        self.scene = task.make_collision_scene(self.runner.physics)
        self.filter = make_task_filter(task, config.safety, scene=self.scene)  # places the scene's parts at q = 0
        self.fast: DistanceLimit = self.filter.distances
        self.snapshot = self.filter._snapshot
        kin = task.kinematics
        identity = kin.model.nq == task.robot.num_joints and not len(kin.joint_map.continuous)
        self.reference_snapshot = ArmSnapshot(kin.model, kin.base, None if identity else kin.configuration)
        self.reference_snapshot.update(np.zeros(task.robot.num_joints))
        safety = config.safety
        frames = {name: kin.frame_id(name) for name in self.scene.robot if name != "pusher"}
        frames["pusher"] = kin.element_frame_id(task.pusher.tip_site)
        self.reference = ReferenceDistanceLimit(
            self.scene, self.reference_snapshot, frames, safety.obstacle_safe_distance,
            safety.obstacle_activation_distance, safety.max_obstacle_rows, self.filter.horizon,
            self.fast.self_pairs)
        self.robot = task.robot

    def place_obstacles(self, rng: np.random.Generator, q: np.ndarray) -> None:
        """Each obstacle near a random part of the arm at ``q`` (up to 15 cm off its origin),
        turned at random."""
        self.reference_snapshot.update(q)
        centers, _ = self.reference_snapshot.placements(self.reference._part_frames)
        count = len(self.fast.object_names) - 1
        rotations = np.array([_rotation(rng) for _ in range(count)])
        positions = centers[rng.integers(len(centers), size=count)] + rng.uniform(-0.15, 0.15, (count, 3))
        self.scene.update_objects(np.array([3.0, 3.0, 0.0]), np.eye(3), positions, rotations)

    def both(self, q: np.ndarray, table: bool, obstacles: bool, self_collision: bool):
        self.snapshot.update(q)
        self.reference_snapshot.update(q)
        fast = self.fast.rows(self.snapshot, table, obstacles, self_collision)
        reference = self.reference.rows(self.reference_snapshot, table, obstacles, self_collision)
        return fast, reference


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.fixture(scope="module", params=["jaco", "j2s6s200"])
def pair(request) -> Pair:
    return Pair(request.param)


def _configuration(robot, rng) -> np.ndarray:
    """Joint angles within the limits widened by 0.3 rad (continuous joints: any angle)."""
    return rng.uniform(np.where(robot.limited, robot.position_lower - 0.3, -np.pi),
                       np.where(robot.limited, robot.position_upper + 0.3, np.pi))


def _without_rows_beyond_reach(pair, q, reference, fast):
    """``reference`` less its self rows missing from ``fast`` (see :func:`_beyond_reach_dropped`)."""
    return _beyond_reach_dropped(pair.fast, pair.reference, pair.reference_snapshot, q, reference, fast)


def _beyond_reach_dropped(limit, reference_limit, reference_snapshot, q, reference, fast):
    """``reference`` less its self rows missing from ``fast``, each checked (independently of the
    segment bound) to join two parts whose enclosing capsules are farther apart than the
    activation distance."""
    reference_snapshot.update(q)
    centers, rotations = reference_snapshot.placements(reference_limit._part_frames)
    index = {name: k for k, name in enumerate(limit.part_names)}
    keep = []
    for k, name in enumerate(reference.names):
        if name in fast.names:
            keep.append(k)
            continue
        assert name.startswith("self:"), name
        a, b = (index[part] for part in name[len("self:"):].split("/"))
        (half_a, radius_a), (half_b, radius_b) = limit._half_radius[a], limit._half_radius[b]
        d = capsule_distance(centers[a], rotations[a][:, 2], half_a, radius_a,
                             centers[b], rotations[b][:, 2], half_b, radius_b)[0]
        assert d > limit.activation_distance, name
    return type(reference)(reference.matrix[keep], reference.bound[keep], tuple(reference.names[k] for k in keep))


def _assert_same(fast, reference) -> None:
    assert fast.names == reference.names
    assert fast.matrix.shape == reference.matrix.shape
    np.testing.assert_array_equal(fast.matrix, reference.matrix)
    np.testing.assert_array_equal(fast.bound, reference.bound)


SHAPES = {"capsule": lambda: coal.Capsule(0.04, 0.2), "cylinder": lambda: coal.Cylinder(0.02, 0.15),
          "box": lambda: coal.Box(0.06, 0.08, 0.1)}


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), a=st.sampled_from(["capsule", "cylinder"]),
       b=st.sampled_from(list(SHAPES)), spread=st.sampled_from([0.02, 0.1, 0.3]))
def test_a_prepared_query_answers_what_signed_distance_answers(seed, a, b, spread):
    """One functor and one result reused over 30 placements (separated, touching, overlapping):
    each answer is signed_distance's, bit for bit, or None where that one took its guarded path."""
    rng = np.random.default_rng(seed)
    first, second = coal.CollisionObject(SHAPES[a]()), coal.CollisionObject(SHAPES[b]())
    compute = coal.ComputeDistance(first.collisionGeometry(), second.collisionGeometry())
    result = coal.DistanceResult()
    for _ in range(30):
        for obj in (first, second):
            obj.setRotation(_rotation(rng))
            obj.setTranslation(rng.uniform(-spread, spread, 3))
        normals = GUARD.normals
        d, point_a, point_b, normal, exact = signed_distance(first, second)
        answer = placed_signed_distance(compute, result, first.getTransform(), second.getTransform(),
                                        first.getTranslation().tolist(), second.getTranslation().tolist())
        if answer is None:
            assert not exact or GUARD.normals > normals
        else:
            assert answer == (d, *point_a.tolist(), *point_b.tolist(), *normal.tolist())


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), table=st.booleans(), obstacles=st.booleans(),
       self_collision=st.booleans())
def test_the_fast_rows_are_the_reference_rows(pair, seed, table, obstacles, self_collision):
    rng = np.random.default_rng(seed)
    q = _configuration(pair.robot, rng)
    pair.place_obstacles(rng, q)
    fast, reference = pair.both(q, table, obstacles, self_collision)
    _assert_same(fast, reference)
    # the same queries, less the obstacle candidates that could not be among the nearest and
    # the self-collision candidates whose segment bound exceeds the activation distance
    assert pair.fast.last_queries <= pair.reference.last_queries
    if not (obstacles or self_collision):
        assert pair.fast.last_queries == pair.reference.last_queries


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), keep=st.integers(1, 4))
def test_pruned_obstacle_candidates_could_not_be_among_the_nearest(pair, seed, keep):
    """With few obstacle rows kept, many candidates are left unmeasured once the nearest are
    found; the rows stay the reference's (which measures every candidate), bit for bit, and every
    obstacle pair within the activation distance that got no row is, by ``signed_distance`` on the
    scene's own objects, no nearer than the farthest obstacle row kept."""
    rng = np.random.default_rng(seed)
    q = _configuration(pair.robot, rng)
    pair.place_obstacles(rng, q)
    saved = pair.fast.max_obstacle_rows
    try:
        pair.fast.max_obstacle_rows = pair.reference.max_obstacle_rows = keep
        fast, reference = pair.both(q, True, True, False)
    finally:
        pair.fast.max_obstacle_rows = pair.reference.max_obstacle_rows = saved
    _assert_same(fast, reference)
    assert pair.fast.last_queries <= pair.reference.last_queries
    kept = [k for k, name in enumerate(fast.names) if name.startswith("obstacle:")]
    assert len(kept) <= keep
    if len(kept) == keep:  # independent: every robot-obstacle distance, measured on the scene
        scene = pair.scene
        pair.reference_snapshot.update(q)
        centers, rotations = pair.reference_snapshot.placements(pair.reference._part_frames)
        farthest = max(fast.bound[kept]) + pair.fast.safe_distance
        for k, name in enumerate(pair.fast.part_names):
            if name not in scene.moving_parts:
                continue
            scene.robot[name].setRotation(rotations[k])
            scene.robot[name].setTranslation(centers[k])
            for obstacle in pair.fast.object_names[1:]:
                if f"obstacle:{name}/{obstacle}" not in fast.names:
                    d = signed_distance(scene.robot[name], scene.environment[obstacle])[0]
                    assert d >= farthest - 1e-9


def test_crowded_poses_give_many_rows_of_every_kind(pair):
    """The comparison above is not vacuous: over 40 draws it sees table, obstacle and self rows,
    obstacle rows cut to ``max_obstacle_rows``, and coal's pairs as well as the closed form."""
    rng = np.random.default_rng(7)
    kinds, most, queries, pruned = set(), 0, 0, 0
    for _ in range(40):
        q = _configuration(pair.robot, rng)
        pair.place_obstacles(rng, q)
        fast, reference = pair.both(q, True, True, True)
        _assert_same(fast, reference)
        kinds |= {name.split(":")[0] for name in fast.names}
        most = max(most, sum(name.startswith("obstacle:") for name in fast.names))
        queries += pair.fast.last_queries
        pruned += pair.reference.last_queries - pair.fast.last_queries
    assert kinds == {"table", "obstacle", "self"}
    assert most == pair.fast.max_obstacle_rows and queries > 40 * most
    assert pruned > 0  # the pruning of obstacle candidates beyond the nearest was exercised


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cartesian=st.booleans())
def test_the_filter_commands_are_the_reference_filters(pair, seed, cartesian):
    """The same commands, statuses and active rows from the filter with the fast rows and with
    the reference rows, over a short random request stream with the obstacle rows on."""
    rng = np.random.default_rng(seed)
    robot = pair.robot
    q = _configuration(robot, rng)
    pair.place_obstacles(rng, q)
    fast, reference = pair.filter, make_task_filter(pair.task, pair.config.safety, scene=pair.scene)
    reference.distances = pair.reference
    reference._snapshot = pair.reference_snapshot
    fast.reset()
    reference.reset()
    for _ in range(4):
        q = q + rng.uniform(-0.05, 0.05, q.shape)
        dq = rng.uniform(-0.5, 0.5, q.shape) * robot.velocity_limit
        request = rng.uniform(-0.3, 0.3, 3) if cartesian else rng.uniform(-1.2, 1.2, q.shape) * robot.velocity_limit
        call = "cartesian" if cartesian else "__call__"
        got = getattr(fast, call)(q, dq, request, obstacles=True)
        want = getattr(reference, call)(q, dq, request, obstacles=True)
        np.testing.assert_array_equal(got.command, want.command)
        assert (got.status, got.active, got.violated, got.modified) == \
            (want.status, want.active, want.violated, want.modified)
        assert got.worst_margin == want.worst_margin or np.isnan(got.worst_margin) and np.isnan(want.worst_margin)
        assert fast.last_rows == reference.last_rows


@pytest.mark.parametrize("failure", ["raise", "nan", "both"])
def test_a_failing_query_takes_the_guarded_answer(pair, monkeypatch, failure):
    """A prepared query that raises or answers NaN is asked again through ``signed_distance``:
    the rows stay the reference's (coal itself answering there), and when coal fails there too
    ("both") both routines give the same conservative bound, counted in GUARD, for every pair they
    both query. (The reference also queries self pairs that the fast path's segment bound puts
    beyond the activation distance; with coal failing, the bounding balls' answer it gets can be
    close enough for a row. Those rows alone may be missing from the fast path's, and each is
    checked to be beyond reach by the closed-form distance of the parts' enclosing capsules.)"""
    def broken(*args):
        if failure == "nan":
            return float("nan")
        raise RuntimeError("std::logic_error: simulated")

    fast = pair.fast
    monkeypatch.setattr(fast, "_object_compute", [[broken] * len(row) for row in fast._object_compute])
    monkeypatch.setattr(fast, "_self_compute", [None if c is None else broken for c in fast._self_compute])
    if failure == "both":
        monkeypatch.setattr(scene_module.coal, "distance", broken)
    rng = np.random.default_rng(11)
    failures, seen = GUARD.failures, 0
    for _ in range(10):
        q = _configuration(pair.robot, rng)
        pair.place_obstacles(rng, q)
        pair.snapshot.update(q)
        pair.reference_snapshot.update(q)
        before = GUARD.failures
        fast_rows = fast.rows(pair.snapshot, True, True, True)
        middle = GUARD.failures
        reference_rows = pair.reference.rows(pair.reference_snapshot, True, True, True)
        if failure == "both":
            reference_rows = _without_rows_beyond_reach(pair, q, reference_rows, fast_rows)
        _assert_same(fast_rows, reference_rows)
        # the same queries guarded, less the obstacle candidates pruned (never among the nearest)
        assert middle - before <= GUARD.failures - middle
        assert (middle - before == GUARD.failures - middle) or fast.last_queries < pair.reference.last_queries
        if failure != "both":
            assert middle == before
        seen += len(fast_rows.names)
    assert seen > 0
    assert (GUARD.failures > failures) == (failure == "both")



@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), spread=st.sampled_from([0.05, 0.2, 0.6]),
       cylinder=st.booleans())
def test_the_segment_bound_never_exceeds_the_distance(seed, spread, cylinder):
    """``_segment_bound`` of two capsules (or a cylinder and a capsule, as the pusher and a link)
    is at most their signed distance, by coal on the placed shapes; and it is not vacuous: for
    separated, long shapes it is often within 5 cm of the distance."""
    rng = np.random.default_rng(seed)
    close = 0
    for _ in range(20):
        half = rng.uniform(0.0, 0.2, 2)
        radius = rng.uniform(0.01, 0.06, 2)
        first = coal.CollisionObject(coal.Cylinder(radius[0], 2 * half[0]) if cylinder
                                     else coal.Capsule(radius[0], 2 * half[0]))
        second = coal.CollisionObject(coal.Capsule(radius[1], 2 * half[1]))
        centers, axes = [], []
        for obj in (first, second):
            rotation = _rotation(rng)
            center = rng.uniform(-spread, spread, 3)
            obj.setRotation(rotation)
            obj.setTranslation(center)
            centers.append(center.tolist())
            axes.append(rotation[:, 2].tolist())
        bound = _segment_bound(centers[0], axes[0], half[0], radius[0], centers[1], axes[1], half[1], radius[1])
        d = signed_distance(first, second)[0]
        assert bound <= d + 1e-7
        close += d > 0 and d - bound < 0.05
    if spread == 0.6:
        assert close > 0


def test_bad_arguments_are_refused_naming_what_and_the_edges_are_accepted(pair):
    """DistanceLimit's definition checks, each refusal one ConstraintDefinitionError naming the
    value, and each limit value itself accepted (a safe distance of 0, no obstacle row,
    an activation distance just above the safe one)."""
    from ahrm_stack.safety.constraints import ConstraintDefinitionError

    scene, kin = pair.scene, pair.task.kinematics
    identity = kin.model.nq == pair.robot.num_joints and not len(kin.joint_map.continuous)
    snapshot = ArmSnapshot(kin.model, kin.base, None if identity else kin.configuration)  # its own
    snapshot.update(np.zeros(pair.robot.num_joints))
    frames = {name: pair.task.kinematics.frame_id(name) for name in scene.robot if name != "pusher"}
    frames["pusher"] = pair.task.kinematics.element_frame_id(pair.task.pusher.tip_site)
    good = dict(safe_distance=0.02, activation_distance=0.1, max_obstacle_rows=4, horizon=0.05)

    def make(frames=frames, self_pairs=(), **changes):
        return DistanceLimit(scene, snapshot, frames, **{**good, **changes}, self_pairs=self_pairs)

    for changes, message in (
            (dict(safe_distance=-0.01), "safe distance must be finite and >= 0 m, got -0.01"),
            (dict(safe_distance=float("nan")), "safe distance must be finite"),
            (dict(activation_distance=0.02), r"activation distance \(0.02 m\) must exceed the safe distance"),
            (dict(activation_distance=float("inf")), "activation distance"),
            (dict(max_obstacle_rows=-1), "max_obstacle_rows must be >= 0, got -1"),
            (dict(horizon=0.0), "distance horizon must be finite and > 0 s, got 0.0"),
            (dict(horizon=float("inf")), "distance horizon must be finite")):
        with pytest.raises(ConstraintDefinitionError, match=message):
            make(**changes)
    part = next(iter(scene.robot))
    with pytest.raises(ConstraintDefinitionError, match=rf"no frame given for robot part\(s\) \['{part}'\]"):
        make(frames={k: v for k, v in frames.items() if k != part})
    names = list(scene.robot)
    with pytest.raises(ConstraintDefinitionError, match="'elbow' is not a robot part of the scene"):
        make(self_pairs=[(names[0], "elbow")])
    for bad in ([(names[0], names[0])], [(names[0], names[3]), (names[3], names[0])],
                [(names[0], names[3]), (names[0], names[3])]):
        with pytest.raises(ConstraintDefinitionError, match="repeats a part or a pair"):
            make(self_pairs=bad)
    edge = make(safe_distance=0.0, activation_distance=1e-6, max_obstacle_rows=0,
                self_pairs=[(names[0], names[3])])
    assert edge.safe_distance == 0.0 and edge.max_obstacle_rows == 0 and edge.self_pairs == ((names[0], names[3]),)


def test_the_segment_bound_of_perpendicular_segments_is_their_distance():
    """A closed form: segment A on the z axis (half length 1) and segment B parallel to x (half
    length 2) centred 5 above A's centre are 4 apart (A's top end to B's middle); the bound is
    exact here, whichever is first, and is the larger of its two one-sided bounds (the smaller,
    2, is what B's end-to-centre reach alone would give)."""
    z, x = [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]
    assert _segment_bound([0, 0, 0], z, 1.0, 0.1, [0, 0, 5], x, 2.0, 0.2) == pytest.approx(4 - 0.3)
    assert _segment_bound([0, 0, 5], x, 2.0, 0.2, [0, 0, 0], z, 1.0, 0.1) == pytest.approx(4 - 0.3)


def _limit_and_reference(pair, scene, self_pairs, max_obstacle_rows=None):
    """A DistanceLimit and the reference over ``scene`` (a copy of the pair's, some objects left
    out), each on its own snapshot of the pair's kinematics, with the pair's safety settings."""
    kin, safety = pair.task.kinematics, pair.config.safety
    scene.kinematics.update(np.zeros(pair.robot.num_joints))  # the parts where q = 0 puts them, as
    scene.update_robot()  # the filter places them before it builds its limit (other tests move them)
    identity = kin.model.nq == pair.robot.num_joints and not len(kin.joint_map.continuous)
    snapshots = [ArmSnapshot(kin.model, kin.base, None if identity else kin.configuration) for _ in range(2)]
    for snapshot in snapshots:
        snapshot.update(np.zeros(pair.robot.num_joints))
    frames = {name: kin.frame_id(name) for name in scene.robot if name != "pusher"}
    frames["pusher"] = kin.element_frame_id(pair.task.pusher.tip_site)
    keep = safety.max_obstacle_rows if max_obstacle_rows is None else max_obstacle_rows
    args = (frames, safety.obstacle_safe_distance, safety.obstacle_activation_distance, keep, pair.filter.horizon)
    return (DistanceLimit(scene, snapshots[0], *args, self_pairs=self_pairs), snapshots[0],
            ReferenceDistanceLimit(scene, snapshots[1], *args, self_pairs), snapshots[1])


def test_one_obstacle_and_one_self_pair_still_give_rows(pair):
    """The edges of "is there anything to ask": a scene with a single obstacle and a limit with a
    single self-collision pair give the reference's rows, obstacle and self rows among them."""
    import copy

    scene = copy.copy(pair.scene)
    scene.environment = {name: obj for name, obj in pair.scene.environment.items()
                         if not name.startswith("obstacle_") or name == "obstacle_0"}
    assert [n for n in scene.environment if n.startswith("obstacle_")] == ["obstacle_0"]
    rng = np.random.default_rng(3)
    seen = set()
    for self_pair in pair.fast.self_pairs[:6]:
        fast, snapshot, reference, reference_snapshot = _limit_and_reference(pair, scene, [self_pair])
        for _ in range(15):
            q = _configuration(pair.robot, rng)
            reference_snapshot.update(q)
            centers, _ = reference_snapshot.placements(reference._part_frames)
            near = centers[rng.integers(len(centers))] + rng.uniform(-0.05, 0.05, 3)
            scene.environment["obstacle_0"].setTranslation(near)
            snapshot.update(q)
            mine = fast.rows(snapshot, True, True, True)
            theirs = reference.rows(reference_snapshot, True, True, True)
            _assert_same(mine, _beyond_reach_dropped(fast, reference, reference_snapshot, q, theirs, mine))
            seen |= {name.split(":")[0] for name in mine.names}
    assert seen == {"table", "obstacle", "self"}



def test_each_kind_of_pruning_saves_queries_and_the_defaults_are_table_and_obstacles(pair, monkeypatch):
    """Over 40 crowded draws: the obstacle candidates beyond the nearest found and the self pairs
    beyond the segment bound are each left unmeasured (fewer queries than the reference, which
    measures every candidate of the bounding test, on each kind alone), with the reference's
    rows; ``rows(snapshot)`` is the table and obstacle rows without the self rows; ``max_rows``
    counts exactly the kinds asked for."""
    rng = np.random.default_rng(11)
    saved = {"obstacles": 0, "self": 0}
    limit = pair.fast
    guarded = []  # the prepared query answers every one here: none falls back to signed_distance
    monkeypatch.setattr(limit, "_guarded", lambda *args, **kwargs: guarded.append(args) or pytest.fail("guarded"))
    for _ in range(40):
        q = _configuration(pair.robot, rng)
        pair.place_obstacles(rng, q)
        for kind, flags in (("obstacles", (False, True, False)), ("self", (False, False, True))):
            fast, reference = pair.both(q, *flags)
            _assert_same(fast, _without_rows_beyond_reach(pair, q, reference, fast))
            saved[kind] += pair.reference.last_queries - limit.last_queries
            assert limit.last_queries >= len(fast.names)  # every row took a query
        assert limit.rows(pair.snapshot).names == limit.rows(pair.snapshot, True, True, False).names
    assert saved["obstacles"] > 0 and saved["self"] > 0
    assert not guarded
    kinds = {name.split(":")[0] for name in limit.rows(pair.snapshot).names}
    moving, pairs = len(limit.scene.moving_parts), len(limit.self_pairs)
    assert limit.max_rows(True, True) == moving + limit.max_obstacle_rows
    assert limit.max_rows(False, False) == 0 and limit.max_rows(False, False, True) == pairs
    assert limit.max_rows(True, False) == moving and limit.max_rows(False, True) == limit.max_obstacle_rows
    assert "self" not in kinds


def test_a_scene_without_a_table_is_refused_and_a_new_limit_has_asked_nothing(pair):
    import copy

    from ahrm_stack.safety.constraints import ConstraintDefinitionError

    fast, *_ = _limit_and_reference(pair, pair.scene, ())
    assert fast.last_queries == 0
    scene = copy.copy(pair.scene)
    scene.environment = {name: obj for name, obj in pair.scene.environment.items() if name != "table"}
    with pytest.raises(ConstraintDefinitionError, match="the collision scene has no 'table'"):
        _limit_and_reference(pair, scene, ())
