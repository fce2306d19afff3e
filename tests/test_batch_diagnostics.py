"""Each batch logs its learning diagnostics (issue 56): the shares of its episodes won, reaching the
cube, touching, cut by the constraint, and lane agreement; the run's figure plots them."""

from __future__ import annotations

import csv
import math

from ahrm_stack.config import load_config
from ahrm_stack.learning.diagnostics import BATCH_SHARES, episode_shares, read_batches
from ahrm_stack.learning.training import train


def _row(success=False, phase3=0, touched=0, cut=False, lane=None) -> dict:
    return {"success": success, "phase_steps": [5, 5, phase3], "touched_steps": touched,
            "constraint_terminated": cut, "lane_agrees": lane}


def test_the_shares_count_the_batch_s_episodes():
    rows = [_row(success=True, phase3=4, lane=True), _row(phase3=2, touched=3, lane=False),
            _row(cut=True), _row(touched=1, lane=True)]
    shares = episode_shares(rows)
    assert shares == {"success_share": 0.25, "reach_share": 0.5, "touch_share": 0.5,
                      "constraint_share": 0.25, "lane_agreement": 2 / 3}


def test_a_batch_without_episodes_or_pushes_leaves_blanks():
    assert set(episode_shares([]).values()) == {""}
    assert episode_shares([_row()])["lane_agreement"] == ""


def test_a_run_logs_them_per_batch_and_plots_them(tmp_path):
    config = load_config(["profile=scratch", "ppo.frames_per_batch=128", "ppo.mini_batch_size=64",
                          "ppo.epochs=1", "train.num_envs=2", "train.frames=384", "train.eval_every_frames=0",
                          "train.time_limit=1"])
    run = train(config, tmp_path / "run", resume=False, progress=False)
    with open(run / "batches.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 3
    for row in rows:
        for key in BATCH_SHARES:
            assert row[key] == "" or 0.0 <= float(row[key]) <= 1.0, (key, row[key])
        assert float(row["success_share"]) >= 0.0  # 1 s episodes: every batch ends some
    with open(run / "episodes.csv") as handle:
        episodes = list(csv.DictReader(handle))
    assert "lane_agrees" in episodes[0]
    batches = read_batches(run)
    assert not math.isnan(batches["reach_share"][0])
    assert (run / "diagnostics.png").stat().st_size > 0
