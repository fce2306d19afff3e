"""studies/touch_diagnosis.py --own: the replay of a run's own evaluation finds as many touching
episodes as the evaluation itself counted."""

import importlib.util
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def test_own_replay_counts_the_evaluations_touching_episodes(tmp_path, capsys):
    from ahrm_stack.train import main as train

    spec = importlib.util.spec_from_file_location("touch_diagnosis", ROOT / "studies" / "touch_diagnosis.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    run = tmp_path / "run"
    assert train(["ppo.hidden_sizes=[16]", "ppo.frames_per_batch=64", "train.warm_start=none", "ppo.bc_coeff=0",
                  "task.episode.duration=3", "train.episodes=2", "train.eval_episodes=3",
                  "--run-dir", str(run), "--no-progress"]) == 0
    touched = yaml.safe_load((run / "evaluation.yaml").read_text())["touched_episodes"]
    capsys.readouterr()
    assert module.main([str(run), "--own", "3"]) == 0
    out = capsys.readouterr().out
    assert len(re.findall(r"^own episode \d+: ", out, flags=re.M)) == touched
    assert out.strip().splitlines()[-1].startswith("first touches:")
