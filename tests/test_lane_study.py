"""studies/lane_study.py: its arms, its run commands and the table it builds from run data."""

import importlib.util
import json
from pathlib import Path

import pytest

from ahrm_stack.config import load_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location("lane_study", ROOT / "studies" / "lane_study.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_arms_load_and_only_the_assisted_one_sees_the_plan(study):
    for name, overrides in study.ARMS.items():
        config = load_config(overrides)
        assisted = name.startswith("assisted-")
        assert config.task.observation.lane_choice == assisted, name
        assert config.ppo.lane_frame.startswith("mirror") == assisted, name  # keyed on the plan
        assert config.ppo.actor_init_scale == 0.01 and config.task.rewards.avoid_margin == 0.02


def test_run_commands_name_the_folder_and_resume_it(study, tmp_path):
    fresh = study.run_command("own-lane-ahrm", 2, 1000, tmp_path, 500, resume=False)
    assert "profile=scratch-own-lane" in fresh and "train.seed=2" in fresh and "train.frames=1000" in fresh
    assert fresh[fresh.index("--run-dir") + 1] == str(tmp_path / "own-lane-ahrm-seed2")
    resumed = study.run_command("own-lane-ahrm", 2, 1000, tmp_path, 500, resume=True)
    assert resumed[resumed.index("--resume") + 1] == str(tmp_path / "own-lane-ahrm-seed2")


def _lane_result(successes, touched, pushed, agreeing, touched_agreeing, touched_disagreeing):
    return {"episodes": 10, "successes": successes, "touched_episodes": touched,
            "lanes": {"episodes": 10, "pushed": pushed, "agreeing": agreeing, "disagreeing": pushed - agreeing,
                      "agreement": agreeing / pushed, "touched_agreeing": touched_agreeing,
                      "touched_disagreeing": touched_disagreeing}}


def test_summarise_builds_the_table_from_the_run_data(study, tmp_path):
    run = tmp_path / "runs" / "own-lane-ahrm-seed0"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text("schema_version: 1\n")
    (run / "evaluations.csv").write_text("episode,frames,episodes,successes,touched_episodes\n"
                                         "0,0,40,0,3\n120,2048,40,7,2\n")
    (run / "batches.csv").write_text("batch,frames\n1,2048\n2,4096\n")
    (run / "episodes.csv").write_text("episode,frames,success\n1,1000,True\n2,2000,False\n3,3000,True\n")
    for name, result in (("episode-00120", _lane_result(6, 2, 8, 6, 0, 2)),
                         ("policy", _lane_result(9, 1, 10, 9, 0, 1)),
                         ("scripted", _lane_result(10, 0, 10, 10, 0, 0))):
        (run / "lanes" / name).mkdir(parents=True)
        (run / "lanes" / name / "evaluation.json").write_text(json.dumps(result))
        (run / "lanes" / name / "evaluation.csv").write_text("episode\n")
    table = study.summarise([tmp_path / "runs"], tmp_path / "out").read_text()
    assert "| own-lane-ahrm-seed0 | 2,048 | 7/40 | 2 | 0.50 |" in table  # 1 of the 2 episodes by 2,048 frames
    assert "| own-lane-ahrm-seed0 | episode-00120 | 2,048 | 6/10 | 2 | 8 | 6/8 (75%) | 0/6 | 2/2 |" in table
    assert "| own-lane-ahrm-seed0 | policy | 4,096 | 9/10 | 1 | 10 | 9/10 (90%) | 0/9 | 1/1 |" in table
    assert "| own-lane-ahrm-seed0 | scripted | – | 10/10 | 0 | 10 | 10/10 (100%) | 0/10 | 0/0 |" in table
    assert (tmp_path / "out" / "runs" / "own-lane-ahrm-seed0" / "episodes.csv.gz").is_file()


def test_the_committed_table_is_what_the_committed_run_data_give(study):
    """docs/lane-study/table.md regenerated from the copies under docs/lane-study/runs/ (issue 42,
    item 5: every table in the docs from committed data, checked)."""
    root = Path(__file__).resolve().parents[1] / "docs" / "lane-study"
    copies = sorted(p for p in (root / "runs").iterdir() if p.is_dir())
    assert study.table(copies) == (root / "table.md").read_text(), (
        "docs/lane-study/table.md is out of date: python studies/lane_study.py summarise ...")
