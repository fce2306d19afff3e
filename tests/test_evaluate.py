"""Evaluation: Table II metrics on crafted episode records (by hand), and the CLI end to end."""

import json

import numpy as np
import pytest

from ahrm_stack.env.episode import EpisodeSummary
from ahrm_stack.evaluate import main as evaluate
from ahrm_stack.learning.rollouts import EvaluationTable
from ahrm_stack.train import main as train


def _episode(success, time, touched, travel, interventions=0, violations=0):
    return EpisodeSummary(
        steps=10, duration=time, success=success, time_to_success=time if success else float("nan"),
        touched_steps=touched, learning_return=0.0, phase_steps=[10, 0, 0], phases_visited="1",
        component_sums=[[0.0] * 3] * 3, closest_approach=0.1, cube_displacement=0.5,
        cube_travel=travel, constraint_terminated=False, constraint_phase=None,
        interventions=interventions, joint_limit_violations=violations)


def test_table_metrics_by_hand():
    table = EvaluationTable.from_summaries([
        _episode(True, 3.0, 0, 0.50, 10), _episode(True, 5.0, 2, 0.52, 20),
        _episode(False, 60.0, 1, 0.0, 30, 1), _episode(False, 60.0, 0, 0.02, 0)])
    assert table.episodes == 4 and table.successes == 2 and table.success_rate == 0.5
    assert table.touched_episodes == 2
    assert table.time_mean == pytest.approx(4.0) and table.time_std == pytest.approx(1.0)
    # travel over all episodes: mean of (0.5, 0.52, 0, 0.02) = 0.26; population std by hand
    assert table.travel_mean == pytest.approx(0.26)
    assert table.travel_std == pytest.approx(np.std([0.5, 0.52, 0.0, 0.02]))
    assert table.interventions_per_episode == pytest.approx(15.0)
    assert table.joint_limit_violations == 1


def test_scripted_evaluation_cli(tmp_path):
    assert evaluate(["--policy", "scripted", "--episodes", "2", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "evaluation.json").read_text())
    assert result["episodes"] == 2 and result["successes"] == 2 and result["joint_limit_violations"] == 0
    assert len((tmp_path / "evaluation.csv").read_text().strip().splitlines()) == 3


def test_scripted_evaluation_takes_config_overrides(tmp_path, capsys):
    """``--config`` reaches the scripted controller's config, a profile included: a 1 s episode
    cannot push the cube off (the controller needs ~4 s), so both episodes end unsuccessful at 1 s."""
    assert evaluate(["--policy", "scripted", "--episodes", "2", "--out", str(tmp_path),
                     "--config", "profile=paper", "task.episode.duration=1"]) == 0
    result = json.loads((tmp_path / "evaluation.json").read_text())
    assert result["episodes"] == 2 and result["successes"] == 0
    rows = (tmp_path / "evaluation.csv").read_text().strip().splitlines()
    header = rows[0].split(",")
    durations = [float(row.split(",")[header.index("duration")]) for row in rows[1:]]
    assert durations == pytest.approx([1.0, 1.0])
    assert evaluate(["--policy", "scripted", "--config", "task.nonsense=1"]) == 2
    assert "task.nonsense" in capsys.readouterr().err


def test_run_evaluation_cli(tmp_path):
    run = tmp_path / "run"
    assert train(["ppo.hidden_sizes=[16]", "ppo.frames_per_batch=128", "task.episode.duration=2",
                  "train.warm_start=none", "ppo.bc_coeff=0",
                  "train.episodes=2", "train.eval_episodes=0", "--run-dir", str(run), "--no-progress"]) == 0
    assert evaluate([str(run), "--episodes", "2"]) == 0
    assert json.loads((run / "evaluation.json").read_text())["episodes"] == 2
    assert evaluate([str(tmp_path / "missing")]) == 2
