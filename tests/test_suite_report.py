"""The suite section of the report: per-family means and paired bootstrap intervals."""

import numpy as np

from ahrm_stack.suite_report import family_means, paired_difference, rank, suite_section


def _suite(success, touched=None, time=None):
    success = np.asarray(success, dtype=float)
    touched = np.zeros_like(success) if touched is None else np.asarray(touched, dtype=float)
    time = np.where(success > 0, 4.0, np.nan) if time is None else np.asarray(time, dtype=float)
    return {"success": success, "touched": touched, "time": time}


def test_identical_methods_differ_by_exactly_zero():
    a = [{"f": _suite([1, 0, 1, 1])}, {"f": _suite([1, 1, 0, 1])}]
    d, lo, hi = paired_difference(a, a, ["f"], "success", 200, np.random.default_rng(0))
    assert d == lo == hi == 0.0


def test_a_constant_paired_difference_has_a_zero_width_interval():
    a = [{"f": _suite([1, 1, 1, 1], time=[3, 3, 3, 3])}] * 2
    b = [{"f": _suite([0, 1, 0, 1], time=[np.nan, 4, np.nan, 4])}] * 2
    d, lo, hi = paired_difference(a, b, ["f"], "success", 200, np.random.default_rng(0))
    assert d == 0.5  # hand: (1-0 + 1-1 + 1-0 + 1-1) / 4
    assert 0.0 <= lo <= d <= hi <= 1.0
    t, tlo, thi = paired_difference(a, b, ["f"], "time", 200, np.random.default_rng(0))
    assert t == tlo == thi == -1.0  # only the episodes both succeeded in: 3 - 4 each


def test_interval_matches_a_direct_two_level_bootstrap():
    rng = np.random.default_rng(1)
    a = [{"f": _suite(rng.random(40) < 0.9)} for _ in range(3)]
    b = [{"f": _suite(rng.random(40) < 0.5)} for _ in range(3)]
    d, lo, hi = paired_difference(a, b, ["f"], "success", 500, np.random.default_rng(7))
    diffs = [x["f"]["success"] - y["f"]["success"] for x, y in zip(a, b)]
    check = np.random.default_rng(7)
    stats = []
    for _ in range(500):  # the same procedure written out: seeds, then episodes within each
        seeds = check.integers(3, size=3)
        stats.append(np.mean(np.concatenate([diffs[s][check.integers(40, size=40)] for s in seeds])))
    assert d == np.mean(np.concatenate(diffs))
    np.testing.assert_allclose([lo, hi], np.percentile(stats, [2.5, 97.5]))
    assert lo > 0  # 0.9 against 0.5 over 120 paired episodes


def test_family_means_and_rank_and_the_section():
    ahrm = [{"f": _suite([1, 1, 1, 0], touched=[0, 0, 0, 1])}, {"f": _suite([1, 1, 1, 1])}]
    ls = [{"f": _suite([0, 1, 0, 0])}, {"f": _suite([1, 0, 0, 0])}]
    means = family_means(ahrm, "f")
    assert means["successes"] == 3.5 and means["touched"] == 0.5 and means["time"] == 4.0
    assert rank({"ahrm": ahrm, "ls": ls}, ["f"], ["ls", "ahrm"]) == ["ahrm", "ls"]
    text = "\n".join(suite_section({"ahrm": ahrm, "ls": ls, "scripted": [{"f": _suite([1] * 4)}]},
                                   ["f"], ["ahrm", "ls"], 100))
    assert "| f | 3.5 | 1.0 | 4.0 |" in text
    assert "| LS | 62.5 pp" in text  # (3/4 + 4/4) / 2 - (1/4 + 1/4) / 2 = 0.875 - 0.25
    assert "| scripted | -12.5 pp" in text


def test_the_section_shows_each_familys_training_support(tmp_path):
    import json

    from ahrm_stack.suite_report import read_support

    for family, verdict in (("heldout", "inside"), ("cube_heavy", "outside: cube_mass")):
        (tmp_path / family).mkdir()
        (tmp_path / family / "evaluation.json").write_text(json.dumps({"training_support": {"verdict": verdict}}))
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "evaluation.json").write_text("{}")  # evaluated before the support was computed
    support = read_support(tmp_path)
    assert support == {"heldout": "inside", "cube_heavy": "outside: cube_mass"}
    suites = [{"heldout": _suite([1, 1]), "cube_heavy": _suite([1, 0]), "old": _suite([0, 0])}]
    text = "\n".join(suite_section({"ahrm": suites, "ls": suites}, ["heldout", "cube_heavy", "old"],
                                   ["ahrm", "ls"], 10, support=support))
    assert "| family | training support | AHRM | LS |" in text
    assert "| cube_heavy | outside: cube_mass | 1.0 | 1.0 |" in text and "| old | – | 0.0 | 0.0 |" in text
    assert "| **sum** | | 3.0 | 3.0 |" in text
    assert "| family | AHRM | LS |" in text  # the other tables as before
