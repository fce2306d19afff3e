"""Interim evaluations beside training (``train.eval_beside``) give the rows the training's own
process gives, and the run folder says where its wall time went (``timing.json``)."""

from __future__ import annotations

import csv
import json

from ahrm_stack.config import load_config
from ahrm_stack.learning.training import train

QUICK = ["profile=scratch", "ppo.frames_per_batch=128", "ppo.mini_batch_size=64", "ppo.epochs=1",
         "train.num_envs=2", "train.frames=512", "train.eval_every_frames=256", "train.eval_episodes=2",
         "task.episode.duration=3", "train.checkpoint_every=2"]


def _rows(run_dir) -> list[dict]:
    with open(run_dir / "evaluations.csv") as handle:
        return list(csv.DictReader(handle))


def test_evaluations_beside_training_give_the_in_process_rows(tmp_path):
    runs = {}
    for beside in (False, True):
        config = load_config([*QUICK, f"train.eval_beside={str(beside).lower()}"])
        runs[beside] = train(config, tmp_path / str(beside), resume=False, progress=False)
    inline, beside_rows = _rows(runs[False]), _rows(runs[True])
    assert len(inline) == 3  # frames 0, 256, 512
    assert inline == beside_rows
    for run in runs.values():
        timing = json.loads((run / "timing.json").read_text())
        assert timing["evaluations"] == 3 and timing["frames"] == 512
        assert timing["evaluation_steps"] == 3 * 2 * 60  # 3 s episodes, no success
        assert 0 < timing["evaluation_share"] < 1
        assert timing["evaluation_wait_seconds"] <= timing["loop_seconds"]
        assert timing["batch_seconds"] <= timing["loop_seconds"]
        assert timing["frames_per_second"] == timing["frames"] / timing["loop_seconds"]
    # in the training's process, the loop waits for every evaluation
    inline_t = json.loads((runs[False] / "timing.json").read_text())
    assert inline_t["evaluation_wait_seconds"] >= 0.9 * inline_t["evaluation_seconds"]
