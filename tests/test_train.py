"""End to end: train for a few thousand frames on the real task, check the run folder, logs, resume
after SIGKILL, the NaN guard and safe loading."""

import csv
import importlib.util
import sys
from pathlib import Path

import pytest
import yaml
import torch

from ahrm_stack.learning.checkpoint import CheckpointManager, load
from ahrm_stack.train import main

SMALL = ["ppo.hidden_sizes=[32,32]", "ppo.frames_per_batch=256", "task.episode.duration=4",
         "train.eval_episodes=1", "train.checkpoint_every=1", "train.warm_start=none", "ppo.bc_coeff=0"]


def _rows(path: Path) -> list[dict]:
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_training_writes_the_run_folder_and_resumes(tmp_path):
    run = tmp_path / "run"
    assert main(SMALL + ["train.episodes=30", "--run-dir", str(run), "--no-progress"]) == 0
    for name in ("config.yaml", "episodes.csv", "batches.csv", "events.jsonl", "policy.pt",
                 "evaluation.yaml", "evaluation.csv", "diagnostics.png"):
        assert (run / name).is_file(), name
    assert list((run / "tb").iterdir())
    final = yaml.safe_load((run / "evaluation.yaml").read_text())  # the table is the episodes' sum
    per_episode = _rows(run / "evaluation.csv")
    assert len(per_episode) == final["episodes"]
    assert sum(r["success"] == "True" for r in per_episode) == final["successes"]
    episodes = _rows(run / "episodes.csv")
    assert len(episodes) >= 30 and int(episodes[-1]["frames"]) >= 2000
    assert [int(r["episode"]) for r in episodes] == list(range(1, len(episodes) + 1))
    assert len(CheckpointManager(run / "checkpoints", 3).paths()) <= 3
    # AHRM level 1 converges on a constant stream: the event log names the episode
    state = CheckpointManager(run / "checkpoints", 3).load_latest()
    assert state["counters"]["episodes"] == len(episodes)
    # resume: continues the numbering and the mechanism state
    assert main(["--resume", str(run), "train.episodes=40", "--no-progress"]) == 0
    assert "episodes: 40" in (run / "config.yaml").read_text()  # the folder says what ran
    resumed = _rows(run / "episodes.csv")
    assert [int(r["episode"]) for r in resumed] == list(range(1, len(resumed) + 1))
    assert len(resumed) >= 40
    # a fresh run into a folder with checkpoints is refused, not overwritten
    assert main(SMALL + ["--run-dir", str(run), "--no-progress"]) == 2


def test_resume_after_sigkill(tmp_path):
    """SIGKILL at two deterministic points (right after config.yaml is written, before the first
    checkpoint; right after the first checkpoint), a resume after each: every episode logged
    once, numbered 1..N, N the trainer's count (benchmarks/resume_kill.py does it at random
    times)."""
    spec = importlib.util.spec_from_file_location(
        "resume_kill", Path(__file__).resolve().parent.parent / "benchmarks" / "resume_kill.py")
    resume_kill = sys.modules.setdefault("resume_kill", importlib.util.module_from_spec(spec))
    spec.loader.exec_module(resume_kill)
    report = resume_kill.kill_and_resume(tmp_path, ["config", "checkpoint"],
                                         [*resume_kill.TINY, "train.eval_episodes=0"])
    assert report.problems == [], report.problems
    assert report.kills == 2 and report.runs == 1 and report.episodes >= 6
    assert report.attempts[0].stage == "before the first checkpoint"
    assert "starting it from scratch" in report.attempts[1].said
    assert report.attempts[-1].said.startswith("resumed ")


class Arbitrary:
    """An object that a weights-only load must refuse to unpickle."""


def test_policy_loads_with_weights_only(tmp_path):
    bad = tmp_path / "bad.pt"
    torch.save({"actor": {}, "arbitrary": Arbitrary()}, bad)
    with pytest.raises(Exception, match="weights_only"):
        load(bad)
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        load(tmp_path / "missing.pt")


def test_nan_loss_stops_with_a_clear_message(tmp_path, monkeypatch):
    from ahrm_stack.learning import trainer as trainer_module

    original = trainer_module.make_loss

    def poisoned(config, modules):
        loss, advantage = original(config, modules)
        forward = loss.forward

        def nan_forward(batch):
            out = forward(batch)
            out["loss_objective"] = out["loss_objective"] * float("nan")
            return out

        loss.forward = nan_forward
        return loss, advantage

    original_lean = trainer_module.lean_loss_for

    def poisoned_lean(config, modules):  # the loss the trainer computes with where it applies
        lean = original_lean(config, modules)
        if lean is None:
            return None

        def nan_call(batch):
            out = lean(batch)
            out["loss_objective"] = out["loss_objective"] * float("nan")
            return out

        return nan_call

    monkeypatch.setattr(trainer_module, "make_loss", poisoned)
    monkeypatch.setattr(trainer_module, "lean_loss_for", poisoned_lean)
    with pytest.raises(SystemExit, match="non-finite loss"):
        main(SMALL + ["train.episodes=5", "--run-dir", str(tmp_path / "nan"), "--no-progress"])
    assert not list((tmp_path / "nan").glob("checkpoints/*.pt"))


def test_bad_config_key_is_named(capsys):
    assert main(["ppo.learning_rat=1", "--no-progress"]) == 2
    assert "unknown config key 'ppo.learning_rat'" in capsys.readouterr().err


def test_same_seed_same_training(tmp_path):
    runs = []
    for name in ("a", "b"):
        run = tmp_path / name
        assert main(SMALL + ["train.episodes=4", "train.eval_episodes=0", "--run-dir", str(run),
                             "--no-progress"]) == 0
        episodes = [{k: v for k, v in row.items()} for row in _rows(run / "episodes.csv")]
        batches = [{k: v for k, v in row.items() if k != "seconds"} for row in _rows(run / "batches.csv")]
        runs.append((episodes, batches))
    assert runs[0] == runs[1]


def test_update_threads_are_set_for_the_update_and_restored(monkeypatch):
    """``train.update_threads`` (at most the machine's CPUs) inside the update, the trainer's count
    outside it, also when the update raises."""
    import os

    from ahrm_stack.config import load_config
    from ahrm_stack.learning import trainer as trainer_module

    before = torch.get_num_threads()
    with trainer_module.update_threads(64) as used:
        assert used == torch.get_num_threads() == (os.cpu_count() or 1)
    assert torch.get_num_threads() == before
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    with trainer_module.update_threads(2) as used:
        assert used == torch.get_num_threads() == 1
    monkeypatch.undo()
    with pytest.raises(RuntimeError, match="inside"):
        with trainer_module.update_threads(2):
            raise RuntimeError("inside")
    assert torch.get_num_threads() == before
    seen = []
    trainer = trainer_module.Trainer(load_config([*SMALL, "ppo.frames_per_batch=64", "ppo.mini_batch_size=32",
                                                  "ppo.epochs=1", "train.update_threads=2"]), collect_demos=False)
    compute = trainer.compute_loss

    def counting(batch):
        seen.append(torch.get_num_threads())
        return compute(batch)

    trainer.compute_loss = counting
    trainer.iteration()
    trainer.close()
    assert seen == [min(2, os.cpu_count() or 1)] * 2 and torch.get_num_threads() == before
