"""A training run's folder: its resolved ``config.yaml``, its logs and how a run starts in it.

A run folder holds ``config.yaml`` (written atomically; a new folder appears only once it holds it),
``checkpoints/`` (:class:`~ahrm_stack.learning.checkpoint.CheckpointManager`), ``episodes.csv``,
``batches.csv``, ``evaluations.csv``, ``events.jsonl`` and TensorBoard logs in ``tb/``
(:class:`RunLog`), interim policies in ``policies/`` and at the end ``policy.pt``.

The logs always match the checkpoint: on resume :func:`repair_logs` cuts them back to it (rows
logged after it are dropped: the resumed run logs those episodes again), repaired files are written
atomically, and :func:`start_run` checks everything before the first write.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import os
import time
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Iterator

from ahrm_stack.atomic import write_atomically
from ahrm_stack.config import Config, ConfigError
from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager, Restored
from ahrm_stack.names import NUM_PHASES, OBJECTIVE_NAMES
from ahrm_stack.run_config import run_config_text

if TYPE_CHECKING:
    from ahrm_stack.learning.trainer import Trainer

EPISODE_FIELDS = ["episode", "frames", "steps", "duration", "success", "time_to_success",
                  "touched_steps", "learning_return", "phase_steps", "phases_visited",
                  "component_sums", "closest_approach", "cube_displacement", "cube_travel",
                  "constraint_terminated", "interventions", "joint_limit_violations", "failure_mode",
                  "orders", "levels", "lane_agrees", "constraint_excluded"]
BATCH_FIELDS = ["batch", "frames", "episodes", "loss_objective", "loss_critic", "loss_entropy",
                "entropy", "kl_approx", "bc_loss", "std", "updates", "grad_norm", "seconds",
                "curriculum_level", "success_share", "reach_share", "touch_share", "constraint_share",
                "lane_agreement"]
# the batch's learning diagnostics (issue 56), over the episodes that ended in it: won, reached the
# cube (phase 3 entered), touched an obstacle, cut or left out of the update by the hierarchy's
# constraint, and among the episodes that pushed the cube along a lane, the share by the planner's
# lane; blank with none

CLONE_POLICY = "policies/clone.pt"  # the warm-started policy before any PPO update (warm_start: bc)
EVALUATION_FIELDS = ["episode", "frames", "episodes", "successes", "success_rate", "touched_episodes",
                     "time_mean", "time_std", "interventions_per_episode", "joint_limit_violations"]



# ----------------------------------------------------------------------------------------------
# Logs that always match the checkpoint: written atomically when repaired, cut back on resume.
# ----------------------------------------------------------------------------------------------

LOGS = {"episodes.csv": (EPISODE_FIELDS, "episode"), "batches.csv": (BATCH_FIELDS, "batch"),
        "evaluations.csv": (EVALUATION_FIELDS, "episode")}  # file: (columns, the row's number)


def has_checkpoint(run_dir: Path | str) -> bool:
    """Whether a run folder holds a checkpoint to resume from (training started and was saved)."""
    return any((Path(run_dir) / "checkpoints").glob("ckpt-*.pt"))


def trained(run_dir: Path | str) -> bool:
    """Whether a run's training finished: its final ``policy.pt`` is written (the last thing
    training writes, atomically)."""
    return (Path(run_dir) / "policy.pt").is_file()


def _write_atomically(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` so that a kill at any moment leaves the old or the new file."""
    write_atomically(path, text)


def _complete_lines(path: Path) -> tuple[list[str], int]:
    """The file's lines that end in a newline, and 1 when a last line cut off by a kill was
    dropped (else 0)."""
    if not path.is_file():
        return [], 0
    lines = path.read_text(errors="replace").splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines.pop()
        return lines, 1
    return lines, 0


def _number(value: object) -> int | None:
    try:
        return int(str(value))
    except ValueError:
        return None


