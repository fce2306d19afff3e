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


def test_wilson_interval_by_hand(study):
    # k = 0: the upper end is z^2 / (n + z^2)
    z = 1.959964
    low, high = study.wilson(0, 40)
    assert low == 0.0 and high == pytest.approx(z * z / (40 + z * z))
    # symmetric: the interval of n - k is the mirror of that of k
    assert study.wilson(30, 40) == pytest.approx(tuple(1 - v for v in reversed(study.wilson(10, 40))))
    # 20/40 is centred on 0.5 with half-width z sqrt(1/160 + z^2/6400) / (1 + z^2/40)
    half = z * (1 / 160 + z * z / 6400) ** 0.5 / (1 + z * z / 40)
    assert study.wilson(20, 40) == pytest.approx((0.5 - half, 0.5 + half))


def _final(folder, successes, touched, times):
    (folder / "own").mkdir(parents=True)
    lines = ["episode,success,touched_steps,time_to_success"]
    lines += [f"{i},{s},{t},{x}" for i, (s, t, x) in enumerate(zip(successes, touched, times))]
    (folder / "own" / "evaluation.csv").write_text("\n".join(lines) + "\n")


def test_final_section_pairs_rows_with_the_scripted_controller_and_ls(study, tmp_path):
    runs = [tmp_path / "a-ls-seed0", tmp_path / "a-mhrm-seed0"]
    _final(runs[0] / "final", [True, True, False, False], [0, 3, 0, 0], [2.0, 4.0, "", ""])
    _final(runs[1] / "final", [True, True, True, False], [0, 0, 0, 1], [1.0, 1.0, 4.0, ""])
    _final(tmp_path / "scripted", [True] * 4, [0] * 4, [3.0] * 4)
    lines = study.final_section(runs, tmp_path / "scripted", samples=200)
    table = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in lines if line.startswith("| ")}
    assert table["scripted controller"][2].startswith("4/4") and table["scripted controller"][5] == "–"
    ls, mhrm = table["a-ls"], table["a-mhrm"]
    assert ls[2].startswith("2/4") and ls[3].startswith("1/4") and ls[4] == "3.00 ± 1.00"
    assert ls[5].startswith("-0.50 [") and ls[6].startswith("+0.25 [") and ls[7] == "–"
    assert mhrm[2].startswith("3/4") and mhrm[4] == "2.00 ± 1.41"
    assert mhrm[7].startswith("+0.25 [") and mhrm[8].startswith("+0.00 [")  # 3/4 - 2/4; 1/4 - 1/4
    assert study.final_section([tmp_path / "nothing"], None) == []
    # a run's own evaluation.csv (training's final evaluation) counts as its final evaluation
    (tmp_path / "b-ls-seed1").mkdir()
    (tmp_path / "b-ls-seed1" / "evaluation.csv").write_text(
        (runs[0] / "final" / "own" / "evaluation.csv").read_text())
    [line] = [x for x in study.final_section([tmp_path / "b-ls-seed1"], None) if x.startswith("| b-ls |")]
    assert line.split(" | ")[2].startswith("2/4")


def test_report_takes_run_folders_and_folders_of_them(study, tmp_path):
    def fake_run(path, successes):
        path.mkdir(parents=True)
        (path / "episodes.csv").write_text(HEADER + "".join(
            f'{i},{100 * i},{s},0.1,0,False,"[1, 1, 1]"\n' for i, s in enumerate(successes, 1)))
        (path / "batches.csv").write_text("batch,frames,episodes,seconds,curriculum_level\n1,400,4,60,0.0\n")
        (path / "evaluations.csv").write_text(
            "episode,frames,episodes,successes,success_rate,touched_episodes,time_mean\n"
            "0,0,40,0,0.0,0,nan\n4,400,40,20,0.5,3,4.0\n")

    fake_run(tmp_path / "round" / "a-ahrm-seed0", [False, True, True, True])
    fake_run(tmp_path / "other" / "b-ls-seed0", [False, False, False, True])
    _final(tmp_path / "round" / "a-ahrm-seed0" / "final", [True, False], [0, 0], [2.0, ""])
    out = tmp_path / "out"
    study.report([tmp_path / "round", tmp_path / "other" / "b-ls-seed0"], out)
    table = (out / "table.md").read_text()
    assert "| a-ahrm-seed0 | 400 | 4 | 3 (75 %) | 200 (2) |" in table
    assert "| b-ls-seed0 | 400 | 4 | 1 (25 %) | 400 (4) |" in table
    assert "20/40 (3 touching, 4.00 s, 400)" in table and "| a-ahrm | 1 | 1/2 [" in table
    assert (out / "curves.png").stat().st_size > 0
    with pytest.raises(SystemExit, match="no run folders"):
        study.report([tmp_path / "out"], tmp_path / "out2")


