"""The QP safety filter (spec §5).

* For any input — joints at and beyond their limits, huge and tiny requests, NaN and inf, infeasible
  combinations — the command is finite and within every hard bound (velocity, acceleration,
  position) to 1e-9, for both solvers (hypothesis, > 10^5 generated cases in all).
* The QP is the spec's QP: with the coupled rows off, or not binding, it equals the analytic clip.
* The coupled rows (table, workspace, obstacle distance) hold on hand-computed cases.
* A 1200-step random-policy episode in the simulator: with every row on (deployment) no joint-limit,
  velocity or table violation in the simulated trajectory. With the training rows (obstacle rows off
  by design) no joint-limit or table violation and every command within the velocity limits, but
  links that strike an obstacle are knocked past their velocity limit by the contact (reported).

Expected values are computed here from the robot description, the config and the public
kinematics API, never read back from the filter.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety import (ConstraintDefinitionError, InterventionStats, SafetyFilterError,
                               make_filter)
from ahrm_stack.safety.solvers import Outcome

HARD = 1e-9  # every hard bound, whatever the solver's tolerance
SOLVERS = ("daqp", "osqp")

# ----------------------------------------------------------------------------------------------
# One simulated task, its kinematics and filters built once for the module.
# ----------------------------------------------------------------------------------------------

_CFG = load_config()
_RUNNER = None
_FILTERS: dict = {}


def world() -> TaskRunner:
    global _RUNNER
    if _RUNNER is None:
        _RUNNER = TaskRunner(PushOffTask(_CFG.task), seed=0)
        _RUNNER.reset()
    return _RUNNER


def build(**changes):
    """A filter on the module's task with ``changes`` to the safety config (and a collision scene
    when the config's distance rows need one)."""
    runner = world()
    task, config = runner.task, dataclasses.replace(_CFG.safety, **changes)
    scene = None
    if config.table_distance_rows or config.obstacle_rows or config.self_collision_rows:
        scene = task.make_collision_scene(runner.physics)
    return make_filter(task.robot, task.kinematics, config,
                       control_period=task.config.episode.control_period,
                       table_height=task.config.table.height, tip_site=task.pusher.tip_site,
                       wrist_site=task.arm.wrist_site, scene=scene)


def cached(**changes):
    key = tuple(sorted(changes.items()))
    if key not in _FILTERS:
        _FILTERS[key] = build(**changes)
    return _FILTERS[key]


ROBOT = world().task.robot
KIN = world().task.kinematics
TIP = KIN.element_frame_id(world().task.pusher.tip_site)
WRIST = KIN.element_frame_id(world().task.arm.wrist_site)
SAFETY = _CFG.safety
DT = _CFG.task.episode.control_period
TABLE = _CFG.task.table.height
V_MAX = ROBOT.velocity_limit * (1 - SAFETY.velocity_margin)  # what may be commanded, rad/s
STEP = np.asarray(SAFETY.acceleration_limit) * DT  # rad/s per period
LIMITED = ROBOT.limited
Q_LOW = ROBOT.position_lower + SAFETY.position_margin
Q_HIGH = ROBOT.position_upper - SAFETY.position_margin
BRAKING_T = max(DT, float(np.max(V_MAX / np.asarray(SAFETY.acceleration_limit))))
HOME = np.asarray(_CFG.task.arm.home)


def horizon(config) -> float:
    return BRAKING_T if config.braking_horizon else DT


# ----------------------------------------------------------------------------------------------
# Inputs. Two kinds of generators:
# * ``cases``: hypothesis picks the kind of every input (joints inside, at, just inside/outside, far
#   beyond their limits, absurd or non-finite values; requests zero, tiny, huge, at the limits...)
#   and a seed; numpy draws the values of that kind. Cheap per case, so most of the 10^5 cases.
# * ``float_vectors``: hypothesis draws every float itself (its own nasty-float heuristics).
# ----------------------------------------------------------------------------------------------

NONFINITE = np.array([np.nan, np.inf, -np.inf])
ABSURD = np.array([1e-300, -1e-300, 5e-324, -5e-324, 1e300, -1e300, 1e15, -1e15,
                   np.finfo(float).max, -np.finfo(float).max, 0.0, -0.0])
SPAN = np.where(LIMITED, ROBOT.position_upper - ROBOT.position_lower, 4 * np.pi)
LOW = np.where(LIMITED, ROBOT.position_lower, -2 * np.pi)
EDGES = np.stack([ROBOT.position_lower, ROBOT.position_upper, Q_LOW, Q_HIGH, Q_LOW + 1e-12,
                  Q_HIGH - 1e-12, Q_LOW - 1e-12, Q_HIGH + 1e-12, ROBOT.position_lower - 1e-9,
                  ROBOT.position_upper + 1e-9])
POSITION_KINDS = ("inside", "inside", "edges", "beyond", "far_beyond", "mixed", "absurd", "nonfinite")
VELOCITY_KINDS = ("zero", "tiny", "small", "inside", "at_limit", "beyond", "huge", "absurd",
                  "mixed", "nonfinite")
PREVIOUS_KINDS = ("stored", "stored", "inside", "at_limit", "beyond", "nonfinite")


def _sprinkle(rng, values, pool):
    """Replace a random non-empty subset of ``values`` with picks from ``pool``."""
    chosen = rng.random(len(values)) < 0.4
    chosen[rng.integers(len(values))] = True
    return np.where(chosen, pool[rng.integers(0, len(pool), len(values))], values)


