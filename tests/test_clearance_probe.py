"""studies/clearance_probe.py: its replay of a run's own evaluation is that evaluation (the same
successes and touched steps per episode, from evaluation.csv), and its clearances are the task's."""

import csv
import importlib.util
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module():
    spec = importlib.util.spec_from_file_location("clearance_probe", ROOT / "studies" / "clearance_probe.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_replay_is_the_runs_own_evaluation(tmp_path, capsys):
    from ahrm_stack.train import main as train

    run = tmp_path / "run"
    assert train(["ppo.hidden_sizes=[16]", "ppo.frames_per_batch=64", "train.warm_start=none", "ppo.bc_coeff=0",
                  "task.episode.duration=3", "train.episodes=2", "train.eval_episodes=3",
                  "--run-dir", str(run), "--no-progress"]) == 0
    with open(run / "evaluation.csv") as handle:
        evaluated = list(csv.DictReader(handle))
    module = _module()
    rows = module.probe(run, 3, None, scripted=False, reach=0.05)
    assert [r["success"] for r in rows] == [int(e["success"] == "True") for e in evaluated]
    assert [r["touched_steps"] for r in rows] == [int(e["touched_steps"]) for e in evaluated]
    for row in rows:
        assert math.isfinite(row["cube_clearance"]) and math.isfinite(row["pusher_clearance"])
    capsys.readouterr()
    out_csv = tmp_path / "probe.csv"
    assert module.main([str(run), "--episodes", "3", "--out", str(out_csv)]) == 0
    assert capsys.readouterr().out.startswith("episodes 3: ")
    assert len(out_csv.read_text().splitlines()) == 4


def test_a_folder_without_a_config_is_a_one_line_error(tmp_path, capsys):
    import pytest

    with pytest.raises(SystemExit) as exit_info:
        _module().main([str(tmp_path)])
    assert exit_info.value.code == 2
    assert "no config.yaml" in capsys.readouterr().err


def test_pair_counts_discordant_near_misses(tmp_path, capsys):
    module = _module()
    header = "episode,success,touched_steps,cube_clearance,pusher_clearance\n"
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    # nearest approach per episode: A 0.004, 0.015, 0.04; B 0.04, 0.015, 0.008
    a.write_text(header + "0,1,0,0.004,0.1\n1,1,0,0.2,0.015\n2,1,0,0.04,0.05\n")
    b.write_text(header + "0,1,0,0.04,0.1\n1,1,0,0.015,0.3\n2,1,0,0.05,0.008\n")
    lines = module.pair(a, b)
    assert lines[1] == "within 0.5 cm: A 1, B 0; discordant 1 / 0, sign test p = 1"
    assert lines[2] == "within 1.0 cm: A 1, B 1; discordant 1 / 1, sign test p = 1"
    assert lines[3] == "within 2.0 cm: A 2, B 2; discordant 1 / 1, sign test p = 1"
    assert module.main(["--pair", str(a), str(tmp_path / "missing.csv")]) == 2
    assert capsys.readouterr().err.startswith("error: ")
    b.write_text(header + "0,1,0,0.04,0.1\n")
    assert module.main(["--pair", str(a), str(b)]) == 2
    assert "not the same episodes" in capsys.readouterr().err