def repair_csv(path: Path, fields: list[str], key: str, limit: int) -> tuple[int, int]:
    """Rewrite ``path`` as its header and the rows whose ``key`` is 1..``limit`` (0..``limit`` for
    evaluations, whose first row is episode 0), each number once (the last row written wins: it
    came from the run that continued), in order. A missing header (a file created empty and then
    appended to) is restored, a row cut off by a kill dropped. Returns (rows kept, rows dropped)."""
    lines, dropped = _complete_lines(path)
    rows = list(csv.reader(lines))
    header = fields
    if rows and rows[0] and _number(rows[0][0]) is None:  # a header line (ours or an older one)
        header, rows = rows[0], rows[1:]
    kept: dict[int, dict] = {}
    for cells in rows:
        row = dict(zip(header, cells))
        number = _number(row.get(key))
        if len(cells) != len(header) or number is None or number < 0 or number > limit:
            dropped += 1
            continue
        if number in kept:
            dropped += 1
        kept[number] = row
    buffer = _LineBuffer()  # the dialect RunLog appends with
    writer = csv.DictWriter(buffer, fieldnames=fields, restval="", extrasaction="ignore")
    writer.writeheader()
    for number in sorted(kept):
        writer.writerow(kept[number])
    _write_atomically(path, "".join(buffer.lines))
    return len(kept), dropped