def _three_runs(tmp_path):
    """Interim evaluations of two AHRM seeds (seed 1 without one at 0.4M) and one LS seed."""
    header = "episode,frames,episodes,successes,success_rate,touched_episodes\n"
    runs = {"r-ahrm-seed0": "0,0,40,0,0.0,1\n5,200704,40,30,0.75,2\n9,401408,40,40,1.0,0\n",
            "r-ahrm-seed1": "0,0,40,0,0.0,0\n6,200704,40,10,0.25,3\n",
            "r-ls-seed0": "0,0,40,0,0.0,0\n5,200704,40,0,0.0,0\n9,401408,40,8,0.2,5\n"}
    for name, text in runs.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "evaluations.csv").write_text(header + text)


def test_matched_frames_pools_seeds_where_every_seed_has_an_evaluation(study, tmp_path):
    _three_runs(tmp_path)
    lines = study.matched_frames_section(sorted(tmp_path.iterdir()))
    table = {line.split(" | ")[0].strip("| "): line.strip("| ").split(" | ")
             for line in lines if line.startswith("| r-")}
    assert lines[3] == "| row | seeds | 0.2M | 0.4M |"  # the budgets after 0 frames, in millions
    low, high = study.wilson(40, 80)  # 30 + 10 of 80 at 200,704 frames
    assert table["r-ahrm"][1] == "2" and table["r-ahrm"][2] == f"40/80 [{low:.2f}, {high:.2f}] (5)"
    assert table["r-ahrm"][3] == "–"  # seed 1 has no evaluation at 401,408 frames
    low, high = study.wilson(8, 40)
    assert table["r-ls"][2].startswith("0/40 [0.00,") and table["r-ls"][3] == f"8/40 [{low:.2f}, {high:.2f}] (5)"
    assert study.matched_frames_section([tmp_path / "nothing"]) == []


def test_run_command_splits_the_environments_over_workers_on_request(study, tmp_path):
    plain = study.run_command("mirror-nj-ahrm", 2, 1000, tmp_path, 500, False)
    assert not any("env_workers" in part for part in plain)
    assert plain[plain.index("--run-dir") + 1] == str(tmp_path / "mirror-nj-ahrm-seed2")
    split = study.run_command("mirror-nj-ahrm", 2, 1000, tmp_path, 500, False, workers=2)
    assert "train.env_workers=2" in split and "train.seed=2" in split
    resumed = study.run_command("mirror-nj-ahrm", 2, 1000, tmp_path, 500, True, workers=2)
    assert resumed[3:6] == ["--resume", str(tmp_path / "mirror-nj-ahrm-seed2"), "train.env_workers=2"]


