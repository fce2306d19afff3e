"""The experiment grid end to end on a tiny real grid (2 methods x 1 seed x a few 2-second
episodes, real simulator and trainer, on a local Ray instance): a failed run is reported and does
not stop the other, a rerun skips the finished run and redoes the failed one, and the report and
the videos are written."""

import json
import os
import shutil

import pytest

from ahrm_stack.env.video import read_mp4
from ahrm_stack.experiment import main
from ahrm_stack.seeds import seed_table

RAY_TEMP = f"/tmp/ahrm-ray-test-{os.getpid()}"  # short: Ray's socket paths must fit 107 bytes
TINY = ["task.episode.duration=2", "ppo.hidden_sizes=[16]", "ppo.frames_per_batch=128",
        "train.warm_start=none", "ppo.bc_coeff=0",
        "experiment.eval_episodes=2", "experiment.scripted_episodes=1",
        "experiment.split=test",  # the final table's path to the sealed split (the default is validation)
        f"experiment.ray_temp_dir={RAY_TEMP}", "video.width=160", "video.height=120"]


def _args(out, episodes=2):
    return ["--methods", "ahrm", "ls", "--seeds", "1", "--episodes", str(episodes), "--out", str(out),
            "--config", *TINY]


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    out = tmp_path_factory.mktemp("grid")
    ahrm, ls = out / "runs" / "ahrm-seed0", out / "runs" / "ls-seed0"
    ls.mkdir(parents=True)
    (ls / "policy.pt").write_bytes(b"not a policy")  # a broken run folder (no config.yaml): it fails
    first_status = main(_args(out))
    first = {"report": (out / "report.md").read_text(), "ls_failed": json.loads((ls / "failed.json").read_text()),
             "ahrm_done_mtime": (ahrm / "done.json").stat().st_mtime_ns,
             "ahrm_episodes_mtime": (ahrm / "episodes.csv").stat().st_mtime_ns,
             "ls_done": (ls / "done.json").exists()}
    (ls / "policy.pt").unlink()  # repaired: the rerun trains it from scratch
    second_status = main(_args(out))
    shutil.rmtree(RAY_TEMP, ignore_errors=True)
    return {"out": out, "first_status": first_status, "first": first, "second_status": second_status}


def test_a_failed_run_is_reported_and_the_other_finishes(grid):
    first = grid["first"]
    assert grid["first_status"] == 1                      # some run failed
    assert not first["ls_done"] and "config.yaml not found" in first["ls_failed"]["error"]
    assert "1 run(s) failed** (ls-seed0)" in first["report"]
    assert "`ls-seed0`: ConfigError: " in first["report"]
    assert first["ahrm_done_mtime"] > 0


def test_rerun_skips_the_finished_run_and_redoes_the_failed_one(grid):
    out, first = grid["out"], grid["first"]
    ahrm, ls = out / "runs" / "ahrm-seed0", out / "runs" / "ls-seed0"
    assert grid["second_status"] == 0
    assert (ahrm / "done.json").stat().st_mtime_ns == first["ahrm_done_mtime"]       # not redone
    assert (ahrm / "episodes.csv").stat().st_mtime_ns == first["ahrm_episodes_mtime"]  # not retrained
    done = json.loads((ls / "done.json").read_text())
    assert done["status"] == "done" and done["evaluation"]["episodes"] == 2
    # the final table: the frozen policy on the sealed test split (experiment.split=test here)
    assert done["evaluation"]["split"] == "test" and done["spec"]["split"] == "test"
    assert done["evaluation"]["seed_offset"] == seed_table().evaluation["random"].test.start  # eval_layout
    assert not (ls / "failed.json").exists()
    assert len((ls / "episodes.csv").read_text().strip().splitlines()) - 1 >= 2      # trained


def test_changed_settings_do_not_reuse_finished_runs(grid, capsys):
    assert main(_args(grid["out"], episodes=3)) == 2
    assert "ahrm-seed0/done.json was made with other settings (overrides differ)" in capsys.readouterr().err


def test_a_run_finished_before_the_split_existed_counts_as_validation(tmp_path):
    """A done.json without a split was evaluated on the validation seeds: a test-split grid does
    not reuse it, a validation grid does."""
    from ahrm_stack.config import ConfigError
    from ahrm_stack.experiment_grid import check_finished

    spec = {"run_dir": str(tmp_path / "run"), "overrides": [], "eval_episodes": 2, "episodes": 2, "layout": "random"}
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "done.json").write_text(json.dumps({"spec": spec}))
    scripted = {"run_dir": str(tmp_path / "scripted")}
    check_finished({"runs": [{**spec, "split": "validation"}], "scripted": scripted})
    with pytest.raises(ConfigError, match="other settings \\(split differ"):
        check_finished({"runs": [{**spec, "split": "test"}], "scripted": scripted})