class _LineBuffer:
    """A file-like sink for ``csv.writer`` that keeps what it writes."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def write(self, text: str) -> int:
        self.lines.append(text)
        return len(text)


def repair_events(path: Path, limit: int) -> tuple[int, int]:
    """Keep the reward-mechanism events of episodes 1..``limit`` (complete JSON lines only)."""
    lines, dropped = _complete_lines(path)
    kept = []
    for line in lines:
        try:
            episode = json.loads(line).get("episode")
        except (json.JSONDecodeError, AttributeError):
            episode = None
        if isinstance(episode, int) and 1 <= episode <= limit:
            kept.append(line)
        else:
            dropped += 1
    _write_atomically(path, "".join(kept))
    return len(kept), dropped


def repair_logs(run_dir: Path, episodes: int, batches: int) -> dict[str, int]:
    """Cut the run's logs back to a checkpoint of ``episodes`` episodes and ``batches`` batches
    (0, 0: a run that starts over); returns the rows dropped per file. Interim policies past it
    are removed with their evaluations."""
    dropped = {}
    limits = {"episodes.csv": episodes, "batches.csv": batches,
              "evaluations.csv": episodes if batches else -1}  # before the first batch: none kept
    for name, (fields, key) in LOGS.items():
        kept, dropped[name] = repair_csv(run_dir / name, fields, key, limits[name])
        if name == "episodes.csv" and kept != episodes:
            print(f"warning: {run_dir / name} holds {kept} of the {episodes} episodes of the "
                  "checkpoint (rows were removed by hand?); the missing ones cannot be rebuilt",
                  file=sys.stderr)
    _, dropped["events.jsonl"] = repair_events(run_dir / "events.jsonl", episodes)
    for policy in sorted((run_dir / "policies").glob("episode-*.pt")):
        number = _number(policy.stem.removeprefix("episode-"))
        if number is not None and (number > episodes or not batches):
            policy.unlink()
    return dropped



@dataclasses.dataclass
class WallTime:
    """Where a run's wall time went, in ``timing.json``: the training loop's wall seconds (from
    the first batch or interim evaluation to the end, warm start and set-up excluded), the
    batches' (collection and update: ``batches.csv``'s ``seconds`` summed) and their frames, the
    interim evaluations' own wall seconds and control steps (wherever they ran), and the seconds
    the loop spent running or waiting for them (with ``train.eval_beside`` only the waits).
    ``frames_per_second`` is frames over the loop's seconds; ``evaluation_share`` the waited
    share of them. Written at each checkpoint and at the end; a resumed run continues the totals
    of its last write."""

    FILE: ClassVar[str] = "timing.json"
    loop_seconds: float = 0.0
    batch_seconds: float = 0.0
    frames: int = 0  # training frames collected in those batches
    evaluation_seconds: float = 0.0
    evaluation_wait_seconds: float = 0.0
    evaluations: int = 0
    evaluation_steps: int = 0  # control steps the evaluations ran

    def __post_init__(self) -> None:
        self._since: float | None = None  # perf_counter when this process's loop started

    @classmethod
    def read(cls, run_dir: Path) -> "WallTime":
        path = Path(run_dir) / cls.FILE
        if not path.is_file():
            return cls()
        data = json.loads(path.read_text())
        return cls(**{f.name: data[f.name] for f in dataclasses.fields(cls) if f.name in data})

    def start(self) -> None:
        """The training loop starts (or resumes) now."""
        self._since = time.perf_counter()

    @contextlib.contextmanager
    def waiting(self) -> Iterator[None]:
        """Time the loop spends on interim evaluations (running them, or waiting for them)."""
        started = time.perf_counter()
        try:
            yield
        finally:
            self.evaluation_wait_seconds += time.perf_counter() - started

    def add_batch(self, seconds: float, frames: int) -> None:
        self.batch_seconds += seconds
        self.frames += frames

    def add_evaluation(self, seconds: float, steps: int) -> None:
        self.evaluation_seconds += seconds
        self.evaluations += 1
        self.evaluation_steps += steps

    def write(self, run_dir: Path) -> None:
        if self._since is not None:  # the loop's seconds so far, this process's included
            now = time.perf_counter()
            self.loop_seconds += now - self._since
            self._since = now
        loop = self.loop_seconds
        data = {**dataclasses.asdict(self),
                "evaluation_share": self.evaluation_wait_seconds / loop if loop > 0 else 0.0,
                "frames_per_second": self.frames / loop if loop > 0 else 0.0}
        _write_atomically(Path(run_dir) / self.FILE, json.dumps(data, indent=2))

class RunLog:
    """CSV, JSONL and TensorBoard logs of one run (appending on resume, after
    :func:`repair_logs` has cut them back to the checkpoint)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self.episodes = self._csv(run_dir / "episodes.csv", EPISODE_FIELDS)
        self.batches = self._csv(run_dir / "batches.csv", BATCH_FIELDS)
        self.evaluations = self._csv(run_dir / "evaluations.csv", EVALUATION_FIELDS)
        self.events = open(run_dir / "events.jsonl", "a")
        from torch.utils.tensorboard import SummaryWriter
        self.tb = SummaryWriter(str(run_dir / "tb"))

    @staticmethod
    def _csv(path: Path, fields: list[str]):
        new = not path.exists() or path.stat().st_size == 0
        if not new:  # a resumed run keeps the columns it was started with
            with open(path, newline="") as existing:
                fields = next(csv.reader(existing), []) or fields
        handle = open(path, "a", newline="")
        writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore", restval="")
        if new:
            writer.writeheader()
            handle.flush()
        return handle, writer

    def episode(self, row: dict) -> None:
        self.episodes[1].writerow({k: row[k] for k in EPISODE_FIELDS})
        n = row["episode"]
        for key in ("success", "learning_return", "touched_steps", "closest_approach",
                    "cube_displacement", "interventions"):
            self.tb.add_scalar(f"episode/{key}", float(row[key]), n)
        for k in range(NUM_PHASES):
            self.tb.add_scalar(f"phase{k + 1}/steps", row["phase_steps"][k], n)
            for i, name in enumerate(OBJECTIVE_NAMES):
                self.tb.add_scalar(f"phase{k + 1}/{name}", row["component_sums"][k][i], n)
            self.tb.add_scalar(f"phase{k + 1}/level", row["levels"][k], n)

    def batch(self, row: dict) -> None:
        self.batches[1].writerow({k: row.get(k, "") for k in BATCH_FIELDS})
        for key in BATCH_FIELDS[3:]:
            if isinstance(row.get(key), float):
                self.tb.add_scalar(f"train/{key}", row[key], row["frames"])

    def evaluation_episodes(self) -> set[int]:
        """The training episode counts of the interim evaluations logged so far."""
        self.evaluations[0].flush()
        with open(self.run_dir / "evaluations.csv", newline="") as handle:
            return {int(row["episode"]) for row in csv.DictReader(handle)}

    def evaluation(self, episodes: int, frames: int, table) -> None:
        """One interim deterministic evaluation (``train.eval_every`` / ``eval_every_frames``) of
        the policy after ``episodes`` training episodes and ``frames`` frames."""
        row = {"episode": episodes, "frames": frames, **dataclasses.asdict(table),
               "success_rate": table.success_rate}
        self.evaluations[1].writerow({k: row[k] for k in EVALUATION_FIELDS})
        self.evaluations[0].flush()
        self.tb.add_scalar("evaluation/success_rate", table.success_rate, episodes)

    def event(self, event) -> None:
        self.events.write(json.dumps({"episode": event.episode, "kind": event.kind,
                                      "phase": event.phase, "detail": event.detail}) + "\n")

    def flush(self) -> None:
        """Everything logged so far, on disk (before a checkpoint that counts it is written)."""
        for handle in (*(h for h, _ in (self.episodes, self.batches, self.evaluations)), self.events):
            handle.flush()
            os.fsync(handle.fileno())
        self.tb.flush()

    def close(self) -> None:
        self.flush()
        for handle, _ in (self.episodes, self.batches, self.evaluations):
            handle.close()
        self.events.close()
        self.tb.close()


