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
    tool.DEFAULT_TEST_SUITE = "suite"
    rows = tool.test_split_rows(tmp_path)
    all_row = rows[2]
    assert all_row.startswith("| all families (2) | 5/6 [35.9, 99.6] % | 1 [0.4, 64.1] % | 3/6 | 0 | 2 / 0 (p = 0.5) ")
    assert all_row.endswith("| 1 / 0 (p = 1) | 0.67 |")  # (2/4 + 3/3 + 2/4) / 3: the episodes both won
    assert rows[3].startswith("| inside the training support (1) | 3/3 ")
    assert rows[4].startswith("| outside it (partly or wholly) (1) | 2/3 ")