def draw_positions(kind: str, rng) -> np.ndarray:
    inside = LOW + rng.random(6) * SPAN
    if kind == "inside":
        return inside
    if kind == "absurd":
        return _sprinkle(rng, inside, ABSURD)
    if kind == "nonfinite":
        return _sprinkle(rng, inside, NONFINITE)
    edges = np.where(LIMITED, EDGES[rng.integers(0, len(EDGES), 6), np.arange(6)], inside)
    reach = 50.0 if kind == "far_beyond" else 0.3
    beyond = np.where(LIMITED, np.where(rng.random(6) < 0.5, ROBOT.position_lower - reach * rng.random(6),
                                        ROBOT.position_upper + reach * rng.random(6)), inside)
    if kind == "edges":
        return np.where(rng.random(6) < 0.7, edges, inside)
    if kind in ("beyond", "far_beyond"):
        return beyond
    return np.choose(rng.integers(0, 3, 6), (inside, edges, beyond))  # mixed


def draw_velocities(kind: str, rng, limit=V_MAX) -> np.ndarray:
    n = len(limit)
    if kind == "zero":
        return np.zeros(n)
    sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    inside = (2 * rng.random(n) - 1) * limit
    if kind == "tiny":
        return sign * 10.0 ** (-6 - 294 * rng.random(n))
    if kind == "small":
        return 0.05 * inside
    if kind == "inside":
        return inside
    if kind == "at_limit":
        return sign * limit
    if kind == "beyond":
        return sign * limit * (1 + 2 * rng.random(n))
    if kind == "huge":
        return sign * 10.0 ** (3 + 297 * rng.random(n))
    if kind == "absurd":
        return _sprinkle(rng, inside, ABSURD)
    if kind == "mixed":
        return np.choose(rng.integers(0, 4, n), (inside, sign * limit, sign * limit * 2.0,
                                                 sign * 10.0 ** (-300 + 600 * rng.random(n))))
    return _sprinkle(rng, inside, NONFINITE)


def draw_previous(kind: str, rng):
    if kind == "stored":
        return None
    inside = (2 * rng.random(6) - 1) * V_MAX
    if kind == "inside":
        return inside
    if kind == "at_limit":
        return np.where(rng.random(6) < 0.5, -V_MAX, V_MAX)
    if kind == "beyond":
        return np.where(rng.random(6) < 0.5, -V_MAX, V_MAX) * (1 + 99 * rng.random(6))
    return _sprinkle(rng, inside, NONFINITE)


SEEDS = st.integers(0, 2**31 - 1)


def cases(requests=VELOCITY_KINDS, positions=POSITION_KINDS, measured=VELOCITY_KINDS,
          previous=PREVIOUS_KINDS):
    """(q, dq, u_prev or None, request kind, rng): hypothesis picks the kinds and the seed."""
    def make(draw):
        q_kind, dq_kind, prev_kind, request_kind, seed = draw
        rng = np.random.default_rng(seed)
        return (draw_positions(q_kind, rng), draw_velocities(dq_kind, rng, ROBOT.velocity_limit),
                draw_previous(prev_kind, rng), request_kind, rng)
    return st.tuples(st.sampled_from(positions), st.sampled_from(measured), st.sampled_from(previous),
                     st.sampled_from(requests), SEEDS).map(make)


_FLOAT = st.one_of(st.floats(-7.0, 7.0), st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([float(x) for x in EDGES.ravel()] + [0.6, -0.6, 0.8, -0.8]))


def float_vectors(n=6):
    return arrays(np.float64, (n,), elements=_FLOAT)


# ----------------------------------------------------------------------------------------------
# The hard-bound oracle, written from the spec.
# ----------------------------------------------------------------------------------------------


def effective_previous(u_prev, stored, dq):
    """The previous command the acceleration limit refers to: the stored one, or the given one
    with non-finite entries replaced by the measured velocity (or zero), clipped to the limits."""
    if u_prev is None:
        return stored
    fill = np.where(np.isfinite(dq), dq, 0.0)
    given_ = np.where(np.isfinite(u_prev), u_prev, fill)
    return np.clip(given_, -V_MAX, V_MAX)


def check_hard_bounds(config, q, dq, previous, request, result, cartesian=False):
    u = result.command
    assert u.shape == (6,) and np.all(np.isfinite(u)), u
    assert np.all(np.abs(u) <= V_MAX + HARD), (u, V_MAX)
    assert np.all(np.abs(u - previous) <= STEP + HARD), (u, previous)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(dq)) and np.all(np.isfinite(request))):
        assert result.status == "nonfinite_input" and result.fallback
    reach_low = np.maximum(-V_MAX, previous - STEP)
    reach_high = np.minimum(V_MAX, previous + STEP)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(dq))):  # brake towards zero, fast as allowed
        np.testing.assert_allclose(u, np.clip(0.0, reach_low, reach_high), rtol=0, atol=HARD)
        return
    t = horizon(config)
    with np.errstate(over="ignore", invalid="ignore"):
        pos_low = np.where(LIMITED, (Q_LOW - q) / t, -np.inf)
        pos_high = np.where(LIMITED, (Q_HIGH - q) / t, np.inf)
        reachable = np.maximum(reach_low, pos_low) <= np.minimum(reach_high, pos_high)
        # reachable: q + T u stays within [q_min + m, q_max - m]
        moved = q + t * u
        assert np.all(~reachable | ~LIMITED | ((moved <= Q_HIGH + HARD) & (moved >= Q_LOW - HARD))), (q, u)
        # ... and with it the spec's literal one-period bound, from inside the range
        inside = LIMITED & reachable & (q >= Q_LOW) & (q <= Q_HIGH)
        step = q + DT * u
        assert np.all(~inside | ((step <= Q_HIGH + HARD) & (step >= Q_LOW - HARD))), (q, u)
    # out of reach this period: back towards the range as fast as the limits allow
    for i in np.flatnonzero(~reachable):
        expected = reach_low[i] if pos_high[i] < reach_low[i] else reach_high[i]
        assert abs(u[i] - expected) <= HARD, (i, q[i], u[i], expected)
        assert f"position[{i}]" in result.violated and result.fallback
    if cartesian:  # joints the policy does not command hold zero (within the box)
        for i in sorted(set(range(6)) - set(ROBOT.commanded_joints)):
            if reachable[i]:
                low, high = max(reach_low[i], pos_low[i]), min(reach_high[i], pos_high[i])
                assert abs(u[i] - np.clip(0.0, low, high)) <= HARD


