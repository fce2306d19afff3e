"""Report statistics on crafted run records, computed by hand (the Table II metrics of one
evaluation are tested in test_evaluate.py)."""

import numpy as np
import pytest

from ahrm_stack.config import PaperRow
from ahrm_stack.report import (RunRecord, episodes_to_hold_threshold, episodes_to_threshold, findings, mean_std,
                               method_summary, orders_by_phase, rank_methods)
from ahrm_stack.report_plots import ORDER_CODES, order_index, seed_band

PAPER = {"ahrm": PaperRow(37, 40, 2, (3.8, 0.3), (0.5103, 0.0032)),
         "ls": PaperRow(4, 40, 39, (8.3, 1.1), (0.5342, 0.0219))}


def _evaluation(successes, touched, time_mean, travel_mean, interventions=10.0, violations=0, episodes=40):
    return {"episodes": episodes, "successes": successes, "success_rate": successes / episodes,
            "touched_episodes": touched, "time_mean": time_mean, "time_std": 0.1,
            "travel_mean": travel_mean, "travel_std": 0.01, "interventions_per_episode": interventions,
            "joint_limit_violations": violations}


def _run(method, seed, evaluation, status="done"):
    return RunRecord(f"{method}-seed{seed}", method, seed, status, evaluation=evaluation)


def test_mean_std_over_seeds_ignores_nan():
    assert mean_std([1.0, 3.0]) == (2.0, 1.0, 2)           # population std: sqrt(((1-2)^2+(3-2)^2)/2)
    assert mean_std([4.0, float("nan")]) == (4.0, 0.0, 1)   # a run without successes has no time
    mean, std, n = mean_std([])
    assert np.isnan(mean) and np.isnan(std) and n == 0


def test_episodes_to_threshold_by_hand():
    """Training episodes played before the first window (of 4 here) with 75 % success."""
    # windows start after 0, 1, ... episodes: [0,1,1,1]=.75 starts after 0 -> 0 (met from the start)
    assert episodes_to_threshold([0, 1, 1, 1, 0, 0, 0, 0], 0.75, 4) == 0
    # [0,0,1,1]=.5, [0,1,1,0]=.5, [1,1,0,1]=.75 starts after 2 episodes -> 2
    assert episodes_to_threshold([0, 0, 1, 1, 0, 1, 0, 0], 0.75, 4) == 2
    assert episodes_to_threshold([1, 1, 1], 0.5, 4) is None          # the window is never full
    assert episodes_to_threshold([0, 1, 0, 1, 0, 1], 0.8, 2) is None  # never 80 %


def test_episodes_to_threshold_returns_more_than_its_floor():
    """The bug: every warm-started run read 20 (the window, the smallest value it could return),
    whether it learned or not. Now the floor is 0 (met from the first episode), and a run that
    learns later reads the episodes it played before: 30 failures, then successes, window 20 at
    80 %: the first window with 16 successes starts after 26 episodes."""
    success = [False] * 30 + [True] * 40
    first = episodes_to_threshold(success, 0.8, 20)
    # the window starting after k episodes holds 20 - (30 - k) successes for 10 <= k <= 30: >= 16 from k = 26
    assert first == 26 and first > 0
    assert episodes_to_threshold([True] * 40, 0.8, 20) == 0  # the warm start: no training needed
    assert episodes_to_hold_threshold(success, 0.8, 20) == 26


def test_holding_the_threshold_needs_it_until_the_end():
    collapsed = [True] * 20 + [False] * 20  # a warm start that training destroyed
    assert episodes_to_threshold(collapsed, 0.8, 4) == 0
    assert episodes_to_hold_threshold(collapsed, 0.8, 4) is None
    recovered = [1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1]  # windows from 7 on: .75, 1.0
    assert episodes_to_hold_threshold(recovered, 0.75, 4) == 7
    assert episodes_to_hold_threshold([1, 1, 1, 1, 1], 0.75, 4) == 0
    assert episodes_to_hold_threshold([1, 1], 0.75, 4) is None  # no full window


def test_orders_by_phase():
    assert orders_by_phase("AMT TAM MAT") == ["avoid > manipulate > time", "time > avoid > manipulate",
                                              "manipulate > avoid > time"]
    assert order_index("AMT TAM MAT", 1) == ORDER_CODES.index("TAM")
    with pytest.raises(ValueError, match="letters A, M, T"):
        orders_by_phase("AMX AMT AMT")