def test_the_budget_is_frames_unless_episodes_are_asked_for(tmp_path):
    from ahrm_stack.experiment import _parse
    from ahrm_stack.experiment_grid import build_grid
    from ahrm_stack.report import budget

    def overrides(*flags):
        grid = build_grid(_parse(["--out", str(tmp_path), *flags, "--config", *TINY]))
        return grid, {o.split("=")[0]: o.split("=")[1] for o in grid["runs"][0]["overrides"]
                      if o.startswith("train.")}

    grid, train = overrides()  # configs/experiment.yaml: frames decide, the same for every method
    assert train["train.frames"] == "60000" and budget(grid) == "60,000 frames"
    grid, train = overrides("--episodes", "7")
    assert train["train.frames"] == "0" and train["train.episodes"] == "7" and budget(grid) == "7 episodes"
    grid, train = overrides("--frames", "512")
    assert train["train.frames"] == "512" and budget(grid) == "512 frames"


def test_report_tables_figures_and_videos(grid):
    out = grid["out"]
    report = (out / "report.md").read_text()
    for row in ("| AHRM (here, 1/1 seeds) |", "| AHRM (paper) | 37 | 92.5 % | 2 | 3.8 ± 0.3 | 0.5103 ± 0.0032 |",
                "| LS (here, 1/1 seeds) |", "| LS (paper) | 4 | 10.0 % | 39 | 8.3 ± 1.1 | 0.5342 ± 0.0219 |",
                "| scripted controller (mink) | ", "| ahrm-seed0 | avoid > manipulate > time |",
                "## Episodes to reach 80% success", "| Method | Reached after | Held from | Per seed |",
                "## Safety", "below the paper's 92.5%", "**test split**",
                "## Table II: this reproduction (test split, mean ± std over seeds) and the paper"):
        assert row in report
    assert "failed" not in report.split("## Findings")[1].split("##")[0]
    for name in ("learning_curves", "objectives_per_phase", "priority_orders"):
        assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"![{name}]({name}.png)" in report
    for method in ("ahrm", "ls", "scripted"):
        frames, size, _ = read_mp4(out / "videos" / f"{method}.mp4")
        assert size == (120, 160) and frames >= 2
        assert f"videos/{method}.mp4" in report
    # a learned policy's episode here runs the full 2 s: 40 control steps + the final frame
    assert read_mp4(out / "videos" / "ahrm.mp4")[0] == 41


def test_interim_evaluations_asked_of_the_training_are_kept(tmp_path):
    """The experiment skips a run's own final evaluation (it evaluates the run itself), but a
    training that asks for interim evaluations (the learning curves, docs/protocol.md) keeps them:
    a real two-episode run of the grid logs one per episode."""
    from ahrm_stack.experiment import _parse
    from ahrm_stack.experiment_grid import build_grid, run_one

    def spec(*config):
        grid = build_grid(_parse(["--methods", "ahrm", "--seeds", "1", "--episodes", "2", "--no-video",
                                  "--out", str(tmp_path), "--config", *TINY, *config]))
        return grid["runs"][0]

    assert "train.eval_episodes=0" in spec()["overrides"]
    kept = spec("train.eval_every=1", "train.eval_episodes=1")
    assert "train.eval_episodes=0" not in kept["overrides"]
    assert run_one(kept)["status"] == "done"
    with open(tmp_path / "runs" / "ahrm-seed0" / "evaluations.csv") as handle:
        rows = handle.read().splitlines()
    assert len(rows) >= 3, rows  # the header, the first point before training, one per episode


def test_runs_start_seed_by_seed_and_finished_ones_are_left_out(tmp_path):
    """A grid stopped part-way holds whole seeds of every method: the schedule is seed-major, after
    the runs that resume from a checkpoint."""
    from ahrm_stack.experiment_grid import DONE, schedule

    methods = ["ahrm", "mhrm", "fhrm", "ls"]
    runs = [{"name": f"{m}-seed{s}", "method": m, "seed": s, "run_dir": str(tmp_path / f"{m}-seed{s}")}
            for m in methods for s in range(3)]  # the grid's own order: method by method
    (tmp_path / "ahrm-seed0").mkdir()
    (tmp_path / "ahrm-seed0" / DONE).write_text("{}")
    (tmp_path / "ls-seed2" / "checkpoints").mkdir(parents=True)
    (tmp_path / "ls-seed2" / "checkpoints" / "ckpt-0000010.pt").write_bytes(b"")  # started: it resumes first
    (tmp_path / "fhrm-seed1").mkdir()  # a folder without a checkpoint has not started
    names = [spec["name"] for spec in schedule({"methods": methods, "runs": runs})]
    assert names == ["ls-seed2", "mhrm-seed0", "fhrm-seed0", "ls-seed0",
                     "ahrm-seed1", "mhrm-seed1", "fhrm-seed1", "ls-seed1",
                     "ahrm-seed2", "mhrm-seed2", "fhrm-seed2"]
