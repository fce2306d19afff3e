"""studies/physics_fidelity.py: the committed report is what its committed data give, and its
measures against closed forms."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fidelity():
    spec = importlib.util.spec_from_file_location("physics_fidelity", ROOT / "studies" / "physics_fidelity.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["physics_fidelity"] = module
    spec.loader.exec_module(module)
    return module


def test_the_committed_report_is_generated_from_the_committed_data(fidelity, monkeypatch):
    monkeypatch.chdir(ROOT)  # the report names its data folder as given
    text = fidelity.report(Path("docs/physics-fidelity/data"), None)
    assert (ROOT / "docs" / "physics-fidelity.md").read_text() == text


def test_the_path_gap_is_the_symmetric_hausdorff_distance_of_the_vertices(fidelity):
    a = [[0.0, 0.0], [1.0, 0.0]]
    b = [[0.0, 0.3], [1.0, 0.0], [2.0, 0.0]]
    assert fidelity._path_gap(a, b) == pytest.approx(1.0)  # b's (2, 0) is 1 from a's nearest vertex
    assert fidelity._path_gap(a, a) == 0.0


def test_the_sign_test_and_the_time_ratio(fidelity):
    assert fidelity._sign_p(0, 0) == 1.0
    assert fidelity._sign_p(0, 5) == pytest.approx(2 / 32)  # two-sided, all five discordant one way
    pairs = [({"time": 2.0}, {"time": 3.0}), ({"time": 4.0}, {"time": 3.0})]
    assert fidelity._time_ratio(pairs) == pytest.approx(1.0)
