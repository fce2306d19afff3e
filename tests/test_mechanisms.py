"""Reward mechanisms (spec §4) on synthetic component streams with hand-computed expectations."""

import dataclasses

import numpy as np
import pytest

from ahrm_stack.learning.mechanisms import (ConstraintMonitor, EpisodeStats, MechanismConfig, RewardMechanism,
                                            blend_weight)

BASE = MechanismConfig(
    method="ahrm",
    fixed_order=("avoid", "manipulate", "time"),
    manual_orders=(("time", "avoid", "manipulate"), ("avoid", "manipulate", "time"),
                   ("manipulate", "avoid", "time")),
    initial_orders=(("avoid", "manipulate", "time"),) * 3,
    convergence_window=10, convergence_tolerance=0.05, constraint_window=10,
    constraint_min_steps=20, constraint_margin=0.1, constraint_check="running", priority_period=30,
    priority_rule="magnitude", blend_band=0.05, blend_slope=40.0)

FAR = np.array([1.0, 1.0])  # far from both regions: phase 1, no blending
PHASE2 = np.array([-1.0, 1.0])  # deep in B_obstacles, far from B_target
PHASE3 = np.array([-1.0, -1.0])


def make(method, **changes):
    return RewardMechanism(dataclasses.replace(BASE, method=method, **changes))


def test_linear_sum():
    ls = make("ls")
    assert ls.reward(np.array([0.0, -1.0, -1.0]), FAR) == -2.0
    assert ls.reward(np.array([-1.0, 0.0, 0.0]), PHASE3) == -1.0


def test_hierarchical_sums_follow_order_and_level():
    mhrm = make("mhrm")
    g = np.array([-1.0, 0.0, -1.0])  # avoid violated, manipulate fine, time violated
    # level 1: phase 1's first objective is time -> -1; phase 2: avoid -> -1; phase 3: manipulate -> 0
    assert mhrm.reward(g, FAR) == -1.0
    assert mhrm.reward(g, PHASE2) == -1.0
    assert mhrm.reward(g, PHASE3) == 0.0
    mhrm.levels = [2, 2, 3]
    # phase 1: time + avoid = -2; phase 2: avoid + manipulate = -1; phase 3: all = -2
    np.testing.assert_array_equal(mhrm.phase_rewards(g), [-2.0, -1.0, -2.0])


@pytest.mark.parametrize("method", ["ahrm", "mhrm", "fhrm"])
def test_at_the_last_level_a_hierarchy_rewards_the_linear_sum(method):
    """Once every phase has reached level N, R^k is the sum of all objectives in every phase, the
    blend of equal rewards is that sum, and each hierarchy's reward is LS's (to rounding): what
    still sets them apart is the priority constraint on the first N - 1 objectives."""
    rng = np.random.default_rng(0)
    g = rng.uniform(-1, 1, (2000, 3))
    distances = rng.uniform(-0.1, 0.1, (2000, 2))  # in and around both blending bands
    hierarchy, ls = make(method), make("ls")
    hierarchy.orders = [tuple(rng.permutation(3)) for _ in range(3)] if method == "ahrm" else hierarchy.orders
    hierarchy.levels = [3, 3, 3]
    np.testing.assert_allclose(hierarchy.reward(g, distances), ls.reward(g, distances), rtol=0, atol=1e-12)
    assert np.isnan(ls.constraint_thresholds()).all()


def test_blend_weight_values():
    assert blend_weight(0.05, 0.05, 40.0) == pytest.approx(0.0)
    assert blend_weight(0.0, 0.05, 40.0) == pytest.approx(0.5)
    assert blend_weight(-0.05, 0.05, 40.0) == pytest.approx(1.0)
    assert blend_weight(0.2, 0.05, 40.0) == 0.0 and blend_weight(-0.2, 0.05, 40.0) == 1.0
    # inside: 0.5 (1 - tanh(40 * 0.02) / tanh(2))
    assert blend_weight(0.02, 0.05, 40.0) == pytest.approx(0.5 * (1 - np.tanh(0.8) / np.tanh(2.0)))


