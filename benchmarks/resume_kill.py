"""Kill training with SIGKILL at random times, resume it, and check that no episode is lost or
repeated.

    python benchmarks/resume_kill.py [--kills 10] [--seed 0] [--workdir DIR] [key=value ...]

A tiny run (:data:`TINY`, plus any ``key=value`` given) is timed once uninterrupted: T s in all,
S s until its run folder appears (imports, validation, building the environments). Then the same
run is started in a subprocess and killed after a delay drawn uniformly over that start's expected
life (S plus the share of T - S still to do, from the newest checkpoint); the next start is
``--resume RUN`` (or a fresh start when the kill came before the run folder existed), again killed
at a random time, until ``--kills`` kills have hit a running process; the last start runs to the
end. A start that finishes before its kill is due completes its run (checked), and the next kill
goes to a new run; so does a run whose training is complete (its next start runs to the end). The kills land in every stage: imports, environment building, before the first
checkpoint, between checkpoints, while saving, in the final evaluation.

Checked after every kill: every episode the newest intact checkpoint counts has its row on disk
(no work lost). Checked at the end: every start that was not killed exited 0; ``episodes.csv``
numbers its episodes 1..N, each once, with N the trainer's count in the final checkpoint and in
``policy.pt``; ``batches.csv`` numbers 1..B likewise; ``events.jsonl`` and ``evaluations.csv``
hold nothing past the run and no evaluation twice; ``diagnostics.png`` exists.
Exit status 0 when everything holds. ``tests/test_resume.py`` runs it with deterministic kill
points.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ahrm_stack import cli

ROOT = Path(__file__).resolve().parent.parent
TINY = ["train.episodes=6", "task.episode.duration=2", "train.warm_start=none", "ppo.bc_coeff=0",
        "train.eval_episodes=1", "train.eval_every=2", "ppo.frames_per_batch=64",
        "ppo.mini_batch_size=32", "ppo.hidden_sizes=[32,32]", "train.checkpoint_every=1",
        "train.keep_checkpoints=2"]


@dataclass
class Attempt:
    command: str  # "fresh" or "resume"
    killed_at: float | None  # s after the start, None: ran to its end
    returncode: int
    stage: str  # where the kill landed (or "completed")
    said: str  # the start's own line about what it did (resumed / from scratch / ...)


@dataclass
class Report:
    attempts: list[Attempt] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    episodes: int = 0  # over the finished runs
    runs: int = 0  # finished runs

    @property
    def kills(self) -> int:
        return sum(a.killed_at is not None for a in self.attempts)


def _environment() -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return env


def _command(run_dir: Path, overrides: list[str], fresh: bool) -> list[str]:
    head = [sys.executable, "-m", "ahrm_stack.train"]
    if fresh:
        return [*head, *overrides, "--run-dir", str(run_dir), "--no-progress"]
    return [*head, "--resume", str(run_dir), "--no-progress"]


def _newest_checkpoint(run_dir: Path) -> tuple[str, dict | None]:
    """(name, state) of the newest intact checkpoint, ("", None) when there is none."""
    from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager

    manager = CheckpointManager(run_dir / "checkpoints", 1)
    try:
        restored = manager.restore()
    except CheckpointError:
        return "", None
    return (restored.path.name if restored.path else ""), restored.state


def _stage(run_dir: Path) -> str:
    if not (run_dir / "config.yaml").is_file():
        return "start-up; before the run folder"
    checkpoints = sorted((run_dir / "checkpoints").glob("ckpt-*.pt"))
    if not checkpoints:
        return "before the first checkpoint"
    if (run_dir / "policy.pt").is_file():
        return "after training (final save / evaluation)"
    return f"after {checkpoints[-1].name}"


def _numbers(path: Path, key: str) -> list[int]:
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        lines = handle.read().splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines.pop()  # a row cut off by the kill
    return [int(row[key]) for row in csv.DictReader(lines)]


def check_after_kill(run_dir: Path) -> list[str]:
    """No work lost: every episode the newest intact checkpoint counts has its row on disk."""
    name, state = _newest_checkpoint(run_dir)
    if state is None:
        return []
    counted = state["counters"]["episodes"]
    on_disk = set(_numbers(run_dir / "episodes.csv", "episode"))
    missing = sorted(set(range(1, counted + 1)) - on_disk)
    return [f"after a kill: {name} counts {counted} episodes, episodes.csv lacks {missing}"] if missing else []


def check_finished(run_dir: Path) -> tuple[int, list[str]]:
    """The end state of a finished run: (episodes, problems)."""
    import torch

    problems = []
    name, state = _newest_checkpoint(run_dir)
    if state is None:
        return 0, [f"{run_dir}: no readable checkpoint at the end"]
    counters = state["counters"]
    episodes = _numbers(run_dir / "episodes.csv", "episode")
    if episodes != list(range(1, counters["episodes"] + 1)):
        problems.append(f"episodes.csv numbers {episodes}, the trainer counted {counters['episodes']}")
    batches = _numbers(run_dir / "batches.csv", "batch")
    if batches != list(range(1, counters["batches"] + 1)):
        problems.append(f"batches.csv numbers {batches}, the trainer counted {counters['batches']}")
    evaluations = _numbers(run_dir / "evaluations.csv", "episode")
    if evaluations != sorted(set(evaluations)) or any(e > counters["episodes"] for e in evaluations):
        problems.append(f"evaluations.csv episodes {evaluations} (repeated or past the run)")
    for line in (run_dir / "events.jsonl").read_text().splitlines():
        if not 1 <= json.loads(line)["episode"] <= counters["episodes"]:
            problems.append(f"events.jsonl: an event past the run: {line}")
            break
    policy = torch.load(run_dir / "policy.pt", weights_only=True)
    if policy["episodes"] != counters["episodes"]:
        problems.append(f"policy.pt says {policy['episodes']} episodes, {name} {counters['episodes']}")
    if not (run_dir / "diagnostics.png").is_file():
        problems.append("no diagnostics.png")
    return counters["episodes"], problems


def _said(stdout: str, stderr: str) -> str:
    for line in (stdout + stderr).splitlines():
        if line.startswith(("resumed ", "resume: ", "note: ", "warning: ", "error: ")):
            return line.strip()
    return ""


def _run(command: list[str], kill: float | str | None, run_dir: Path, logs: Path,
         index: int) -> tuple[float | None, int, str, str, str, float | None]:
    """Run ``command``; kill it after ``kill`` s (a float) or once ``run_dir`` reaches a stage
    (``"config"``: config.yaml exists; ``"checkpoint"``: a checkpoint exists). Returns
    (killed_at or None, returncode, stage at the kill, stdout, stderr, seconds until the run
    folder held config.yaml or None)."""
    out, err = logs / f"{index:02d}.out", logs / f"{index:02d}.err"
    with open(out, "w") as stdout, open(err, "w") as stderr:
        started = time.perf_counter()
        proc = subprocess.Popen(command, stdout=stdout, stderr=stderr, env=_environment(), cwd=logs)
        killed_at, stage, setup = None, "completed", None
        existed = (run_dir / "config.yaml").is_file()
        while proc.poll() is None:
            now = time.perf_counter() - started
            if setup is None and not existed and (run_dir / "config.yaml").is_file():
                setup = now
            due = (isinstance(kill, float) and now >= kill) or (
                kill == "config" and (run_dir / "config.yaml").is_file()) or (
                kill == "checkpoint" and any((run_dir / "checkpoints").glob("ckpt-*.pt")))
            if due:
                stage = _stage(run_dir)
                os.kill(proc.pid, signal.SIGKILL)
                proc.wait()
                killed_at = now
                break
            time.sleep(0.005)
        returncode = proc.wait()
    return killed_at, returncode, stage, out.read_text(), err.read_text(), setup


Kill = float | str | Callable[[Path], float]


def kill_and_resume(workdir: Path, kills: list[Kill], overrides: list[str],
                    timing: Timing | None = None) -> Report:
    """Start a run, kill it at each of ``kills`` in turn (a delay in s; a function of the run
    folder giving the delay, drawn when the start begins; or the stages "config" / "checkpoint"),
    resuming after each kill; a start that ends before its kill is due completes that run
    (checked), and the remaining kills go to a new run. The last run finishes."""
    logs = workdir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    report = Report()
    pending: list[float | str] = list(kills)
    runs = 0
    run_dir = workdir / f"run{runs}"
    index = 0
    while index < 5 * (len(kills) + 1):
        kill = pending[0] if pending else None
        if callable(kill):
            kill = float(kill(run_dir))
        fresh = not (run_dir / "config.yaml").is_file()
        started = time.perf_counter()
        killed_at, returncode, stage, stdout, stderr, setup = _run(
            _command(run_dir, overrides, fresh), kill, run_dir, logs, index)
        if killed_at is None and fresh and timing is not None:
            timing.observe(time.perf_counter() - started, setup)
        if killed_at is not None and not fresh and not _said(stdout, stderr):
            stage = f"start-up; folder {stage}"
        index += 1
        attempt = Attempt("fresh" if fresh else "resume", killed_at, returncode, stage,
                          _said(stdout, stderr))
        report.attempts.append(attempt)
        if killed_at is not None:
            pending.pop(0)
            report.problems += [f"{run_dir.name}: {p}" for p in check_after_kill(run_dir)]
            continue
        if returncode != 0:
            last = stderr.strip().splitlines()[-1] if stderr.strip() else ""
            report.problems.append(f"start {index - 1} ({attempt.command}) exited {returncode}: {last}")
            return report
        episodes, problems = check_finished(run_dir)
        report.episodes += episodes
        report.runs += 1
        report.problems += [f"{run_dir.name}: {p}" for p in problems]
        if not pending:
            return report
        runs += 1
        run_dir = workdir / f"run{runs}"
    report.problems.append(f"{index} starts and still not done")
    return report


def measure(workdir: Path, overrides: list[str]) -> tuple[float, float]:
    """One uninterrupted run: (seconds to its end, seconds until its run folder appears: imports,
    validation and building the environments)."""
    run_dir = workdir / "reference"
    started = time.perf_counter()
    proc = subprocess.Popen(_command(run_dir, overrides, fresh=True), env=_environment(), cwd=workdir,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    setup = None
    while proc.poll() is None:
        if setup is None and (run_dir / "config.yaml").is_file():
            setup = time.perf_counter() - started
        time.sleep(0.005)
    if proc.returncode != 0:
        raise SystemExit(f"the uninterrupted run failed (exit {proc.returncode})")
    total = time.perf_counter() - started
    return total, setup if setup is not None else total


@dataclass
class Timing:
    """Seconds of one uninterrupted start: in all, and until its run folder appears. Updated
    from every start that runs to its end (the machine's load changes)."""

    total: float
    setup: float

    def observe(self, total: float, setup: float | None) -> None:
        self.total = 0.5 * (self.total + total)
        if setup is not None:
            self.setup = 0.5 * (self.setup + setup)


def lifetime_delay(timing: Timing, episodes: int, rng: random.Random) -> Callable[[Path], float]:
    """A kill time drawn uniformly over the expected life of the next start: setup (imports,
    building) plus the share of the run's work still to do, from the newest intact checkpoint.
    A run whose training is complete is let finish (infinite delay): the next kill goes to a new
    run instead of to the start-up of one more resume with nothing left to train."""
    def delay(run_dir: Path) -> float:
        _, state = _newest_checkpoint(run_dir) if (run_dir / "checkpoints").is_dir() else ("", None)
        done = min(state["counters"]["episodes"] / episodes, 1.0) if state else 0.0
        if done >= 1.0:
            return float("inf")
        rest = (timing.total - timing.setup) * (1.0 - done)
        return rng.uniform(0.0, timing.setup + rest)
    return delay


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--kills", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0, help="of the kill times")
    parser.add_argument("--workdir", help="where the runs go, kept (default: a temporary folder, removed "
                        "at the end unless a problem was found)")
    parser.add_argument("overrides", nargs="*", help="key=value on top of the tiny run")
    args = parser.parse_args()
    cli.quiet(args.verbose)
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="resume-kill-"))
    workdir.mkdir(parents=True, exist_ok=True)
    overrides = [*TINY, *args.overrides]
    timing = Timing(*measure(workdir, overrides))
    from ahrm_stack.config import load_config

    episodes = load_config(overrides).train.episodes
    rng = random.Random(args.seed)
    kills: list[Kill] = [lifetime_delay(timing, episodes, rng) for _ in range(args.kills)]
    print(f"one uninterrupted run: {timing.total:.1f} s, its run folder after {timing.setup:.1f} s; "
          f"each start is killed at a time drawn uniformly from [0, start-up + the share of the "
          f"training still to do]; folder {workdir}")
    report = kill_and_resume(workdir, kills, overrides, timing)
    if not args.workdir and not report.problems:
        shutil.rmtree(workdir, ignore_errors=True)
    print("    start    when                        folder at the kill                     the start said")
    for i, attempt in enumerate(report.attempts):
        when = f"killed at {attempt.killed_at:5.2f} s" if attempt.killed_at is not None else "ran to the end"
        print(f"{i:2d} {attempt.command:6s} {when:>18s}  rc {attempt.returncode:>3}  "
              f"{attempt.stage:42s} {attempt.said[:110]}")
    before_first = sum(a.killed_at is not None and "before" in a.stage for a in report.attempts)
    print(f"{report.kills} kills ({before_first} before the first checkpoint), "
          f"{len(report.attempts)} starts, {report.runs} runs finished, {report.episodes} episodes")
    if report.problems:
        for problem in report.problems:
            print(f"PROBLEM: {problem}")
        print(f"the runs are kept for inspection in {workdir}")
        return 1
    print("every resume completed; episodes.csv numbers 1..N exactly once, N = the trainer's count")
    return 0


if __name__ == "__main__":
    sys.exit(main())
