"""studies/scratch_study.py's report: the per-part behaviour table, computed by hand."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location("scratch_study", ROOT / "studies" / "scratch_study.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


HEADER = "episode,frames,success,cube_displacement,touched_steps,constraint_terminated,phase_steps\n"


def test_behaviour_by_part_by_hand(study, tmp_path):
    rows = [
        '1,100,False,0.002,0,False,"[10, 0, 0]"',
        '2,200,True,0.300,3,False,"[0, 5, 5]"',
        '3,300,False,0.010,0,True,"[0, 20, 0]"',
        '4,400,False,0.000,1,False,"[4, 4, 12]"',
    ]
    (tmp_path / "episodes.csv").write_text(HEADER + "\n".join(rows) + "\n")
    parts = study.behaviour_by_part(tmp_path, parts=2)
    assert [p["episodes"] for p in parts] == [(1, 2), (3, 4)]
    assert [p["frames"] for p in parts] == [200, 400]
    assert [p["successes"] for p in parts] == [1, 0]
    assert parts[0]["displacement_mm"] == pytest.approx(151.0)  # (2 + 300) / 2 mm
    assert parts[1]["displacement_mm"] == pytest.approx(5.0)
    assert [p["touching"] for p in parts] == [1, 1]
    assert [p["constraint"] for p in parts] == [0, 1]
    assert parts[0]["phase_share"] == pytest.approx([0.5, 0.25, 0.25])  # 10, 5, 5 of 20 steps
    assert parts[1]["phase_share"] == pytest.approx([0.1, 0.6, 0.3])   # 4, 24, 12 of 40


def test_probe_runs_the_task_and_counts(study):
    """Two episodes of the steering probe without noise: the counts are consistent."""
    (cell,) = study.probe([0.0], [0.0], episodes=2, speed=0.4, gain=20.0, overrides=[])
    assert cell["episodes"] == 2 and 0 <= cell["wins"] <= 2 and 0 <= cell["touching"] <= 2
    assert 0.0 < cell["f2_share"] <= 1.0  # the probe approaches the cube: some steps make progress


def test_easy_eval_starts_every_episode_near_the_cube(study, tmp_path):
    """A tiny run with behind starts and 1 s training episodes: easy-eval runs its policy from
    those starts, on the evaluation seeds."""
    from ahrm_stack.train import main as train

    run = tmp_path / "run"
    assert train(["ppo.hidden_sizes=[16]", "ppo.frames_per_batch=64", "train.warm_start=none", "ppo.bc_coeff=0",
                  "train.time_limit=1", "train.start_curriculum=near_cube", "task.arm.near_cube.bearing=behind",
                  "train.episodes=2", "train.eval_episodes=0", "--run-dir", str(run), "--no-progress"]) == 0
    result = study.easy_eval(run, None, episodes=2)
    assert result["policy"] == "policy.pt" and result["episodes"] == 2
    assert result["successes"] <= 2
    assert study.behaviour_by_part(run, parts=1)[0]["episodes"][1] >= 2  # a batch may end more


def test_a_compressed_episode_log_reads_the_same(study, tmp_path):
    import gzip
    text = HEADER + '1,100,True,0.3,0,False,"[0, 5, 5]"\n'
    plain, packed = tmp_path / "plain", tmp_path / "packed"
    plain.mkdir(), packed.mkdir()
    (plain / "episodes.csv").write_text(text)
    with gzip.open(packed / "episodes.csv.gz", "wt") as handle:
        handle.write(text)
    assert study.behaviour_by_part(plain, 1) == study.behaviour_by_part(packed, 1)
    assert study.behaviour_by_part(packed, 1)[0]["successes"] == 1


def test_rate_reached_by_hand(study):
    import numpy as np
    success = np.array([0, 0, 1, 1, 0, 1, 1, 1], dtype=bool)
    frames = np.arange(1, 9) * 10
    # windows of 4: rates 0.5 (episodes 1-4), 0.5, 0.75 (3-6), 0.75, 0.75
    assert study._rate_reached(success, frames, 0.5, window=4) == (40, 4)
    assert study._rate_reached(success, frames, 0.75, window=4) == (60, 6)
    assert study._rate_reached(success, frames, 0.9, window=4) is None
    assert study._rate_reached(success[:3], frames[:3], 0.1, window=4) is None


def test_first_evaluation_names_the_training_episode(study):
    rows = [{"episode": "2008", "frames": "200704", "episodes": "40", "successes": "0"},
            {"episode": "6012", "frames": "600064", "episodes": "40", "successes": "3"}]
    assert study._first(rows, lambda r: int(r["successes"]) >= 1) == (600064, 6012)