@pytest.mark.parametrize("axis", [0, 1])
def test_blended_reward_is_continuous_across_each_boundary(axis):
    mhrm = make("mhrm")
    mhrm.levels = [1, 1, 3]
    g = np.array([0.0, -1.0, -1.0])  # R^1 = -1 (time), R^2 = 0 (avoid), R^3 = -2 (all)
    path = np.linspace(0.1, -0.1, 200_001)  # 1e-6 m steps through the boundary and the band
    distances = np.tile(PHASE2 if axis == 1 else FAR, (len(path), 1))
    distances[:, axis] = path
    rewards = mhrm.reward(g, distances)
    r = mhrm.phase_rewards(g)
    near, far = (r[0], r[1]) if axis == 0 else (r[1], r[2])
    slope = 40.0 / (2 * np.tanh(40.0 * 0.05))  # the blend weight's steepest slope, 1/m
    assert np.max(np.abs(np.diff(rewards))) <= abs(far - near) * slope * 1e-6 * (1 + 1e-6)
    # far on either side: the pure phase rewards
    assert rewards[0] == near and rewards[-1] == far


def test_no_jump_at_the_boundary_only_the_bounded_slope():
    """Across the exact boundary a step changes R by no more than the blend's slope allows:
    |dR| <= |R3 - R2| * alpha / (2 tanh(alpha delta)) * ds (20.7 |dR| per metre at the defaults),
    the same as anywhere in the band; a 1e-6 m step gives 2.07e-5, a 4.8e-8 m step under 1e-6."""
    mhrm = make("mhrm")
    g = np.array([0.0, -1.0, 0.0])  # R^2 = 0 (avoid), R^3 = -1 (manipulate): |R3 - R2| = 1
    slope = 40.0 / (2 * np.tanh(40.0 * 0.05))
    for step in (1e-6, 4.8e-8):
        a = mhrm.reward(g, np.array([-1.0, step / 2]))
        b = mhrm.reward(g, np.array([-1.0, -step / 2]))
        assert abs(a - b) <= slope * step * (1 + 1e-6)
    assert abs(mhrm.reward(g, np.array([-1.0, 2.4e-8])) - mhrm.reward(g, np.array([-1.0, -2.4e-8]))) < 1e-6


def _episode(phase_steps, f_rows):
    """f (T, 3) and phase (T,) from {phase: steps} and {phase: f row}."""
    f, phase = [], []
    for k, n in phase_steps.items():
        f += [f_rows[k]] * n
        phase += [k] * n
    return np.array(f, dtype=float), np.array(phase)


def test_priority_order_from_average_episode_rewards_with_ties():
    ahrm = make("ahrm")
    # phase 1 for 10 steps per episode: avoid always +1 (sum 10), manipulate alternates +-1
    # (sum 0), time -1 (sum -10): |means| = (10, 0, 10) -> tie avoid/time broken by index
    f = np.tile([[1, 1, -1], [1, -1, -1]], (5, 1)).astype(float)
    phase = np.ones(10, dtype=int)
    events = []
    for _ in range(29):
        events += ahrm.end_episode(f, phase)
    assert ahrm.orders[0] == (0, 1, 2) and not [e for e in events if e.kind != "level_advanced"]
    events = ahrm.end_episode(f, phase)
    assert ahrm.orders[0] == (0, 2, 1)
    assert [e.kind for e in events] == ["order_changed"] and events[0].episode == 30
    assert ahrm.levels[0] == 1


def _phase3_episode(avoid_violated: int, manipulate_violated: int, steps: int):
    """``steps`` steps in phase 3; the first n steps violate avoid / manipulate; time always holds."""
    f = np.ones((steps, 3))
    f[:avoid_violated, 0] = -1
    f[:manipulate_violated, 1] = -1
    return f, np.full(steps, 3)


