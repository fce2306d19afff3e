"""studies/suite_compare.py: the paired differences on hand-made suites, checked by hand."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).parents[1] / "studies" / "suite_compare.py"
SPEC = importlib.util.spec_from_file_location("suite_compare", SCRIPT)
assert SPEC is not None and SPEC.loader is not None
suite_compare = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(suite_compare)


def _suite(folder: Path, episodes: dict[str, list[tuple[bool, int, float]]]) -> Path:
    for family, rows in episodes.items():
        (folder / family).mkdir(parents=True)
        lines = ["success,touched_steps,time_to_success"]
        lines += [f"{s},{t},{time if s else 'nan'}" for s, t, time in rows]
        (folder / family / "evaluation.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_differences_by_hand(tmp_path, capsys):
    a = _suite(tmp_path / "a", {"x": [(True, 0, 3.0), (False, 2, 0.0)], "y": [(True, 1, 2.0)]})
    b = _suite(tmp_path / "b", {"x": [(True, 0, 2.5), (True, 0, 4.0)], "y": [(True, 3, 1.0)]})
    families = ["x", "y"]
    pairs = [(suite_compare.load_suite(a, families), suite_compare.load_suite(b, families))]
    successes, touching, time = suite_compare.differences(pairs)
    # by hand: B wins 3 of 3, A 2 of 3 -> +1; B touches in 1 episode, A in 2 -> -1;
    # both won x[0] (2.5 - 3.0) and y[0] (1.0 - 2.0): mean -0.75 s
    assert (successes, touching, time) == (1.0, -1.0, -0.75)
    assert suite_compare.main([str(a), "--", str(b), "--samples", "50"]) == 0
    out = capsys.readouterr().out
    assert "successes per suite: +1.00" in out and "time to success (s, both won): -0.75" in out


def test_bootstrap_of_identical_pairs_is_zero(tmp_path):
    rows = {"x": [(True, 0, 3.0), (True, 1, 2.0), (False, 0, 0.0)]}
    a = suite_compare.load_suite(_suite(tmp_path / "a", rows), ["x"])
    boots = suite_compare.bootstrap([a, a], [a, a], samples=20)
    assert np.all(boots == 0.0)


def test_unpaired_folders_are_refused(tmp_path):
    a = _suite(tmp_path / "a", {"x": [(True, 0, 3.0)]})
    with pytest.raises(SystemExit, match="pair them by seed"):
        suite_compare.main([str(a), str(a), "--", str(a)])
