"""docs/results.md's headline tables are what the committed evaluation files give
(tools/results_headlines.py), and its pages say which evaluation split the figures are on."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _tool():
    spec = importlib.util.spec_from_file_location("results_headlines", ROOT / "tools" / "results_headlines.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_generated_block_is_up_to_date() -> None:
    tool = _tool()
    text = (ROOT / "docs" / "results.md").read_text()
    assert tool.render(text) == text, "docs/results.md is out of date: run python tools/results_headlines.py"


def test_suite_counts_read_policy_and_scripted_columns(tmp_path: Path) -> None:
    tool = _tool()
    report = tmp_path / "suite.md"
    report.write_text("Evaluation suite of X\n\n| family | policy successes | touching | time (s) | scripted successes "
                      "| touching | time (s) | time / scripted |\n|---|---|---|---|---|---|---|---|\n"
                      "| default | 38/40 | 2 | 2.9 ± 0.3 | 40/40 | 0 | 3.6 ± 0.4 | 0.80 |\n"
                      "| corridor | 40/40 | 1 | 2.8 ± 0.3 | 39/40 | 3 | 3.5 ± 0.4 | 0.80 |\n")
    counts = tool.suite_counts(report)
    assert counts["default"] == (38, 40, 2)
    assert counts["scripted:corridor"] == (39, 40, 3)
    assert tool._total(counts) == (78, 80, 3)
    assert tool._total(counts, scripted=True) == (79, 80, 3)


def test_results_page_names_the_split() -> None:
    text = (ROOT / "docs" / "results.md").read_text()
    assert "validation" in text and "`test`" in text
    readme = (ROOT / "README.md").read_text()
    assert "validation" in readme and "test split" in readme


def test_the_readme_test_split_table_is_up_to_date() -> None:
    tool = _tool()
    text = (ROOT / "README.md").read_text()
    assert tool.render_readme(text) == text, ("README.md's test-split table is out of date: run "
                                              "python tools/results_headlines.py")


def test_test_split_rows_pool_paired_episodes(tmp_path: Path) -> None:
    """Two families of 3 episodes: the pooled counts, the discordant pairs and the exact sign test
    (2 vs 0 discordant: p = 0.5, the closed form 2 x 0.5^2), the interval from scipy's exact test."""
    import json

    header = "success,touched_steps,time_to_success\n"
    policy = {"a": ["True,0,2.0", "True,1,2.0", "True,0,3.0"], "b": ["True,0,1.0", "False,0,", "True,0,2.0"]}
    scripted = {"a": ["True,0,4.0", "False,0,", "True,0,3.0"], "b": ["False,0,", "False,0,", "True,0,4.0"]}
    folder = tmp_path / "suite"
    for family in ("a", "b"):
        (folder / family / "scripted").mkdir(parents=True)
        (folder / family / "evaluation.csv").write_text(header + "\n".join(policy[family]) + "\n")
        (folder / family / "scripted" / "evaluation.csv").write_text(header + "\n".join(scripted[family]) + "\n")
    support = {"a": True, "b": False}
    (folder / "suite.json").write_text(json.dumps({
        "split": "test", "families": ["a", "b"],
        "results": {f: {"training_support": {"inside": inside}} for f, inside in support.items()}}))
    tool = _tool()
    rows = tool.test_split_rows(tmp_path, ("suite",))
    all_row = rows[2]
    assert all_row.startswith("| all families (2) | 5/6 [35.9, 99.6] % | 1 [0.4, 64.1] % | 3/6 | 0 | 2 / 0 (p = 0.5) ")
    assert all_row.endswith("| 1 / 0 (p = 1) | 0.67 |")  # (2/4 + 3/3 + 2/4) / 3: the episodes both won
    assert rows[3].startswith("| inside the training support (1) | 3/3 ")
    assert rows[4].startswith("| outside it (partly or wholly) (1) | 2/3 ")


def _write_suite(folder: Path, policy: dict[str, list[str]], scripted: dict[str, list[str]]) -> None:
    import json

    header = "success,touched_steps,time_to_success\n"
    for family in policy:
        (folder / family / "scripted").mkdir(parents=True)
        (folder / family / "evaluation.csv").write_text(header + "\n".join(policy[family]) + "\n")
        (folder / family / "scripted" / "evaluation.csv").write_text(header + "\n".join(scripted[family]) + "\n")
    (folder / "suite.json").write_text(json.dumps({
        "split": "test", "families": list(policy),
        "results": {f: {"training_support": {"inside": True}} for f in policy}}))