def test_violation_rule_ranks_by_the_per_step_average_low_first():
    # two kinds of phase-3 episode, alternating (15 of each in P = 30):
    #   A: 10 steps, avoid violated 1, manipulate 7: sums (8, -4, 10), per-step (0.8, -0.4, 1)
    #   B: 30 steps, avoid violated 20, manipulate 0: sums (-10, 30, 30), per-step (-1/3, 1, 1)
    # mean sums (-1, 13, 20): magnitude ranks time > manipulate > avoid
    # mean per-step averages (0.2333, 0.3, 1): violation ranks avoid > manipulate > time
    a, b = _phase3_episode(1, 7, 10), _phase3_episode(20, 0, 30)
    orders = {}
    for rule in ("magnitude", "violation"):
        ahrm = make("ahrm", priority_rule=rule)
        events = []
        for i in range(30):
            events += ahrm.end_episode(*(a if i % 2 == 0 else b))
        orders[rule] = ahrm.orders[2]
        assert [e.kind for e in events if e.kind != "level_advanced"] == (
            ["order_changed"] if rule == "magnitude" else [])
    assert orders["magnitude"] == (2, 1, 0)
    assert orders["violation"] == (0, 1, 2)  # the initial order: no change event for it
    ahrm = make("ahrm", priority_rule="violation", initial_orders=(("time", "avoid", "manipulate"),) * 3)
    events = []
    for i in range(30):
        events += ahrm.end_episode(*(a if i % 2 == 0 else b))
    assert ahrm.orders[2] == (0, 1, 2)
    [changed] = [e for e in events if e.kind == "order_changed"]
    assert changed.phase == 3 and changed.episode == 30
    assert "per-step mean [0.233, 0.3, 1.0]" in changed.detail


def test_locking_after_two_equal_orders():
    ahrm = make("ahrm")
    f, phase = _episode({1: 10}, {1: [1, -1, 1]})  # sums (10, -10, 10): order avoid, manipulate, time
    kinds = []
    for _ in range(60):
        kinds += [e.kind for e in ahrm.end_episode(f, phase)]
    # determination at 30 gives the initial order (no change, first determination);
    # at 60 the same order again: locked
    assert kinds.count("order_locked") == 1 and "order_changed" not in kinds
    assert ahrm.locked[0] and not ahrm.locked[1]
    for _ in range(30):
        ahrm.end_episode(*_episode({1: 10}, {1: [-1, 1, 1]}))
    assert ahrm.orders[0] == (0, 1, 2)  # locked: no further determination


def test_level_advance_on_convergence():
    fhrm = make("fhrm")
    stream = [np.array([[1, 1, 1]] * 5 + [[-1, 1, 1]] * 5, float)] * 20
    events = []
    for i, f in enumerate(stream):
        events += fhrm.end_episode(f, np.ones(10, int))
        if i < 19:
            assert fhrm.levels[0] == 1  # needs 2 W = 20 episodes
    assert fhrm.levels[0] == 2 and events[-1].kind == "level_advanced" and events[-1].episode == 20


def test_no_advance_while_changing():
    fhrm = make("fhrm")
    for i in range(20):
        n_good = 1 + i // 2  # the level-1 sum keeps improving
        f = np.array([[1, 1, 1]] * n_good + [[-1, 1, 1]] * (10 - min(n_good, 10)), float)
        fhrm.end_episode(f, np.ones(len(f), int))
    assert fhrm.levels[0] == 1


def test_constraint_termination_at_the_right_step():
    fhrm = make("fhrm")
    fhrm.levels = [2, 1, 1]
    # history: 10 episodes whose per-step average of R_1 (avoid) in phase 1 is 1.0
    for _ in range(10):
        fhrm._history[0].append((10.0, np.array([10.0, 0.0, 0.0])))
    tau = fhrm.constraint_thresholds()
    assert tau[0] == 1.0 and np.isnan(tau[1])
    monitor = fhrm.constraint_monitor()
    # 20 good steps, then bad ones: average after 20 + n steps = (20 - n) / (20 + n) < 0.9
    # -> n > 20 * 0.1 / 1.9 = 1.05 -> ends on the 2nd bad step (the 22nd step)
    results = [monitor.step(np.array([1.0, 1.0, 1.0]), 1) for _ in range(20)]
    results += [monitor.step(np.array([-1.0, 1.0, 1.0]), 1) for _ in range(2)]
    assert not any(results[:21]) and results[21] and monitor.violated_phase == 1


