"""Reward components f1-f3 (spec §3) on crafted values, computed by hand."""

import numpy as np
import pytest

from ahrm_stack.env.rewards import (ProgressObjective, TimeObjective, avoid_component,
                                    obstacle_touched, penalty_form, progress)


def test_penalty_form():
    np.testing.assert_array_equal(penalty_form(np.array([1.0, -1.0, 1.0])), [0.0, -1.0, 0.0])


def test_avoid_from_contacts_and_speeds():
    is_obstacle = np.array([False, False, True, True])
    is_toucher = np.array([False, True, False, False])
    slow = np.array([0.0, 0.0])
    # geom 1 (robot) against geom 3 (obstacle), either order
    assert obstacle_touched(np.array([[1, 3]]), is_obstacle, is_toucher, slow, 1e-3)
    assert obstacle_touched(np.array([[3, 1]]), is_obstacle, is_toucher, slow, 1e-3)
    # obstacle resting on the table (geom 0) is not a touch
    assert not obstacle_touched(np.array([[0, 3], [0, 2]]), is_obstacle, is_toucher, slow, 1e-3)
    # a moving obstacle is a touch even without a contact listed
    assert obstacle_touched(np.empty((0, 2), int), is_obstacle, is_toucher, np.array([0, 2e-3]), 1e-3)
    assert not obstacle_touched(np.empty((0, 2), int), is_obstacle, is_toucher, np.array([0, 9e-4]), 1e-3)
    assert avoid_component(True) == -1.0 and avoid_component(False) == 1.0


def test_progress_by_hand():
    # target at (0.3, 0.4): d = 0.5; tip 0.1 m above the target: l = 0.1 -> P = 0.4
    assert progress(np.array([0.3, 0.4, 0.425]), np.zeros(2), np.array([0.3, 0.4, 0.525])) == pytest.approx(0.4)


def test_progress_objective_counts_only_new_bests():
    f2 = ProgressObjective(eps=0.0005)
    f2.reset(0.0)
    # creep forward 1 mm (+1), snap back (-1), creep to the old best (-1: not a new best),
    # 0.4 mm past it (-1: within eps, but the best is now 1.4 mm), then 0.6 mm past that (+1)
    assert [f2.step(p) for p in (0.001, -0.01, 0.001, 0.0014, 0.002)] == [1, -1, -1, -1, 1]
    # progress within eps of the best is not progress (but raises the best to 0.4 mm)
    f2.reset(0.0)
    assert f2.step(0.0004) == -1 and f2.step(0.0008) == -1 and f2.step(0.0014) == 1


def test_time_objective_budgets_by_hand():
    f3 = TimeObjective(episode_duration=1.0)
    f3.reset()
    # never visited: budget = remaining time. Steps of 0.25 s in phase 1:
    # t1 = 0.25 < 1 - 0.25 -> +1; t1 = 0.5 < 0.5 is false -> -1
    assert f3.step(1, 0.25, elapsed=0.25) == 1
    assert f3.step(1, 0.25, elapsed=0.5) == -1
    # phase 2 was never visited, so its budget is the remaining time 1 - 0.75 = 0.25: 0.25 < 0.25 -> -1
    assert f3.step(2, 0.25, elapsed=0.75) == -1
    f3.end_episode()
    np.testing.assert_allclose(f3.budget, [0.5, 0.25, np.nan])
    f3.reset()
    assert f3.step(1, 0.25, elapsed=0.25) == 1    # 0.25 < 0.5
    assert f3.step(1, 0.25, elapsed=0.5) == -1    # 0.5 < 0.5 is false
    state = f3.state_dict()
    restored = TimeObjective(episode_duration=1.0)
    restored.load_state_dict(state)
    np.testing.assert_array_equal(restored.budget, f3.budget)


def test_time_objective_success_reference_by_hand():
    """time_reference: success — only a successful episode sets Gamma_k, every phase at once (0
    where it did not go); until then the budget is the remaining episode time."""
    f3 = TimeObjective(episode_duration=1.0, reference="success")
    f3.reset()
    assert f3.step(1, 0.25, elapsed=0.25) == 1     # 0.25 < 1 - 0.25
    assert f3.step(3, 0.25, elapsed=0.5) == 1      # 0.25 < 0.5
    f3.end_episode(success=False)                  # a failure sets nothing
    assert np.isnan(f3.budget).all()
    f3.reset()
    assert f3.step(3, 0.25, elapsed=0.25) == 1
    f3.end_episode(success=True)                   # phase 3 took 0.25 s; 1 and 2 were skipped
    np.testing.assert_allclose(f3.budget, [0.0, 0.0, 0.25])
    f3.reset()
    assert f3.step(1, 0.25, elapsed=0.25) == -1    # 0.25 < 0 is false: phase 1 costs at once
    assert f3.step(3, 0.25, elapsed=0.5) == -1     # 0.25 < 0.25 is false
    f3.end_episode(success=False)
    np.testing.assert_allclose(f3.budget, [0.0, 0.0, 0.25])
    restored = TimeObjective(episode_duration=1.0, reference="success")
    restored.load_state_dict(f3.state_dict())
    np.testing.assert_array_equal(restored.budget, f3.budget)


def test_time_objective_rejects_an_unknown_reference():
    with pytest.raises(ValueError, match="time reference"):
        TimeObjective(episode_duration=1.0, reference="best")


def test_touches_at_the_boundaries():
    is_obstacle = np.array([False, False, True, True])
    is_toucher = np.array([False, True, False, False])
    none = np.empty((0, 2), int)
    # an obstacle moving exactly at the threshold is not pushed; no contact at all is exactly False
    assert obstacle_touched(none, is_obstacle, is_toucher, np.array([0.0, 0.5]), 0.5) is False
    assert obstacle_touched(none, is_obstacle, is_toucher, np.array([]), 0.5) is False
    # an obstacle on the table, listed obstacle first, or two obstacles together: no touch
    assert not obstacle_touched(np.array([[3, 0], [2, 3]]), is_obstacle, is_toucher, np.zeros(2), 0.5)
    # one robot contact among others is a touch
    assert obstacle_touched(np.array([[0, 3], [1, 3], [0, 2]]), is_obstacle, is_toucher, np.zeros(2), 0.5) is True


def test_progress_is_measured_from_the_table_centre():
    # target 0.5 m from the centre (1, 2): (1.3, 2.4); tip 0.1 m above it
    assert progress(np.array([1.3, 2.4, 0.4]), np.array([1.0, 2.0]), np.array([1.3, 2.4, 0.5])) == pytest.approx(0.4)


def test_progress_must_beat_the_best_by_more_than_eps_and_anything_beats_no_best():
    f2 = ProgressObjective(eps=0.25)
    assert f2.step(-5.0) == 1  # before reset the best is -inf
    f2.reset(0.0)
    assert f2.step(0.25) == -1  # exactly eps better: not more
    assert f2.step(0.5625) == 1  # 0.3125 better than 0.25


def test_time_objective_end_episode_defaults_to_a_failure_and_refuses_a_state_of_another_size():
    f3 = TimeObjective(episode_duration=1.0, reference="success")
    f3.reset()
    f3.step(1, 0.25, elapsed=0.25)
    f3.end_episode()
    assert np.isnan(f3.budget).all()
    with pytest.raises(ValueError, match=r"^time objective state has \(2,\) budgets, expected \(3,\)"):
        f3.load_state_dict({"budget": [0.5, 0.5]})