def test_method_summary_over_seeds_by_hand():
    runs = [_run("ahrm", 0, _evaluation(30, 2, 4.0, 0.50, interventions=10.0)),
            _run("ahrm", 1, _evaluation(20, 4, 6.0, 0.52, interventions=30.0, violations=1)),
            _run("ahrm", 2, None, status="failed")]
    s = method_summary(runs)
    assert s["seeds"] == 3 and s["seeds_done"] == 2          # the failed run is left out
    assert s["successes"] == (25.0, 5.0, 2)
    assert s["success_rate"][0] == pytest.approx(0.625) and s["success_rate"][1] == pytest.approx(0.125)
    assert s["touched_episodes"] == (3.0, 1.0, 2)
    assert s["time_mean"] == (5.0, 1.0, 2)
    assert s["travel_mean"][0] == pytest.approx(0.51) and s["travel_mean"][1] == pytest.approx(0.01)
    assert s["interventions_per_episode"] == (20.0, 10.0, 2)
    assert s["joint_limit_violations"] == (0.5, 0.5, 2)


def test_findings_say_plainly_when_ahrm_is_not_first_and_below_the_paper():
    runs = [_run("ahrm", 0, _evaluation(10, 5, 5.0, 0.5)), _run("ls", 0, _evaluation(20, 9, 6.0, 0.5)),
            _run("ls", 1, None, status="failed")]
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in ("ahrm", "ls")}
    assert rank_methods(summaries) == ["ls", "ahrm"]
    text = "\n".join(findings(summaries, PAPER, runs))
    assert "AHRM is not the best method here" in text and "ranks 2 of 2" in text
    assert "below the paper's 92.5%" in text
    assert "LS: 50.0% here vs 10.0% in the paper" in text
    assert "1 run(s) failed** (ls-seed1)" in text


def test_findings_when_ahrm_leads_and_reaches_the_paper():
    runs = [_run("ahrm", 0, _evaluation(38, 1, 3.9, 0.51)), _run("ls", 0, _evaluation(5, 30, 8.0, 0.53))]
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in ("ahrm", "ls")}
    text = "\n".join(findings(summaries, PAPER, runs))
    assert "AHRM ranks first of 2" in text and "reaches the paper's 92.5%" in text
    assert "not the best" not in text and "below" not in text


def test_seed_band_on_the_common_episodes():
    episode, mean, std = seed_band([np.array([0.0, 1.0, 1.0]), np.array([1.0, 1.0])])
    assert episode.tolist() == [1, 2] and mean.tolist() == [0.5, 1.0] and std.tolist() == [0.5, 0.0]


def test_findings_name_a_tie_on_success_rate_and_the_touch_tiebreak():
    # all methods at 0 successes: the order comes from touches alone (LS 6 < AHRM 39), and the text
    # must say so instead of calling LS the best by success rate
    runs = [_run("ahrm", 0, _evaluation(0, 39, float("nan"), 0.01)),
            _run("ls", 0, _evaluation(0, 6, float("nan"), 0.001))]
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in ("ahrm", "ls")}
    assert rank_methods(summaries) == ["ls", "ahrm"]
    text = "\n".join(findings(summaries, PAPER, runs))
    assert "No method succeeded in any evaluation episode" in text
    assert "AHRM ties with LS on mean evaluation success rate (0.0%)" in text
    assert "touching an obstacle: LS 6.0, AHRM 39.0) it ranks 2 of 2" in text
    assert "it is not the best method here" in text and "below the paper's 92.5%" in text


def test_findings_when_ahrm_ties_for_first_and_wins_the_tiebreak():
    runs = [_run("ahrm", 0, _evaluation(40, 0, 4.0, 0.5)), _run("ls", 0, _evaluation(40, 3, 4.5, 0.5))]
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in ("ahrm", "ls")}
    text = "\n".join(findings(summaries, PAPER, runs))
    assert "AHRM ties with LS on mean evaluation success rate (100.0%): it is not ahead of them" in text
    assert "it ranks 1 of 2" in text and "No method succeeded" not in text


def test_findings_when_every_figure_ties():
    runs = [_run("ls", 0, _evaluation(40, 0, 4.5, 0.5)), _run("ahrm", 0, _evaluation(40, 0, 4.0, 0.5))]
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in ("ls", "ahrm")}
    text = "\n".join(findings(summaries, PAPER, runs))
    assert "(100.0%): it is not ahead of them" in text and "they tie on it too" in text
    assert "not the best" not in text and "ranks" not in text.split("\n")[0]