def test_constraint_waits_for_min_steps():
    monitor = ConstraintMonitor(np.array([1.0, np.nan, np.nan]), [[0], [], []], 20, 0.1)
    assert not any(monitor.step(np.array([-1.0, 0, 0]), 1) for _ in range(19))
    assert monitor.step(np.array([-1.0, 0, 0]), 1)


def test_a_margin_beyond_the_reward_range_never_ends_an_episode():
    """The scratch study's ``-free`` rows (``constraint_margin=1000``): a two-objective per-step
    average is >= -2, so with tau <= 2 it never falls below tau - 1000, at the last level or any."""
    fhrm = make("fhrm", constraint_margin=1000.0)
    fhrm.levels = [3, 3, 3]
    for k in range(3):  # a history whose prefix average is the best possible: tau = 2
        for _ in range(10):
            fhrm._history[k].append((10.0, np.array([10.0, 10.0, 10.0])))
    assert fhrm.constraint_thresholds().tolist() == [2.0, 2.0, 2.0]
    monitor = fhrm.constraint_monitor()
    worst = np.array([-1.0, -1.0, -1.0])
    assert not any(monitor.step(worst, phase) for phase in (1, 2, 3) for _ in range(500))
    default = make("fhrm")  # the same worst steps end an episode under the default margin
    default.levels, default._history = [3, 3, 3], fhrm._history
    strict = default.constraint_monitor()
    assert any(strict.step(worst, 1) for _ in range(30))


def test_state_survives_save_and_restore_exactly():
    rng = np.random.default_rng(0)
    a = make("ahrm", priority_period=5, convergence_window=3)
    for _ in range(40):
        phase = rng.integers(1, 4, 30)
        f = rng.choice([-1.0, 1.0], (30, 3))
        a.end_episode(f, phase)
    b = make("ahrm", priority_period=5, convergence_window=3)
    b.load_state_dict(a.state_dict())
    assert b.state_dict() == a.state_dict()
    for _ in range(20):
        phase = rng.integers(1, 4, 30)
        f = rng.choice([-1.0, 1.0], (30, 3))
        ea, eb = a.end_episode(f, phase), b.end_episode(f, phase)
        assert [(e.kind, e.phase, e.detail) for e in ea] == [(e.kind, e.phase, e.detail) for e in eb]
    assert b.state_dict() == a.state_dict()
    g = rng.uniform(-1, 0, (100, 3))
    d = rng.uniform(-0.1, 0.1, (100, 2))
    np.testing.assert_array_equal(a.reward(g, d), b.reward(g, d))
    with pytest.raises(ValueError, match="'ahrm'"):
        make("mhrm").load_state_dict(a.state_dict())


def test_bad_order_is_named():
    with pytest.raises(ValueError, match=r"mechanism\.fixed_order.*permutation"):
        make("fhrm", fixed_order=("avoid", "avoid", "time"))


def _level_one_episode(total: int) -> tuple[np.ndarray, np.ndarray]:
    """A phase-1 episode whose level-1 sum (avoid first: the sum of f_avoid) is ``total``:
    |total| steps of sign(total), or a +1/-1 pair for 0."""
    column = [1.0, -1.0] if total == 0 else [float(np.sign(total))] * abs(total)
    f = np.ones((len(column), 3))
    f[:, 0] = column
    return f, np.ones(len(column), int)


def test_level_advance_compares_the_last_w_episodes_with_the_w_before_them():
    """W = 2, level-1 sums 0, 4, 6, 5, 5. After 4 episodes the last two (6, 5: mean 5.5) differ
    from the two before (0, 4: mean 2); after 5 the last two (5, 5) equal the two before them
    (4, 6): the level advances at episode 5. Comparing with the first W episodes (0, 4) instead,
    or with all the earlier ones, would not advance; neither would the last W + 1."""
    fhrm = make("fhrm", convergence_window=2, convergence_tolerance=0.01)
    levels = []
    for total in (0, 4, 6, 5, 5):
        fhrm.end_episode(*_level_one_episode(total))
        levels.append(fhrm.levels[0])
    assert levels == [1, 1, 1, 1, 2]
    assert fhrm._level_sums[0] == []  # the sums of the new level start afresh
    [event] = [e for e in fhrm.events if e.kind == "level_advanced"]
    assert (event.episode, event.phase) == (5, 1)
    assert event.detail == "level 1 -> 2 (episode-sum mean 5.000 vs 5.000)"