def test_test_split_rows_pool_every_seed_first_and_give_seed_level_intervals(tmp_path: Path) -> None:
    """Two seeds on the same two scripted episodes: the policy pooled over both (4 episodes), the
    scripted controller counted once (2), the discordant pairs of both seeds, and the seed-level
    t-interval in closed form: gains (2-1)/2 = 0.5 and (1-1)/2 = 0, mean 0.25, sd 0.3536,
    half-width t(0.975, 1) x 0.3536 / sqrt 2 = 12.706 x 0.25 = 3.177."""
    scripted = {"a": ["True,0,4.0", "False,0,"]}
    _write_suite(tmp_path / "seed0", {"a": ["True,0,2.0", "True,1,2.0"]}, scripted)
    _write_suite(tmp_path / "seed1", {"a": ["True,0,4.0", "False,0,"]}, scripted)
    tool = _tool()
    rows = tool.test_split_rows(tmp_path, ("seed0", "seed1"))
    assert rows[0].startswith("| families (40 test episodes each) | policy successes, 2 seeds pooled |")
    assert rows[2].startswith("| all families (1) | 3/4 ")
    assert "| 1/2 | 0 | 1 / 0 (p = 1) |" in rows[2]
    assert rows[7] == "| 0 | 2/2 | 1 | 1 / 0 (p = 1) | 0.50 |"
    assert rows[8] == "| 1 | 1/2 | 0 | 0 / 0 (p = 1) | 1.00 |"
    assert "success share minus the scripted controller's +0.250 [-2.927, +3.427], not established" in rows[10]
    assert "time / scripted (both won) 0.750 [-2.427, 3.927], not established" in rows[10]


def test_test_split_rows_refuse_seeds_on_other_episodes(tmp_path: Path) -> None:
    """A seed whose scripted results differ was not evaluated on the same test episodes: refused."""
    import pytest

    _write_suite(tmp_path / "seed0", {"a": ["True,0,2.0"]}, {"a": ["True,0,4.0"]})
    _write_suite(tmp_path / "seed1", {"a": ["True,0,2.0"]}, {"a": ["False,0,"]})
    with pytest.raises(ValueError, match="not the episodes of seed 0"):
        _tool().test_split_rows(tmp_path, ("seed0", "seed1"))


def test_a_seed_level_interval_that_excludes_the_null_is_established() -> None:
    """Three seeds 0.10, 0.12, 0.14: mean 0.12, sd 0.02, half-width t(0.975, 2) x 0.02 / sqrt 3 =
    4.303 x 0.01155 = 0.0497: [0.070, 0.170] excludes 0; a ratio interval around 1 does not."""
    tool = _tool()
    assert tool._t_interval([0.10, 0.12, 0.14]) == "+0.120 [+0.070, +0.170], established"
    assert tool._t_interval([0.9, 1.1, 1.0], sign="", null=1.0).endswith(", not established")
    assert tool._t_interval([0.5]) == "+0.500 (one seed: no interval)"


def test_robustness_rows_read_the_all_row_and_count_the_met_conditions(tmp_path: Path) -> None:
    header = ("| condition | policy: success | touching | time (s) | judged wrong | e-stops | scripted: success | "
              "touching | time (s) | judged wrong | paired time (s) | goal |\n" + "|---" * 12 + "|\n")
    (tmp_path / "r.md").write_text(
        "Robustness of X\n\n" + header
        + "| ideal | 30/30 | 1 | 2.8 | 0 | 0 | 30/30 | 0 | 3.7 | 0 | 2.8 / 3.7 (30) | met |\n"
        + "| all (jaco2) | 28/30 | 2 | 3.4 | 0 | 0 | 29/30 | 1 | 4.1 | 0 | 3.4 / 4.1 (27) | **missed** |\n")
    rows = _tool().robustness_rows(tmp_path, {"3": "r.md"})
    assert rows[2] == "| 3 | 28/30 | 2 | 29/30 | 1 | 1 of 2 |"