def test_seed_level_section_takes_the_seed_as_the_unit(study, tmp_path):
    _three_runs(tmp_path)
    (tmp_path / "r-ls-seed1").mkdir()  # a second LS seed (rows of one seed are not compared)
    (tmp_path / "r-ls-seed1" / "evaluations.csv").write_text(
        "episode,frames,episodes,successes,success_rate,touched_episodes\n0,0,40,0,0.0,0\n5,200704,40,4,0.1,0\n")
    (tmp_path / "r-mhrm-seed0").mkdir()  # one seed: in the table, not in the comparison
    (tmp_path / "r-mhrm-seed0" / "evaluations.csv").write_text(
        "episode,frames,episodes,successes,success_rate,touched_episodes\n5,200704,40,40,1.0,0\n")
    lines = study.seed_level_section(sorted(tmp_path.iterdir()), samples=4000)
    split = next(i for i, line in enumerate(lines) if line.startswith("Differences"))
    table = {line.split(" | ")[0].strip("| "): line.strip("| ").split(" | ")
             for line in lines[:split] if line.startswith("| r-")}
    # two seeds of shares 0.75 and 0.25: resampled means 0.25 / 0.5 / 0.75 with chances 1/4, 1/2, 1/4,
    # so the 2.5th and 97.5th percentiles are the two ends; one seed of two won half its episodes
    low, high = study.wilson(1, 2)
    assert table["r-ahrm"][2] == f"30, 10: 0.50 [0.25, 0.75]; 1/2 [{low:.2f}, {high:.2f}]"
    assert table["r-ahrm"][3] == "–"  # seed 1 has no evaluation at 0.4M
    assert table["r-ls"][2].startswith("0, 4: 0.05 [0.00, 0.10]; 0/2") and table["r-ls"][3] == "–"
    assert table["r-mhrm"][2].startswith("40: 1.00 [1.00, 1.00]; 1/1")  # one seed: no spread to resample
    # the comparison: rows of two seeds or more, at the largest budget all their seeds have (0.2M).
    # Differences of resampled means: AHRM 0.25 / 0.5 / 0.75 (chances 1/4, 1/2, 1/4) minus LS 0 / 0.05 /
    # 0.1 (the same chances): each end has chance 1/16 > 0.025, so the interval is [0.15, 0.75]
    [diff] = [line for line in lines if line.startswith("| r-ahrm | +")]
    assert "200,704 frames" in "".join(lines) and diff == "| r-ahrm | +0.45 [+0.15, +0.75] |"
    header = next(line for line in lines if line.startswith("| row | r-"))
    assert header == "| row | r-ls |" and not any(line.startswith("| r-mhrm | +") for line in lines)
    assert study.seed_level_section([tmp_path / "nothing"]) == []


def test_seed_bootstrap_by_hand(study):
    rng = __import__("numpy").random.default_rng(1)
    # identical seeds: no spread; a difference of two constant rows is exact
    assert study.seed_bootstrap([0.5, 0.5, 0.5], rng, 100) == (0.5, 0.5, 0.5)
    assert study.seed_bootstrap([0.9, 0.9], rng, 100, [0.4]) == pytest.approx((0.5, 0.5, 0.5))
    # three seeds 0, 0, 1: the resampled mean is 0 with chance (2/3)^3 = 0.30 > 0.025 and 1 with
    # chance (1/3)^3 = 0.037 > 0.025, so the interval is [0, 1] around the mean 1/3
    point, low, high = study.seed_bootstrap([0.0, 0.0, 1.0], rng, 20000)
    assert point == pytest.approx(1 / 3) and (low, high) == (0.0, 1.0)


def test_early_behaviour_reads_the_first_episodes_only(study, tmp_path):
    rows = [f'{i},{100 * i},{i == 3},{0.001 * i},{int(i % 2 == 0)},False,"[1, 1, 1]"' for i in range(1, 6)]
    (tmp_path / "episodes.csv").write_text(HEADER + "\n".join(rows) + "\n")
    early = study.early_behaviour(tmp_path, episodes=4)
    assert early["episodes"] == (1, 4) and early["frames"] == 400
    assert early["touching"] == 2 and early["successes"] == 1  # episodes 2 and 4 touch; 3 succeeds
    assert early["displacement_mm"] == pytest.approx(2.5)  # (1 + 2 + 3 + 4) / 4 mm
    assert study.early_behaviour(tmp_path, episodes=6) is None