def test_level_advance_tolerance_is_relative_to_the_recent_mean_with_a_floor_of_one():
    """|recent - before| <= tolerance x max(1, |recent|): 10 vs 10.4 is within 5 % of 10; 0 vs 0.4
    is not within 5 % of max(1, 0) = 1, nor 0 vs 0.06; 0 vs 0.04 is."""
    for sums, advanced in [((10.4, 10.4, 10, 10), True), ((0.4, 0.4, 0, 0), False), ((0.06, 0.06, 0, 0), False),
                           ((0.04, 0.04, 0, 0), True), ((-10.4, -10.4, -10, -10), True),
                           ((10.6, 10.6, 10, 10), False)]:
        fhrm = make("fhrm", convergence_window=2, convergence_tolerance=0.05)
        fhrm._level_sums[0] = list(sums)
        events = fhrm._advance_level(0)
        assert (fhrm.levels[0] == 2) is advanced and bool(events) is advanced, sums


def test_the_last_level_never_advances_and_ls_keeps_every_level():
    fhrm = make("fhrm", convergence_window=1)
    fhrm.levels = [3, 1, 1]
    for _ in range(4):
        fhrm.end_episode(*_level_one_episode(5))
    assert fhrm.levels[0] == 3
    ls = make("ls", convergence_window=1)
    assert ls.levels == [3, 3, 3] and ls.locked == [True, True, True]
    for _ in range(4):
        assert ls.end_episode(*_level_one_episode(5)) == []
    assert ls.levels == [3, 3, 3] and ls._level_sums == [[], [], []] and ls.visits == [4, 0, 0]


def test_level_advance_at_exactly_the_tolerance_advances():
    """|recent - before| = 1 = 0.25 x |recent| (all exact in binary): within tolerance."""
    fhrm = make("fhrm", convergence_window=1, convergence_tolerance=0.25)
    fhrm._level_sums[0] = [5.0, 4.0]
    assert fhrm._advance_level(0) and fhrm.levels[0] == 2


def test_episode_stats_have_one_row_per_phase():
    f = np.array([[1, -1, 1], [-1, -1, 1], [1, 1, -1], [1, 1, 1]], float)
    stats = EpisodeStats.from_steps(f, np.array([1, 1, 3, 3]))
    np.testing.assert_array_equal(stats.steps, [2, 0, 2])
    np.testing.assert_array_equal(stats.sums, [[0, -2, 2], [0, 0, 0], [2, 2, 0]])


def test_thresholds_need_a_second_level_and_a_full_window():
    """tau_k is nan at level 1 (no higher level to protect), and before W episodes visited k."""
    fhrm = make("fhrm", constraint_window=3)
    fhrm.levels = [1, 2, 2]
    for k, episodes in ((0, 3), (1, 2), (2, 4)):
        for _ in range(episodes):
            fhrm._history[k].append((4.0, np.array([2.0, 4.0, -4.0])))
    fhrm._history[2].append((2.0, np.array([-2.0, 2.0, 2.0])))  # the last of phase 3's five
    tau = fhrm.constraint_thresholds()
    assert np.isnan(tau[0]) and np.isnan(tau[1])
    assert tau[2] == pytest.approx((0.5 + 0.5 - 1.0) / 3)  # the last three: 2/4, 2/4, -2/2
    assert fhrm.constraint_monitor().prefixes == [[], [0], [0]]
    assert make("ls").constraint_thresholds().tolist() == [pytest.approx(np.nan, nan_ok=True)] * 3