# ----------------------------------------------------------------------------------------------
# Hard bounds for any input (hypothesis). Cases: joint mode 30000 + 16000, Cartesian 8000 + 5000,
# obstacle rows 2000 + 1000, hypothesis' own floats 2 x 4000 (daqp + osqp). With the 32000 below:
# 102000 generated cases in this module.
# ----------------------------------------------------------------------------------------------


def fuzz(examples: int):
    return settings(max_examples=examples, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


def run_cases(examples: int, body, **strategies) -> int:
    """Run ``body`` on ``examples`` hypothesis-generated cases; returns (and checks) how many ran."""
    ran = []

    @fuzz(examples)
    @given(**strategies)
    def check(**case):
        ran.append(1)
        body(**case)

    check()
    assert len(ran) >= examples, f"hypothesis generated only {len(ran)} of {examples} cases"
    print(f"{len(ran)} cases", end=" ")
    return len(ran)


def filter_and_check(safety, q, dq, u_prev, request, cartesian=False):
    stored = safety.previous_command
    call = safety.cartesian if cartesian else safety
    result = call(q, dq, request, u_prev=u_prev)
    check_hard_bounds(safety.config, q, dq, effective_previous(u_prev, stored, dq), request, result,
                      cartesian=cartesian)
    np.testing.assert_array_equal(safety.previous_command, result.command)
    return result


@pytest.mark.parametrize("solver, examples", [("daqp", 30_000), ("osqp", 16_000)])
def test_joint_mode_command_is_finite_and_within_every_hard_bound(solver, examples):
    safety = cached(solver=solver)

    def check(case):
        q, dq, u_prev, kind, rng = case
        filter_and_check(safety, q, dq, u_prev, draw_velocities(kind, rng))

    run_cases(examples, check, case=cases())


@pytest.mark.parametrize("solver, examples", [("daqp", 8_000), ("osqp", 5_000)])
def test_cartesian_mode_command_is_finite_and_within_every_hard_bound(solver, examples):
    safety = cached(solver=solver)

    def check(case):
        q, dq, u_prev, kind, rng = case
        v_nom = draw_velocities(kind, rng, np.full(3, 0.5))  # m/s
        filter_and_check(safety, q, dq, u_prev, v_nom, cartesian=True)

    run_cases(examples, check, case=cases())


@pytest.mark.parametrize("solver, examples", [("daqp", 2_000), ("osqp", 1_000)])
def test_obstacle_rows_keep_the_hard_bounds(solver, examples):
    safety = cached(solver=solver, obstacle_rows=True, obstacle_activation_distance=0.3)

    def check(case, offset_seed):
        _, dq, u_prev, kind, rng = case
        q = HOME + np.random.default_rng(offset_seed).uniform(-0.8, 0.8, 6)  # near the table and obstacles
        result = filter_and_check(safety, q, dq, u_prev, draw_velocities(kind, rng))
        if result.status == "optimal":
            assert result.worst_margin >= -1e-6

    run_cases(examples, check, case=cases(positions=("inside",)), offset_seed=SEEDS)


@pytest.mark.parametrize("solver", SOLVERS)
def test_hypothesis_floats_never_break_a_hard_bound(solver):
    safety = cached(solver=solver)

    def check(q, dq, u_prev, u_nom):
        filter_and_check(safety, q, dq, u_prev, u_nom)

    run_cases(4_000, check, q=float_vectors(), dq=float_vectors(), u_prev=st.none() | float_vectors(),
              u_nom=float_vectors())


# ----------------------------------------------------------------------------------------------
# The formulation: box-only QP = analytic clip (10000 + 8000 cases), and = clip whenever the clip
# meets every coupled row, computed independently here (7000 + 5000), the two solvers agree (2000).
# ----------------------------------------------------------------------------------------------


def analytic_box(config, q, previous):
    t = horizon(config)
    low = np.maximum(np.maximum(-V_MAX, previous - STEP), np.where(LIMITED, (Q_LOW - q) / t, -np.inf))
    high = np.minimum(np.minimum(V_MAX, previous + STEP), np.where(LIMITED, (Q_HIGH - q) / t, np.inf))
    return low, high


FINITE_POSITIONS = ("inside", "inside", "edges", "beyond", "mixed")
FINITE_REQUESTS = ("zero", "tiny", "small", "inside", "at_limit", "beyond", "huge")


@pytest.mark.parametrize("solver, examples", [("daqp", 10_000), ("osqp", 8_000)])
def test_box_only_qp_equals_the_analytic_clip(solver, examples):
    safety = cached(solver=solver, table_rows=False, workspace_rows=False, table_distance_rows=False,
                    self_collision_rows=False)

    def check(case):
        q, dq, u_prev, kind, rng = case
        u_nom = draw_velocities(kind, rng)
        low, high = analytic_box(safety.config, q, u_prev)
        if not np.all(low <= high):  # a joint's position bound out of reach: the hard bounds hold
            filter_and_check(safety, q, dq, u_prev, u_nom)
            return
        result = safety(q, dq, u_nom, u_prev=u_prev)
        clip = np.clip(u_nom, low, high)
        np.testing.assert_allclose(result.command, clip, rtol=0, atol=HARD)
        assert result.status == "optimal" and not result.fallback
        assert result.worst_margin == np.inf
        assert result.modified == bool(np.any(np.abs(clip - u_nom) > 1e-7))

    run_cases(examples, check,
              case=cases(FINITE_REQUESTS, FINITE_POSITIONS, ("zero",), ("inside", "at_limit")))


def point_rows(config, q):
    """Coupled rows A u <= b (table, workspace) for the tip and the wrist, from the public
    kinematics API."""
    KIN.update(q)
    t = horizon(config)
    rows, bounds = [], []
    floors = {TIP: TABLE + config.table_margin, WRIST: TABLE + config.wrist_table_margin}
    for frame in (TIP, WRIST):
        p, _ = KIN.frame_pose(frame)
        jac = KIN.frame_jacobian(frame)[:3]
        if config.table_rows:
            rows.append(-t * jac[2])
            bounds.append(p[2] - floors[frame])
        if config.workspace_rows:
            for k in range(3):
                rows += [t * jac[k], -t * jac[k]]
                bounds += [config.workspace_upper[k] - p[k], p[k] - config.workspace_lower[k]]
    return np.array(rows), np.array(bounds)


@pytest.mark.parametrize("solver, examples", [("daqp", 7_000), ("osqp", 5_000)])
def test_qp_equals_the_clip_whenever_the_clip_meets_every_coupled_row(solver, examples):
    safety = cached(solver=solver, table_distance_rows=False,
                    self_collision_rows=False)  # the point rows, computed below

    def check(case, offset_seed):
        _, dq, u_prev, kind, rng = case
        q = HOME + np.random.default_rng(offset_seed).uniform(-1.0, 1.0, 6)
        u_nom = draw_velocities(kind, rng)
        low, high = analytic_box(safety.config, q, u_prev)
        if not np.all(low <= high):
            filter_and_check(safety, q, dq, u_prev, u_nom)
            return
        clip = np.clip(u_nom, low, high)
        matrix, bound = point_rows(safety.config, q)
        result = safety(q, dq, u_nom, u_prev=u_prev)
        if np.all(matrix @ clip < bound - 1e-9):
            np.testing.assert_allclose(result.command, clip, rtol=0, atol=HARD)
            assert result.worst_margin == pytest.approx(float(np.min(bound - matrix @ clip)), abs=1e-9)
        elif result.status == "optimal":  # a row binds: the command meets every row
            assert np.all(matrix @ result.command <= bound + 1e-7)
            assert result.worst_margin == pytest.approx(float(np.min(bound - matrix @ result.command)),
                                                        abs=1e-9)
            assert any(name.startswith(("table:", "workspace:")) for name in result.active)

    run_cases(examples, check, case=cases(FINITE_REQUESTS, ("inside",), ("zero",), ("inside", "at_limit")),
              offset_seed=SEEDS)


def test_daqp_and_osqp_agree():
    """Where both solvers solve the QP they agree to 1e-6. OSQP (an ADMM method) sometimes declares
    a problem that is feasible only by a hair infeasible, or stops at its iteration limit; the filter
    then returns its safe fallback (hard bounds checked in the fuzz tests). That must stay rare."""
    daqp_filter, osqp_filter = cached(solver="daqp"), cached(solver="osqp")
    disagreements = []

    def check(case, offset_seed):
        _, dq, u_prev, kind, rng = case
        q = HOME + np.random.default_rng(offset_seed).uniform(-1.0, 1.0, 6)
        u_nom = draw_velocities(kind, rng)
        first = daqp_filter(q, dq, u_nom, u_prev=u_prev)
        second = osqp_filter(q, dq, u_nom, u_prev=u_prev)
        if first.status != second.status:
            disagreements.append((first.status, second.status))
            return
        np.testing.assert_allclose(first.command, second.command, rtol=0, atol=1e-6)

    ran = run_cases(2_000, check, case=cases(FINITE_REQUESTS, ("inside",), ("zero",), ("inside",)),
                    offset_seed=SEEDS)
    print(f"status disagreements: {len(disagreements)} {sorted(set(disagreements))}")
    assert len(disagreements) <= 0.01 * ran


# ----------------------------------------------------------------------------------------------
# Coupled rows on hand-computed cases.
# ----------------------------------------------------------------------------------------------


def pose_pointing_down(tip_position, iterations=300) -> np.ndarray:
    """Joint positions putting the tip at ``tip_position`` with the pusher axis straight down
    (damped least squares on the public kinematics, from home via a point 20 cm higher)."""
    q = HOME.copy()
    down = np.array([0.0, 0.0, -1.0])
    for target in (tip_position + [0.0, 0.0, 0.2], tip_position):
        for _ in range(iterations):
            KIN.update(q)
            p, rotation = KIN.frame_pose(TIP)
            error = np.r_[target - p, np.cross(rotation[:, 2], down)]
            jac = KIN.frame_jacobian(TIP)
            q = q + jac.T @ np.linalg.solve(jac @ jac.T + 1e-6 * np.eye(6), error)
    KIN.update(q)
    p, rotation = KIN.frame_pose(TIP)
    assert np.allclose(p, tip_position, atol=1e-9) and rotation[2, 2] < -1 + 1e-9
    assert np.all(q[LIMITED] > Q_LOW[LIMITED]) and np.all(q[LIMITED] < Q_HIGH[LIMITED])
    return q


def _rotation_taking(a, b):
    """The rotation matrix turning unit vector a onto unit vector b (Rodrigues)."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), a @ b
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k * ((1 - c) / s**2)


def halfspace_projection(u_nom, row, bound):
    """The closest point to u_nom with row @ u <= bound."""
    excess = row @ u_nom - bound
    return u_nom - max(excess, 0.0) / (row @ row) * row


FAST_ACCEL = tuple([1e3] * 6)  # so that only the row under test binds


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("braking", [False, True])
def test_tip_2cm_above_the_table_moving_down_at_full_speed_is_slowed_to_the_margin(solver, braking):
    safety = build(solver=solver, braking_horizon=braking, acceleration_limit=FAST_ACCEL,
                   table_distance_rows=False, self_collision_rows=False)  # the tip row alone
    t = DT if braking is False else safety.horizon
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.02]))
    KIN.update(q)
    p, _ = KIN.frame_pose(TIP)
    jz = KIN.frame_jacobian(TIP)[2]
    u_nom = -np.sign(jz) * V_MAX * (np.abs(jz) > 1e-6)  # full speed on every joint that lowers the tip
    assert jz @ u_nom < -0.25  # m/s down: as fast as the joints can take it
    floor = TABLE + SAFETY.table_margin
    expected = halfspace_projection(u_nom, -t * jz, p[2] - floor)
    assert np.all(np.abs(expected) <= V_MAX)  # the box does not bind: the row alone does
    result = safety(q, np.zeros(6), u_nom, u_prev=u_nom)
    np.testing.assert_allclose(result.command, expected, rtol=0, atol=1e-9)
    assert p[2] + t * (jz @ result.command) == pytest.approx(floor, abs=1e-9)
    assert p[2] + DT * (jz @ result.command) >= floor - 1e-9  # the spec's one-period row
    assert result.active == ("table:tip",) and result.modified and result.status == "optimal"
    assert result.worst_margin == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_tip_pressing_into_the_workspace_x_face_is_slowed_to_it(solver):
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.2]))
    KIN.update(q)
    p, _ = KIN.frame_pose(TIP)
    upper = (p[0] + 0.01, 1.0, 1.4)
    safety = build(solver=solver, braking_horizon=False, acceleration_limit=FAST_ACCEL,
                   workspace_upper=upper, table_distance_rows=False, self_collision_rows=False)
    jx = KIN.frame_jacobian(TIP)[0]
    u_nom = np.sign(jx) * V_MAX * (np.abs(jx) > 1e-6)
    expected = halfspace_projection(u_nom, DT * jx, upper[0] - p[0])
    result = safety(q, np.zeros(6), u_nom, u_prev=u_nom)
    np.testing.assert_allclose(result.command, expected, rtol=0, atol=1e-9)
    assert p[0] + DT * (jx @ result.command) == pytest.approx(upper[0], abs=1e-9)
    assert result.active == ("workspace:tip:x_upper",)


@pytest.mark.parametrize("solver", SOLVERS)
def test_pusher_heading_into_an_obstacle_keeps_the_safe_distance(solver):
    runner = TaskRunner(PushOffTask(_CFG.task), seed=0)
    runner.reset()
    task = runner.task
    kin = task.kinematics
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.25]))
    scene = task.make_collision_scene(runner.physics)
    # obstacle_0 turned corner-up, that corner 1.5 cm straight below the tip (so the witness points
    # are unique: the corner and the centre of the pusher's end face); the others far away
    half = np.asarray(_CFG.task.obstacles.size) / 2
    kin.update(q)
    tip_position, _ = kin.frame_pose(TIP)
    corner_up = _rotation_taking(half / np.linalg.norm(half), np.array([0.0, 0.0, 1.0]))
    centers = np.array([[2.0, 2.0 + i, half[2]] for i in range(4)])
    centers[0] = tip_position - [0.0, 0.0, 0.015 + np.linalg.norm(half)]
    rotations = np.tile(np.eye(3), (4, 1, 1))
    rotations[0] = corner_up
    scene.update_objects(np.array([3.0, -3.0, 0.0]), np.eye(3), centers, rotations)
    safety = make_filter(task.robot, kin, dataclasses.replace(
        _CFG.safety, solver=solver, braking_horizon=False, acceleration_limit=FAST_ACCEL,
        table_rows=False, table_distance_rows=False, self_collision_rows=False, obstacle_rows=True),
        control_period=DT,
        table_height=TABLE,
        tip_site=task.pusher.tip_site, wrist_site=task.arm.wrist_site, scene=scene)
    # the row, independently: FCL distance and witness points, Jacobian of the witness point
    kin.update(q)
    scene.update_robot()
    found = scene.distance("pusher", "obstacle_0")
    assert found.distance == pytest.approx(0.015, abs=1e-6)
    normal = (found.point_a - found.point_b) / np.linalg.norm(found.point_a - found.point_b)
    assert normal @ [0, 0, 1] > 1 - 1e-6
    origin, _ = kin.frame_pose(TIP)
    jac = kin.frame_jacobian(TIP)
    r = found.point_a - origin
    skew = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    witness_jacobian = jac[:3] - skew @ jac[3:]
    row = -DT * normal @ witness_jacobian
    u_nom = np.sign(row) * V_MAX * (np.abs(row) > 1e-8)  # straight at the obstacle, full speed
    bound = found.distance - SAFETY.obstacle_safe_distance
    expected = halfspace_projection(u_nom, row, bound)
    result = safety(q, np.zeros(6), u_nom, u_prev=u_nom)
    assert result.active == ("obstacle:pusher/obstacle_0",)
    np.testing.assert_allclose(result.command, expected, rtol=0, atol=1e-9)
    predicted = found.distance + DT * normal @ witness_jacobian @ result.command
    assert predicted == pytest.approx(SAFETY.obstacle_safe_distance, abs=1e-9)
    # without the rows the same request goes through untouched
    free = safety(q, np.zeros(6), u_nom, u_prev=u_nom, obstacles=False)
    np.testing.assert_array_equal(free.command, u_nom)


def test_closed_loop_descent_at_full_speed_stops_at_the_table_margin_with_real_acceleration_limits():
    # The kinematic model integrates exactly what is commanded: only the linearisation differs.
    safety = build()
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.25]))
    floor = TABLE + SAFETY.table_margin
    lowest = np.inf
    for _ in range(80):
        KIN.update(q)
        jz = KIN.frame_jacobian(TIP)[2]
        result = safety(q, np.zeros(6), -np.sign(jz) * V_MAX)
        assert result.status == "optimal" and not result.fallback
        q = q + DT * result.command
        KIN.update(q)
        lowest = min(lowest, KIN.frame_pose(TIP)[0][2])
    # down until a table row holds it (the tip's, or the tilted pusher's rim), never through
    assert any(name.startswith("table:") for name in result.active)
    assert floor - 1e-4 <= lowest <= floor + 0.01


def test_with_the_one_period_rows_the_same_descent_overruns_the_margin():
    # why braking_horizon exists: with rows one period ahead the arm sees the floor too late
    safety = build(braking_horizon=False)
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.25]))
    statuses, lowest = set(), np.inf
    for _ in range(80):
        KIN.update(q)
        jz = KIN.frame_jacobian(TIP)[2]
        result = safety(q, np.zeros(6), -np.sign(jz) * V_MAX)
        statuses.add(result.status)
        q = q + DT * result.command
        KIN.update(q)
        lowest = min(lowest, KIN.frame_pose(TIP)[0][2])
    assert "infeasible" in statuses and lowest < TABLE + SAFETY.table_margin - 1e-3


# ----------------------------------------------------------------------------------------------
# Infeasible, failing, non-finite.
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", SOLVERS)
def test_joint_past_its_limit_and_moving_further_decelerates_at_the_limit(solver):
    safety = build(solver=solver, table_rows=False, workspace_rows=False,
                   self_collision_rows=False)  # the box alone
    q = HOME.copy()
    q[1] = ROBOT.position_upper[1] + 0.2
    u_prev = np.array([0.3, V_MAX[1], -0.1, 0.0, 0.5, 0.0])
    result = safety(q, u_prev, u_prev, u_prev=u_prev)
    assert result.command[1] == pytest.approx(V_MAX[1] - STEP[1], abs=1e-12)
    assert result.status == "infeasible" and result.fallback
    assert "position[1]" in result.violated and "acceleration[1]" in result.active
    brake = np.clip(0.0, u_prev - STEP, u_prev + STEP)  # the others brake towards zero
    np.testing.assert_allclose(np.delete(result.command, 1), np.delete(brake, 1), atol=1e-9)


@pytest.mark.parametrize("solver", SOLVERS)
def test_tip_below_the_margin_and_falling_gets_the_least_violating_command(solver):
    safety = build(solver=solver, table_distance_rows=False, self_collision_rows=False)  # the tip row alone
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.005]))
    KIN.update(q)
    p, _ = KIN.frame_pose(TIP)
    jz = KIN.frame_jacobian(TIP)[2]
    u_prev = -np.sign(jz) * V_MAX  # falling at full speed: no command in reach meets the row
    result = safety(q, np.zeros(6), u_prev, u_prev=u_prev)
    assert result.status == "infeasible" and result.fallback
    assert "table:tip" in result.violated and result.worst_margin < 0
    low, high = np.maximum(-V_MAX, u_prev - STEP), np.minimum(V_MAX, u_prev + STEP)
    assert np.all(result.command >= low - HARD) and np.all(result.command <= high + HARD)
    # least violation: at least as high as the fastest rise the box allows along J_z (its vertex)
    best = np.where(jz > 0, high, low)
    assert jz @ result.command == pytest.approx(jz @ best, abs=1e-6)


def test_a_failing_solver_gives_the_safest_command():
    safety = build()
    safety.solver.solve = lambda *args: Outcome(None, "failed: test")
    q = HOME.copy()
    u_prev = 0.5 * V_MAX
    result = safety(q, np.zeros(6), V_MAX, u_prev=u_prev)
    assert result.status == "solver_failed" and result.fallback
    np.testing.assert_allclose(result.command, np.clip(0.0, u_prev - STEP, u_prev + STEP), atol=HARD)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_request_is_a_request_for_zero(bad):
    safety = cached(solver="daqp")
    q, u_prev = HOME.copy(), 0.4 * V_MAX
    u_nom = 0.1 * V_MAX
    u_nom[2] = bad
    result = safety(q, np.zeros(6), u_nom, u_prev=u_prev)
    zero = safety(q, np.zeros(6), np.zeros(6), u_prev=u_prev)
    np.testing.assert_array_equal(result.command, zero.command)
    assert result.status == "nonfinite_input" and result.fallback and result.modified
    cartesian = safety.cartesian(q, np.zeros(6), np.array([0.0, bad, 0.0]), u_prev=u_prev)
    assert cartesian.status == "nonfinite_input" and np.all(np.isfinite(cartesian.command))


@pytest.mark.parametrize("where", ["q", "dq"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("sign", [1.0, -1.0])  # moving forwards the lower bound brakes, backwards the upper
def test_nonfinite_state_brakes_within_the_acceleration_limit(where, bad, sign):
    safety = cached(solver="daqp")
    q, dq, u_prev = HOME.copy(), np.zeros(6), sign * 0.5 * V_MAX
    (q if where == "q" else dq)[3] = bad
    result = safety(q, dq, V_MAX, u_prev=u_prev)
    np.testing.assert_allclose(result.command, sign * np.maximum(0.5 * V_MAX - STEP, 0.0), atol=HARD)
    assert result.status == "nonfinite_input" and result.fallback and np.isnan(result.worst_margin)


def test_nonfinite_previous_command_is_replaced_by_the_measured_velocity():
    safety = cached(solver="daqp")
    dq = 0.3 * V_MAX
    u_prev = np.full(6, np.nan)
    result = safety(HOME, dq, V_MAX, u_prev=u_prev)
    assert np.all(np.abs(result.command - dq) <= STEP + HARD)
    assert result.status == "nonfinite_input"


# ----------------------------------------------------------------------------------------------
# Report, aggregate, configuration, construction.
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_request_inside_every_bound_passes_unchanged(solver):
    safety = build(solver=solver)
    u = 0.05 * V_MAX
    result = safety(HOME, np.zeros(6), u, u_prev=u)
    np.testing.assert_array_equal(result.command, u)
    assert not result.modified and result.active == () and result.status == "optimal"
    assert result.worst_margin > 0 and result.violated == ()


def test_reset_makes_the_previous_command_zero():
    safety = build()
    safety(HOME, np.zeros(6), V_MAX)
    assert np.any(safety.previous_command != 0)
    safety.reset()
    np.testing.assert_array_equal(safety.previous_command, np.zeros(6))
    result = safety(HOME, np.zeros(6), V_MAX)
    np.testing.assert_allclose(result.command, np.minimum(STEP, V_MAX), atol=HARD)


def test_osqp_workspace_is_set_up_once_and_reused(monkeypatch):
    import osqp
    calls = []
    original = osqp.OSQP.setup
    monkeypatch.setattr(osqp.OSQP, "setup",
                        lambda self, *a, **k: (calls.append(1), original(self, *a, **k))[1])
    safety = build(solver="osqp")
    rng = np.random.default_rng(0)
    for _ in range(50):
        safety(HOME + rng.uniform(-0.3, 0.3, 6), np.zeros(6), rng.uniform(-1, 1, 6))
    safety.cartesian(HOME, np.zeros(6), np.array([0.0, 0.1, 0.0]))
    assert len(calls) == 1


def test_cartesian_mode_tracks_a_free_tip_velocity():
    safety = build(acceleration_limit=FAST_ACCEL)
    q = pose_pointing_down(np.array([0.1, 0.0, TABLE + 0.3]))
    v_nom = np.array([0.05, -0.03, 0.02])
    result = safety.cartesian(q, np.zeros(6), v_nom)
    KIN.update(q)
    jac = KIN.frame_jacobian(TIP)
    np.testing.assert_allclose(jac[:3] @ result.command, v_nom, atol=2e-3)
    axis = np.array([0.0, 0.0, -1.0])
    omega = jac[3:] @ result.command
    assert np.linalg.norm(omega - axis * (axis @ omega)) < 0.05  # the axis is (nearly) held
    assert result.command[5] == 0.0 and result.status == "optimal"


def test_cartesian_mode_descent_is_stopped_by_the_table_row():
    safety = build(acceleration_limit=FAST_ACCEL, braking_horizon=False)
    q = pose_pointing_down(np.array([0.1, 0.1, TABLE + 0.02]))
    result = safety.cartesian(q, np.zeros(6), np.array([0.0, 0.0, -1.0]))
    KIN.update(q)
    p, _ = KIN.frame_pose(TIP)
    assert "table:tip" in result.active
    assert p[2] + DT * KIN.frame_jacobian(TIP)[2] @ result.command >= TABLE + SAFETY.table_margin - 1e-9


def test_disabled_filter_only_clips_and_sanitises():
    safety = build(enabled=False)
    u = np.array([10.0, -10.0, 0.1, np.nan, 0.0, np.inf])
    result = safety(HOME, np.zeros(6), u)
    np.testing.assert_array_equal(result.command, np.zeros(6))  # a non-finite request asks for nothing
    assert result.status == "nonfinite_input"
    u = np.array([10.0, -10.0, 0.1, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(safety(HOME, np.zeros(6), u).command,
                                  np.clip(u, -ROBOT.velocity_limit, ROBOT.velocity_limit))


def test_intervention_stats_aggregate_an_episode():
    safety = build()
    stats = InterventionStats()
    results = [safety(HOME, np.zeros(6), u) for u in (np.zeros(6), V_MAX, 0.01 * V_MAX)]
    for result in results:
        stats.add(result)
    assert stats.steps == 3
    assert [r.modified for r in results] == [False, True, False]  # zero; past the rate limit; inside
    assert stats.interventions == 1
    assert stats.worst_margin == min(r.worst_margin for r in results)
    assert stats.active_counts["acceleration[0]"] >= 1
    summary = stats.summary()
    assert summary["safety/interventions"] == 1 and summary["safety/intervention_rate"] == 1 / 3
    stats.reset()
    assert stats.steps == 0 and stats.worst_margin == np.inf


def test_construction_rejects_inconsistent_settings():
    with pytest.raises(ConstraintDefinitionError, match="acceleration_limit has 3 values"):
        build(acceleration_limit=(1.0, 2.0, 3.0))
    with pytest.raises(ConstraintDefinitionError, match="leaves no room"):
        build(position_margin=3.0)
    task = world().task
    for switch in ("obstacle_rows", "table_distance_rows", "self_collision_rows"):
        with pytest.raises(SafetyFilterError, match=f"{switch} is on but no collision scene"):
            changes = {"obstacle_rows": False, "table_distance_rows": False, "self_collision_rows": False,
                       switch: True}
            make_filter(task.robot, task.kinematics, dataclasses.replace(_CFG.safety, **changes),
                        control_period=DT, table_height=TABLE, tip_site=task.pusher.tip_site,
                        wrist_site=task.arm.wrist_site)
    safety = build(table_distance_rows=False, self_collision_rows=False)
    with pytest.raises(SafetyFilterError, match="no collision scene"):
        safety(HOME, np.zeros(6), np.zeros(6), obstacles=True)
    with pytest.raises(SafetyFilterError, match="u_nom must have shape"):
        safety(HOME, np.zeros(6), np.zeros(5))


@pytest.mark.parametrize("override, message", [
    ("safety.velocity_margin=1.0", "velocity_margin"),
    ("safety.obstacle_activation_distance=0.005", "obstacle_activation_distance"),
    ("safety.wrist_table_margin=-0.1", "wrist_table_margin"),
    ("safety.cartesian_regularization=0.0", "cartesian_regularization"),
    ("safety.self_collision_pairs.jaco=[[base, base]]",
     r"safety\.self_collision_pairs\.jaco\[0\]: a part cannot be paired with itself"),
    ("safety.self_collision_pairs.jaco=[[base, elbow]]",
     r"safety\.self_collision_pairs\.jaco\[0\]: 'elbow' is not an arm part"),
    ("safety.self_collision_pairs.ur5=[]", r"unknown config key 'safety\.self_collision_pairs\.ur5'"),
])
def test_config_rejects_bad_safety_values(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config([override])


# ----------------------------------------------------------------------------------------------
# A full episode in the simulator under a random policy.
# ----------------------------------------------------------------------------------------------


def run_random_policy_episode(changes: dict, seed: int = 0):
    """One full episode, random joint-velocity requests -> filter -> ``runner.step_only``; returns
    the simulated arm joint positions and velocities, the simulated tip and wrist heights over the
    table top, the interventions and the commands."""
    cfg = _CFG
    safety_config = dataclasses.replace(cfg.safety, **changes)
    runner = TaskRunner(PushOffTask(cfg.task), seed=seed)
    runner.reset()
    task, physics = runner.task, runner.physics
    scene = task.make_collision_scene(physics)
    safety = make_filter(task.robot, task.kinematics, safety_config,
                         control_period=cfg.task.episode.control_period,
                         table_height=cfg.task.table.height, tip_site=task.pusher.tip_site,
                         wrist_site=task.arm.wrist_site, scene=scene)
    safety.reset()
    joints = physics.bind(task.arm.joints)
    sites = [physics.bind(task.pusher.tip_site), physics.bind(task.arm.wrist_site)]
    cube = physics.bind(task.cube.geom)
    obstacles = [physics.bind(o.geom) for o in task.obstacles]
    half = np.asarray(cfg.task.table.half_extent)
    stats = InterventionStats()
    rng = np.random.default_rng(seed)
    u_nom = np.zeros(6)
    qs, dqs, heights, commands = [], [], [], []
    for step in range(cfg.task.max_steps):
        if step % 20 == 0:  # a random policy: new random joint velocities, up to 1.5x the limits
            u_nom = rng.uniform(-1.5, 1.5, 6) * task.robot.velocity_limit
            u_nom[5] = 0.0
        if safety_config.obstacle_rows:  # where the objects are now
            scene.update_objects(cube.xpos, cube.xmat.reshape(3, 3),
                                 np.array([o.xpos for o in obstacles]),
                                 np.array([o.xmat.reshape(3, 3) for o in obstacles]))
        result = safety(np.array(joints.qpos), np.array(joints.qvel), u_nom)
        stats.add(result)
        commands.append(result.command)
        _, terminated, truncated = runner.step_only(result.command)
        qs.append(np.array(joints.qpos))
        dqs.append(np.array(joints.qvel))
        heights += [site.xpos[2] - cfg.task.table.height for site in sites
                    if np.all(np.abs(site.xpos[:2]) <= half)]  # over the table top
        if terminated or truncated:
            break
    return task.robot, np.array(qs), np.array(dqs), np.array(heights), stats, np.array(commands)


@pytest.mark.parametrize("mode, changes", [("deployment", {"obstacle_rows": True}), ("training", {})])
def test_random_policy_episode_has_no_limit_velocity_or_table_violation(mode, changes):
    """Joint limits and the table top hold in the simulator in both modes; the simulated joint
    speeds stay within the limits when the obstacle rows are on. (In training they are off: the
    random arm then strikes obstacles, and the contact, not the command, can overspeed a joint.)"""
    robot, qs, dqs, heights, stats, commands = run_random_policy_episode(changes)
    peak = np.max(np.abs(dqs) / robot.velocity_limit)
    print(f"\n{mode}: random-policy episode of {stats.steps} steps: {stats.interventions} "
          f"interventions, {stats.fallbacks} fallbacks, worst predicted margin "
          f"{stats.worst_margin:.1e} m; in the simulator: lowest tip/wrist over the table "
          f"{heights.min() * 1e3:.1f} mm above it, peak |qvel|/v_max {peak:.3f}, closest joint "
          f"limit {np.min(np.minimum(qs - robot.position_lower, robot.position_upper - qs)):.3f} rad")
    assert stats.steps == 1200 and stats.interventions > 0 and stats.fallbacks == 0
    lim = robot.limited
    assert np.all(qs[:, lim] >= robot.position_lower[lim]) and np.all(qs[:, lim] <= robot.position_upper[lim])
    assert heights.min() >= 0.0
    assert np.all(np.abs(commands) <= robot.velocity_limit)
    if mode == "deployment":
        assert peak <= 1.0
