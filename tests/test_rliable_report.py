"""docs/rliable.md's tables are rliable's estimates on the committed runs of experiment 42
(studies/rliable_report.py): regenerated here from docs/experiment-42/data and compared; and rliable's
interquartile mean and probability of improvement agree with their closed forms on those runs."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

pytest.importorskip("rliable")
ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("rliable_report", ROOT / "studies" / "rliable_report.py")
report = importlib.util.module_from_spec(spec)
sys.modules["rliable_report"] = report
spec.loader.exec_module(report)


@pytest.fixture(scope="module")
def result():
    return report.analyse(report.load())


def test_the_committed_tables_are_regenerated(result):
    committed = report.PAGE.read_text()
    assert report.render(committed, result) == committed, (
        "docs/rliable.md is out of date: python studies/rliable_report.py")
    data = json.loads((report.OUT / "rliable.json").read_text())
    assert data == json.loads(json.dumps(result))  # every estimate, the curves and profile too
    for figure in ("learning-curves.png", "performance-profile.png"):
        assert (report.OUT / figure).stat().st_size > 10_000


def test_the_estimates_match_their_closed_forms(result):
    for method in report.METHODS:
        runs = np.array(result["success"][method]["runs"])
        assert result["success"][method]["iqm"] == pytest.approx(stats.trim_mean(runs, 0.25), abs=1e-4)
        assert result["success"][method]["mean"] == pytest.approx(runs.mean(), abs=1e-4)
    ahrm = np.array(result["success"]["ahrm"]["runs"])
    for method in ("mhrm", "fhrm", "ls"):
        other = np.array(result["success"][method]["runs"])
        wins = np.mean([(a > b) + 0.5 * (a == b) for a in ahrm for b in other])
        assert result["improvement"][f"ahrm>{method}"]["p"] == pytest.approx(wins, abs=1e-9)
        low, high = result["improvement"][f"ahrm>{method}"]["ci"]
        assert low <= wins <= high