def test_priority_determination_reads_the_last_p_episodes_even_when_w_is_shorter():
    """P = 4, W = 2: the history keeps max(W, P) = 4 episodes. Two episodes with sums (0, 10, 0),
    then two with (4, 0, 2): over all four the mean sums are (2, 5, 1) -> manipulate, avoid, time;
    over only the last two (W) they would be (4, 0, 2) -> avoid, time, manipulate."""
    ahrm = make("ahrm", priority_period=4, constraint_window=2)
    manipulating = np.array([[1, 1, 1], [-1, 1, -1]] * 5, float)  # sums (0, 10, 0)
    avoiding = np.ones((10, 3))
    avoiding[:3, 0] = -1  # avoid: 7 - 3 = 4
    avoiding[::2, 1] = -1  # manipulate: 5 - 5 = 0
    avoiding[:4, 2] = -1  # time: 6 - 4 = 2
    for f in (manipulating, manipulating, avoiding, avoiding):
        ahrm.end_episode(f, np.ones(10, int))
    assert ahrm.orders[0] == (1, 0, 2)
    assert len(ahrm._history[0]) == 4


def test_a_constraint_terminated_episode_is_an_event_naming_its_phase():
    fhrm = make("fhrm")
    f, phase = _level_one_episode(3)
    [event] = fhrm.end_episode(f, phase, constraint_terminated=True, terminated_phase=2)
    assert (event.episode, event.kind, event.phase) == (1, "constraint_termination", 2)
    [event] = fhrm.end_episode(f, phase, constraint_terminated=True)
    assert (event.episode, event.phase) == (2, 0)
    assert fhrm.events[-1] is event


def test_a_locked_order_is_an_event_of_its_phase_with_the_order_named():
    ahrm = make("ahrm", priority_period=1, initial_orders=(("time", "avoid", "manipulate"),) * 3)
    f = np.tile([1.0, -1.0, 1.0], (4, 1))  # sums (4, -4, 4): |means| tie avoid/time, then manipulate
    events = ahrm.end_episode(f, np.full(4, 2)) + ahrm.end_episode(f, np.full(4, 2))
    assert [(e.kind, e.phase) for e in events] == [("order_changed", 2), ("order_locked", 2)]
    assert events[0].detail.startswith("time>avoid>manipulate -> avoid>manipulate>time (|mean| [4.0, 4.0, 4.0])")
    assert events[1].detail == "avoid>manipulate>time" and ahrm.locked == [False, True, False]


def test_the_constraint_monitor_ignores_a_phase_without_threshold_and_ends_only_below_tau_minus_margin():
    monitor = ConstraintMonitor(np.array([np.nan, 0.75, np.nan]), [[], [0], []], 2, 0.25)
    assert monitor.step(np.array([-1.0, -1.0, -1.0]), 1) is False and monitor.steps.tolist() == [0, 0, 0]
    # per-step average of f_avoid in phase 2: 1, then (1 + 0) / 2 = 0.5 = tau - margin: not below
    assert monitor.step(np.array([1.0, -1.0, -1.0]), 2) is False
    assert monitor.step(np.array([0.0, -1.0, -1.0]), 2) is False
    assert monitor.violated_phase is None
    assert monitor.step(np.array([-0.1, 1.0, 1.0]), 2) is True and monitor.violated_phase == 2


def test_one_order_per_phase_is_required():
    with pytest.raises(ValueError, match=r"^mechanism\.manual_orders: expected 3 orders \(one per phase\), got 2"):
        make("mhrm", manual_orders=(("avoid", "manipulate", "time"),) * 2)


def test_the_methods_are_registered_classes():
    from ahrm_stack.learning.mechanisms import (MECHANISMS, AdaptiveHierarchy, FixedHierarchy, LinearSum,
                                                ManualHierarchy, label)

    assert {name: cls for name, cls in MECHANISMS.items()} == {
        "ls": LinearSum, "fhrm": FixedHierarchy, "mhrm": ManualHierarchy, "ahrm": AdaptiveHierarchy}
    for name, cls in MECHANISMS.items():
        mechanism = make(name)
        assert type(mechanism) is cls and isinstance(mechanism, RewardMechanism)
        assert label(name) == name.upper() and mechanism.method == name
    assert not LinearSum.hierarchical and AdaptiveHierarchy.adaptive and not FixedHierarchy.adaptive
    assert make("fhrm").orders == [(0, 1, 2)] * 3
    assert make("mhrm").orders == [(2, 0, 1), (0, 1, 2), (1, 0, 2)]
    assert label("not-a-method") == "not-a-method"
