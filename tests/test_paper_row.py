"""tools/paper_row.py (issue 42, item 6): the row's table from run data, by hand on a synthetic
run, and the committed table from the committed copies."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def row():
    spec = importlib.util.spec_from_file_location("paper_row", ROOT / "tools" / "paper_row.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["paper_row"] = module
    spec.loader.exec_module(module)
    return module


def _run(folder: Path, evaluations: list[str], episodes: int = 4,
         config: str = "train:\n  warm_start: bc\n  seed: 3\ntask:\n  action:\n    mode: joint\n"
                       "  arm:\n    start: home\n    home_deg:\n      jaco: [1, 2]\nnot_a_key: 1\n") -> Path:
    folder.mkdir(parents=True)
    (folder / "config.yaml").write_text(config)
    (folder / "episodes.csv").write_text("episode,frames,success\n" + "".join(
        f"{i},{(i + 1) * 100},{i % 2 == 1}\n" for i in range(episodes)))
    (folder / "batches.csv").write_text("batch,frames,updates\n1,200,24\n2,400,3\n")
    (folder / "evaluations.csv").write_text("episode,frames,episodes,successes,touched_episodes\n"
                                            + "".join(line + "\n" for line in evaluations))
    return folder


def test_the_row_of_a_run(row, tmp_path):
    """At the budget: the last evaluation at or before episode 300; first >= 37/40; the best; the
    PPO gradient steps summed from batches.csv. The
    setting: the keys whose values differ from profile=paper's (seed, budget and unknown keys not)."""
    run = _run(tmp_path / "in" / "paper-bc-seed0", ["0,0,40,30,1", "250,1000,40,38,0", "301,2000,40,39,2"])
    text = row.summarise([run], tmp_path / "out").read_text()
    line = [r for r in text.splitlines() if r.startswith("| paper-bc-seed0 |")][0]
    assert line == ("| paper-bc-seed0 | train.warm_start=bc, task.arm.home_deg.jaco=[1,2] | 4, 400, 2, 27 | "
                    "38/40 (0 touching) at episode 250, 1,000 frames | "
                    "not yet (4 of 300 episodes) | 38/40 (0 touching) at episode 250, 1,000 frames | 39/40 (2 "
                    "touching) at episode 301, 2,000 frames |")
    long = _run(tmp_path / "in" / "long-seed0", ["0,0,40,39,0", "300,9000,40,20,5"], episodes=301)
    assert "| no | 39/40 (0 touching) at episode 0, 0 frames |" in row.table(row.collect([long], tmp_path / "o2"))
    assert (tmp_path / "out" / "runs" / "paper-bc-seed0" / "episodes.csv.gz").is_file()
    assert (tmp_path / "out" / "runs" / "paper-bc-seed0" / "batches.csv.gz").is_file()
    never = _run(tmp_path / "in" / "paper-seed0", ["0,0,40,0,0", "100,500,40,0,3"],
                 config="train:\n  warm_start: none\n  episodes: 300\nppo:\n  learning_rate: 0.001\n")
    line = row.table([row.collect([never], tmp_path / "out")[0]]).splitlines()[-1]
    assert line.startswith("| paper-seed0 | the paper's setting | 4, 400, 2, 27 |")
    assert line.endswith("| not yet (4 of 300 episodes) | never (up to 400 frames) | 0 at all 2 evaluations |")


def test_the_committed_table_is_what_the_committed_run_data_give(row):
    root = ROOT / "docs" / "paper-row"
    copies = sorted(p for p in (root / "runs").iterdir() if p.is_dir())
    assert row.table(copies) + row.answer(root) == (root / "table.md").read_text(), (
        "docs/paper-row/table.md is out of date: python tools/paper_row.py summarise ...")


def test_the_answer_line_from_its_test_evaluation(row, tmp_path):
    """Successes with the exact interval, touching, and the sign test against the scripted
    controller on the same episodes; nothing before the evaluation exists; a validation file is refused."""
    assert row.answer(tmp_path) == ""
    for folder, results in (("test", [(1, 0)] * 38 + [(0, 1), (0, 0)]), ("test-scripted", [(1, 0)] * 40)):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "evaluation.csv").write_text("success,touched_steps\n" + "".join(
            f"{bool(w)},{t}\n" for w, t in results))
    (tmp_path / "test" / "evaluation.json").write_text('{"split": "test", "policy": "/x/paper-bc-ppo-seed0"}')
    line = row.answer(tmp_path)
    assert "`paper-bc-ppo-seed0`" in line and "38/40 [83.1%, 99.4%], 1 touching" in line  # Clopper-Pearson
    assert "same episodes 40/40, 0 touching" in line and "policy 0 / scripted 2 (exact sign test p = 0.5)" in line
    (tmp_path / "test" / "evaluation.json").write_text('{"split": "validation", "policy": "x"}')
    with pytest.raises(SystemExit, match="not test"):
        row.answer(tmp_path)


def test_the_answers_robustness_table_is_its_committed_data():
    """docs/paper-row/robustness: change 4's policy through the deploy loop (python -m
    ahrm_stack.robustness RUN --no-dose); its table is rendered from its json."""
    import json

    from ahrm_stack import robustness

    folder = ROOT / "docs" / "paper-row" / "robustness"
    data = json.loads((folder / "robustness.json").read_text())
    assert data["run"].endswith("paper-bc-ppo-ahrm-seed0")
    assert (folder / "robustness.md").read_text() == robustness.table(data)