# ----------------------------------------------------------------------------------------------
# Starting a run in its folder.
# ----------------------------------------------------------------------------------------------


def write_config(run_dir: Path, config: Config) -> None:
    """``run_dir/config.yaml`` (the resolved configuration, :func:`run_config_text`), atomically; a new
    folder appears only once it holds it, so a run folder without a config.yaml is never left
    behind by a kill."""
    text = run_config_text(config)
    if run_dir.is_dir():
        _write_atomically(run_dir / "config.yaml", text)
        return
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    for stale in run_dir.parent.glob(f".{run_dir.name}.*.tmp"):  # left by a start killed here
        shutil.rmtree(stale, ignore_errors=True)
    staging = run_dir.with_name(f".{run_dir.name}.{os.getpid()}.tmp")
    staging.mkdir()
    _write_atomically(staging / "config.yaml", text)
    try:
        os.rename(staging, run_dir)
    except OSError:  # created meanwhile by someone else
        (staging / "config.yaml").unlink()
        staging.rmdir()
        _write_atomically(run_dir / "config.yaml", text)


def start_run(config: Config, run_dir: Path, resume: bool, rewrite_config: bool,
               checkpoints: CheckpointManager, trainer: Trainer) -> Restored:
    """Everything a run checks before it writes, then the writes: config.yaml, corrupt
    checkpoints moved aside, the logs cut back to the checkpoint. Says what it did."""
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError(f"--run-dir {run_dir}: exists and is not a folder")
    if not resume and checkpoints.paths():
        raise ConfigError(f"{run_dir} already holds checkpoints; use --resume {run_dir}")
    restored = checkpoints.restore() if resume else Restored(None, None, [])
    if restored.state is not None:
        try:
            trainer.load_state_dict(restored.state)
        except (RuntimeError, KeyError, ValueError, TypeError) as error:
            first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise CheckpointError(f"{restored.path} does not fit this run's configuration (changed "
                                  f"by an override?): {first}") from None
    # validated: from here on the run folder is written
    if not resume or rewrite_config:
        write_config(run_dir, config)
    for path, reason in restored.skipped:
        print(f"warning: {reason}; moved aside to {path.name}.corrupt", file=sys.stderr)
    checkpoints.discard(restored.skipped)
    leftovers = any((run_dir / name).exists() for name in (*LOGS, "events.jsonl"))
    dropped = repair_logs(run_dir, trainer.episodes, trainer.batches)
    dropped_text = ", ".join(f"{n} {name}" for name, n in dropped.items() if n)
    if restored.state is not None and restored.path is not None:
        print(f"resumed {run_dir} from {restored.path.name}: episode {trainer.episodes}, batch "
              f"{trainer.batches}, {trainer.frames} frames"
              + (f"; dropped the rows logged after it ({dropped_text})" if dropped_text else ""))
    elif resume:
        print(f"resume: {run_dir} has no checkpoint (stopped before its first one); starting it "
              "from scratch" + (f", logs reset ({dropped_text} rows dropped)" if dropped_text else ""))
    elif leftovers:
        print(f"note: {run_dir} held the logs of a run stopped before its first checkpoint; starting "
              "from scratch" + (f", logs reset ({dropped_text} rows dropped)" if dropped_text else ""))
    return restored
