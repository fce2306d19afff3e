"""The robustness evaluation (python -m ahrm_stack.robustness): its conditions come from
configs/realism.yaml, an episode runs through the real deploy loop on the sim backend and is
counted in the simulator, bad input is one line, and every committed table under
docs/robustness/ is what the code makes of its committed data."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from ahrm_stack import robustness
from ahrm_stack.realism import GROUPS, RealismConfig, realism_profiles
from ahrm_stack.schema import ConfigError

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "robustness"


def test_conditions_are_the_profile_one_group_at_a_time_then_all_then_the_doses():
    rows = robustness.conditions("jaco2", dose=True)
    names = [r.name for r in rows]
    assert names[0] == "ideal" and rows[0].realism.is_ideal
    assert names[1:1 + len(GROUPS)] == list(GROUPS)
    jaco2 = realism_profiles()["jaco2"]
    assert rows[1 + len(GROUPS)].realism == jaco2
    for row in rows[1:1 + len(GROUPS)]:
        assert row.realism == jaco2.only(row.name)
    doses = [r for r in rows if r.kind == "dose"]
    assert {r.realism.velocity_noise_deg_s for r in doses} >= {5.0}
    assert {r.realism.angle_noise_deg for r in doses} >= {0.5}
    assert len(robustness.conditions("jaco2", dose=False)) == 2 + len(GROUPS)


def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    with pytest.raises(ConfigError, match="--profile 'nope'"):
        robustness.conditions("nope")
    assert robustness.main([str(tmp_path)]) == 2
    assert "no config.yaml" in capsys.readouterr().err
    assert robustness.main([str(ROOT / "docs" / "policies" / "ahrm-default-seed0"), "--profile", "nope",
                            "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()
    assert robustness.main(["--render", str(tmp_path)]) == 2


def test_an_episode_runs_through_the_deploy_loop_and_is_counted_in_the_simulator():
    seed = 4_200_000
    jaco2 = realism_profiles()["jaco2"]
    records = robustness._episodes((None, "scripted", jaco2.to_dict(), [seed], 30.0))
    (record,) = records
    assert record["seed"] == seed and record["controller"] == "scripted"
    assert record["success"] and not record["touched"] and 1.0 < record["time"] < 10.0
    assert record["judged_success"]  # the loop's perception-based verdict agrees here
    assert abs(record["cube_final"][0]) > 0.45 or abs(record["cube_final"][1]) > 0.45


def _records(times: list[float | None], touched: int = 0) -> list[dict]:
    """Episodes on seeds 0.. with these times to success (None: a failure)."""
    return [{"seed": i, "success": t is not None, "time": t, "touched": i < touched, "judged_success": t is not None,
             "emergency_stops": 0} for i, t in enumerate(times)]


def test_the_goal_per_condition():
    scripted = _records([3.7] * 30)
    assert robustness.meets_goal(_records([3.5] * 29 + [None], touched=1), scripted)
    assert not robustness.meets_goal(_records([3.5] * 28 + [None] * 2), scripted)  # 2 fewer successes
    assert not robustness.meets_goal(_records([3.5] * 30, touched=2), scripted)  # touching 2 > 1
    assert not robustness.meets_goal(_records([3.8] * 30), scripted)  # slower
    assert robustness.meets_goal(_records([None] * 30), _records([None] * 30))
    # time on the episodes both won: a policy that also wins the scripted controller's failures
    # (slowly) is compared where both won
    hard = _records([3.0] * 15 + [9.0] * 15)
    assert robustness.meets_goal(hard, _records([3.5] * 15 + [None] * 15))
    assert robustness.paired_times(hard, _records([3.5] * 15 + [None] * 15)) == (3.0, 3.5, 15)
    assert math.isnan(robustness.Row.of(_records([None] * 3)).mean_time)


def _committed() -> list[Path]:
    return sorted(DOCS.glob("*/robustness/robustness.json"))


def test_the_committed_tables_are_generated_from_the_committed_data():
    folders = _committed()
    assert folders, "docs/robustness holds the study's rows"
    for source in folders:
        data = json.loads(source.read_text())
        assert (source.parent / "robustness.md").read_text() == robustness.table(data), source
    import importlib.util

    spec = importlib.util.spec_from_file_location("robustness_study", ROOT / "studies" / "robustness_study.py")
    study = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(study)
    assert (DOCS / "summary.md").read_text() == study.summary(DOCS)


def test_every_committed_row_ran_every_condition_for_both_controllers():
    for source in _committed():
        data = json.loads(source.read_text())
        for name in data["conditions"]:
            for controller in robustness.CONTROLLERS:
                rows = [r for r in data["records"] if r["condition"] == name and r["controller"] == controller]
                assert len(rows) == data["episodes"], (source, name, controller)
                assert [r["seed"] for r in rows] == data["seeds"]
        assert RealismConfig.from_dict(data["realism"]["ideal"]).is_ideal
