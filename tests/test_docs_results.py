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