def test_sign_test_by_hand(study):
    # 0 against 4: 2 * (1/2)^4; 1 against 5: 2 * (1 + 6) / 64; 3 against 3 and no pairs: 1
    assert study.sign_test(0, 4) == pytest.approx(2 / 16)
    assert study.sign_test(5, 1) == pytest.approx(2 * 7 / 64)
    assert study.sign_test(3, 3) == 1.0 and study.sign_test(0, 0) == 1.0


def test_compare_pairs_the_same_episodes(study, tmp_path):
    a, b = tmp_path / "a" / "evaluation.csv", tmp_path / "b" / "evaluation.csv"
    _final(tmp_path / "a", [True, True, True, False], [1, 0, 2, 0], [2.0, 2.0, 4.0, ""])
    _final(tmp_path / "b", [True, True, True, True], [0, 0, 0, 0], [1.0, 3.0, 3.0, 5.0])
    (tmp_path / "a" / "own" / "evaluation.csv").rename(a)
    (tmp_path / "b" / "own" / "evaluation.csv").rename(b)
    lines = study.compare([a, b], ["a", "b"], samples=500)
    table = {line.split(" | ")[0].strip("| "): line.strip("| ").split(" | ") for line in lines if line.startswith("| ")}
    assert table["a"][1].startswith("3/4") and table["a"][2].startswith("2/4") and table["a"][4] == "–"
    assert table["a"][3] == "2.67 ± 0.94"
    b_row = table["b"]
    assert b_row[1].startswith("4/4") and b_row[2].startswith("0/4") and b_row[3] == "3.00 ± 1.41"
    # success: one episode only b wins (+1/4); touching: two only a touches (-2/4)
    assert b_row[4].startswith("+0.250 [") and b_row[5] == "0 / 1 (1)"
    assert b_row[6].startswith("-0.500 [") and b_row[7] == "2 / 0 (0.5)"
    # the seeds are named: no evaluation.json (written before the split existed) is validation;
    # evaluations on two different splits are not compared
    assert lines[0] == "Seeds: the validation split of configs/seeds.yaml."
    b.with_name("evaluation.json").write_text('{"split": "other"}')
    with pytest.raises(ValueError, match="different splits"):
        study.compare([a, b], ["a", "b"], samples=10)
    b.with_name("evaluation.json").unlink()
    # different episode counts: a one-line error, nothing compared
    _final(tmp_path / "c", [True], [0], [1.0])
    with pytest.raises(ValueError, match="different episode counts"):
        study.compare([a, tmp_path / "c" / "own" / "evaluation.csv"], ["a", "c"])
    assert study.main(["compare", str(a), str(tmp_path / "nothing.csv")]) == 2
    (tmp_path / "other.csv").write_text("x,y\n1,2\n")
    with pytest.raises(ValueError, match="other.csv: not an evaluation"):
        study.compare([a, tmp_path / "other.csv"], ["a", "other"])


def test_branch_checks_before_copying(study, tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("{}\n")
    # no checkpoint: refused, nothing copied
    assert study.main(["branch", str(run), str(tmp_path / "new"), "train.touch_end=true"]) == 2
    assert "not a run folder with a checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    (run / "checkpoints").mkdir()
    (run / "checkpoints" / "ckpt-0000001.pt").write_bytes(b"")
    # a bad override: the config's one-line error, nothing copied
    assert study.main(["branch", str(run), str(tmp_path / "new"), "train.touch_end=maybe"]) == 2
    assert "touch_end" in capsys.readouterr().err and not (tmp_path / "new").exists()
    # an existing destination is never overwritten
    assert study.main(["branch", str(run), str(run)]) == 2
    assert "exists" in capsys.readouterr().err
    assert study.branch_command(tmp_path / "new", ["train.touch_end=true"])[-5:] == [
        "ahrm_stack.train", "--resume", str(tmp_path / "new"), "train.touch_end=true", "--no-progress"]
