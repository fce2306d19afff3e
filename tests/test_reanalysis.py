"""studies/reanalysis.py: its committed tables are what the committed data give, and its episode-level
statistics agree with closed forms on small cases."""

import importlib.util
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("reanalysis", ROOT / "studies" / "reanalysis.py")
reanalysis = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(reanalysis)


def test_the_committed_page_and_data_are_what_the_committed_files_give():
    data = reanalysis.collect()
    committed = json.loads((ROOT / "docs" / "reanalysis" / "data.json").read_text())
    assert json.loads(json.dumps(data)) == committed
    page = reanalysis.PAGE.read_text()
    assert reanalysis.render(page, data) == page, "run python studies/reanalysis.py"


def test_the_counts_match_the_per_run_files():
    e = reanalysis.experiment()
    assert e["gap"][0] < e["learned_share"] <= e["gap"][1]
    assert [e["methods"][m]["learned"] for m in reanalysis.METHODS] == [5, 4, 4, 4]
    d = reanalysis.default_policy()
    assert d["episodes"] == 800 and d["success"]["teacher_events"] == 791
    assert (d["success"]["sign_test"]["above"], d["success"]["sign_test"]["below"]) == (9, 14)
    cap = reanalysis.teacher_at_cap()  # the teacher at the policy's cap: the ledger's counts (20 x 40)
    assert (cap["episodes"], cap["successes"], cap["touching"]) == (800, 793, 1)
    assert set(reanalysis.ppo_over_clone()["seeds"]) == {0, 1, 2, 3, 4}


def test_the_sign_test_and_the_bootstrap_against_closed_forms():
    sign = reanalysis._sign_test(np.array([1, 1, 1, 0, 0.5]), np.array([0, 0, 0, 1, 0.5]))
    assert (sign["above"], sign["below"]) == (3, 1) and abs(sign["p"] - 0.625) < 1e-12  # 2 * 5/16
    rng = np.random.default_rng(0)
    a = np.ones((3, 50))
    assert reanalysis._two_way_bootstrap(a, np.zeros((1, 50)), rng) == [1.0, 1.0]  # no variance at all
    b = (rng.random((4, 400)) < 0.5).astype(float)
    low, high = reanalysis._two_way_bootstrap(b, None, rng)
    assert low < b.mean() < high and high - low < 0.2
