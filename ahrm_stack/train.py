"""Train one reward mechanism with PPO on the push-off task.

    python -m ahrm_stack.train [key=value ...] [--run-dir DIR] [--no-progress]
    python -m ahrm_stack.train --resume RUN_DIR [--no-progress]

Configuration: ``configs/*.yaml``, overridden by dotted ``key=value`` arguments (e.g.
``mechanism.method=ls train.episodes=50 ppo.hidden_sizes=[256,256,256]``; ``profile=paper`` applies
``configs/profiles/paper.yaml``, the paper-faithful configuration), validated at start-up.
A run folder holds the resolved ``config.yaml``, ``checkpoints/`` (atomic writes, rotated),
``episodes.csv`` (one row per episode), ``batches.csv`` (losses), ``events.jsonl`` (reward-mechanism
events), TensorBoard logs in ``tb/``, with ``train.eval_every`` interim deterministic evaluations in
``evaluations.csv`` and their policies in ``policies/``, and at the end ``policy.pt`` and
``diagnostics.png`` (per-episode diagnostics: where a failing run fails). Every evaluation a training
makes (interim, and ``evaluation.yaml`` at the end) uses the validation split of the run's own
layouts (``configs/seeds.yaml``); the test split is sealed while it runs. ``--resume`` continues a run
that was stopped or killed from its last checkpoint, reward-mechanism state included.

Resume never loses or repeats an episode and says what it did: the logs are cut back to the
checkpoint it continues from (rows logged after it are dropped: the resumed run logs those
episodes again), a torn or truncated checkpoint is named and skipped for the newest intact one,
a run killed before its first checkpoint starts over (its logs reset), and a folder whose
checkpoints are all unreadable is an error, never a silent restart. The whole configuration is
checked, and the environments built, before anything is written.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from ahrm_stack.cli import add_verbose_flag, quiet
from ahrm_stack.config import Config, ConfigError, load_config
from ahrm_stack.names import NUM_PHASES, OBJECTIVE_NAMES
from ahrm_stack.run_config import load_run_config, run_config_text

# torchrl announces its own deprecations at import, and dm_control turns every DeprecationWarning
# on (warnings.simplefilter('always')): on stderr they would bury a one-line error. The warnings
# of these imports are recorded and dropped; the warning filters are restored afterwards.
with warnings.catch_warnings(record=True):
    import torch
    from tqdm import tqdm

    from ahrm_stack.env.realism import nominal
    from ahrm_stack.env.torchrl_env import PushOffEnv
    from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager, Restored
    from ahrm_stack.learning.diagnostics import plot_run
    from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, EvaluationTable, run_episodes
    from ahrm_stack.learning.pool import WorkerError
    from ahrm_stack.learning.trainer import DemonstrationsFailed, Trainer, TrainingDiverged
    from ahrm_stack.safety.constraints.base import ConstraintDefinitionError
    from ahrm_stack.safety.filter import SafetyFilterError

EPISODE_FIELDS = ["episode", "frames", "steps", "duration", "success", "time_to_success",
                  "touched_steps", "learning_return", "phase_steps", "phases_visited",
                  "component_sums", "closest_approach", "cube_displacement", "cube_travel",
                  "constraint_terminated", "interventions", "joint_limit_violations", "failure_mode",
                  "orders", "levels"]
BATCH_FIELDS = ["batch", "frames", "episodes", "loss_objective", "loss_critic", "loss_entropy",
                "entropy", "kl_approx", "bc_loss", "std", "updates", "grad_norm", "seconds",
                "curriculum_level"]

CLONE_POLICY = "policies/clone.pt"  # the warm-started policy before any PPO update (warm_start: bc)
EVALUATION_FIELDS = ["episode", "frames", "episodes", "successes", "success_rate", "touched_episodes",
                     "time_mean", "time_std", "interventions_per_episode", "joint_limit_violations"]


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m ahrm_stack.train", description=__doc__.split("\n\n")[0])
    parser.add_argument("overrides", nargs="*", help="dotted config overrides, key=value")
    parser.add_argument("--run-dir", help="run folder (default: <train.runs_dir>/<method>-seed<seed>-<time>)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_verbose_flag(parser)
    return parser.parse_args(argv)


def resolve_config(args: argparse.Namespace) -> tuple[Config, Path]:
    """The validated configuration (``configs/`` or the resumed run's ``config.yaml``, with the
    overrides) and the run folder."""
    if args.resume:
        run_dir = Path(args.resume)
        path = run_dir / "config.yaml"
        if not run_dir.is_dir():
            raise ConfigError(f"--resume {run_dir}: no such folder")
        if not path.is_file():
            raise ConfigError(f"--resume {run_dir}: no config.yaml there; is it a run folder? (a run "
                              "killed before writing it has nothing to resume: start it again)")
        return load_run_config(run_dir, args.overrides), run_dir
    config = load_config(args.overrides)
    if args.run_dir:
        run_dir = Path(args.run_dir)
    else:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = Path(config.train.runs_dir) / f"{config.mechanism.method}-seed{config.train.seed}-{stamp}"
    return config, run_dir


# ----------------------------------------------------------------------------------------------
# Logs that always match the checkpoint: written atomically when repaired, cut back on resume.
# ----------------------------------------------------------------------------------------------

LOGS = {"episodes.csv": (EPISODE_FIELDS, "episode"), "batches.csv": (BATCH_FIELDS, "batch"),
        "evaluations.csv": (EVALUATION_FIELDS, "episode")}  # file: (columns, the row's number)


def _write_atomically(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` so that a kill at any moment leaves the old or the new file."""
    tmp = path.with_name(f".{path.name}.tmp")  # one writer per run folder
    with open(tmp, "w", newline="") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


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


class RunLog:
    """CSV, JSONL and TensorBoard logs of one run (appending on resume, after
    :func:`repair_logs` has cut them back to the checkpoint)."""

    def __init__(self, run_dir: Path) -> None:
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
                fields = next(csv.reader(existing), None) or fields
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

    def evaluation(self, trainer, table) -> None:
        """One interim deterministic evaluation (``train.eval_every`` / ``eval_every_frames``)."""
        row = {"episode": trainer.episodes, "frames": trainer.frames, **dataclasses.asdict(table),
               "success_rate": table.success_rate}
        self.evaluations[1].writerow({k: row[k] for k in EVALUATION_FIELDS})
        self.evaluations[0].flush()
        self.tb.add_scalar("evaluation/success_rate", table.success_rate, trainer.episodes)

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
# The run.
# ----------------------------------------------------------------------------------------------


def _write_config(run_dir: Path, config: Config) -> None:
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


def _start_run(config: Config, run_dir: Path, resume: bool, rewrite_config: bool,
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
        _write_config(run_dir, config)
    for path, reason in restored.skipped:
        print(f"warning: {reason}; moved aside to {path.name}.corrupt", file=sys.stderr)
    checkpoints.discard(restored.skipped)
    leftovers = any((run_dir / name).exists() for name in (*LOGS, "events.jsonl"))
    dropped = repair_logs(run_dir, trainer.episodes, trainer.batches)
    dropped_text = ", ".join(f"{n} {name}" for name, n in dropped.items() if n)
    if restored.state is not None:
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


def train(config: Config, run_dir: Path, resume: bool, progress: bool = True,
          rewrite_config: bool = False) -> Path:
    """Run (or continue) training; returns the run folder.

    Raises ``ConfigError`` (a bad value that only the built environment reveals, a fresh run into
    a folder with checkpoints) or :class:`CheckpointError` (no usable checkpoint to resume from)
    before anything is written. ``rewrite_config``: on resume, store ``config`` (the run's config
    with this resume's overrides) as the run's config.yaml. The whole run holds
    :func:`ahrm_stack.seeds.sealed`: its interim evaluations use the validation split, and nothing
    it calls can obtain a test seed.
    """
    from ahrm_stack.seeds import sealed

    with sealed():
        return _train(config, run_dir, resume, progress, rewrite_config)


def _train(config: Config, run_dir: Path, resume: bool, progress: bool, rewrite_config: bool) -> Path:
    """:func:`train`'s body, run inside the sealed test split."""
    cpus = os.cpu_count() or 1
    if config.train.threads > cpus:
        raise ConfigError(f"train.threads ({config.train.threads}) must be <= the {cpus} CPUs of this "
                          "machine")
    torch.set_num_threads(config.train.threads)
    checkpoints = CheckpointManager(run_dir / "checkpoints", config.train.keep_checkpoints)
    try:  # building the environments checks what the configuration alone cannot
        trainer = Trainer(config, collect_demos=False)
    except (SafetyFilterError, ConstraintDefinitionError) as error:
        raise ConfigError(f"safety: {error}") from None
    try:
        restored = _start_run(config, run_dir, resume, rewrite_config, checkpoints, trainer)
        trainer.collect_demos()
        if restored.state is not None:  # exactly the state saved, whatever the demos drew
            torch.set_rng_state(restored.state["torch_rng"])
    except BaseException:
        trainer.close()
        raise
    log = RunLog(run_dir)
    by_frames = bool(config.train.frames)  # the budget: train.frames when set, else train.episodes
    total = config.train.frames if by_frames else config.train.episodes
    done = trainer.frames if by_frames else trainer.episodes
    bar = tqdm(total=total, initial=min(done, total), unit="frame" if by_frames else "ep",
               disable=not progress, dynamic_ncols=True)
    recent: list[bool] = []
    every, every_frames = config.train.eval_every, config.train.eval_every_frames
    interim = bool((every or every_frames) and config.train.eval_episodes)
    # built once: every interim evaluation replays the same evaluation seeds on this environment
    eval_env = PushOffEnv(nominal(config.task), config.safety, seed=VALIDATION_SEED_OFFSET) if interim else None

    def evaluate_now() -> None:
        """One interim deterministic evaluation, logged, with the policy it evaluated."""
        summaries = run_episodes(eval_env, trainer.modules.actor, config.train.eval_episodes)
        log.evaluation(trainer, EvaluationTable.from_summaries(summaries))
        trainer.save_policy(run_dir / "policies" / f"episode-{trainer.episodes:05d}.pt")

    evaluated, evaluated_frames = trainer.episodes, trainer.frames

    def evaluation_due() -> bool:
        return bool((every and trainer.episodes // every > evaluated // every)
                    or (every_frames and trainer.frames // every_frames > evaluated_frames // every_frames))

    try:
        if trainer.batches == 0 and config.train.warm_start == "bc":
            trainer.warm_start()  # the clone, kept: the policy before any PPO update
            trainer.save_policy(run_dir / CLONE_POLICY)
            if trainer.warm_start_report is not None:
                print(f"warm start: {trainer.warm_start_report}")
            if interim:
                evaluate_now()  # the curve's first point
        elif interim and trainer.batches == 0:
            evaluate_now()
        while not trainer.finished():
            try:
                result = trainer.iteration()
            except TrainingDiverged as error:
                raise SystemExit(f"training stopped: {error}. The last good checkpoint is kept in "
                                 f"{checkpoints.directory}; nothing after it was written.") from None
            for row in result.episodes:
                log.episode(row)
                recent = (recent + [bool(row["success"])])[-20:]
            for event in result.events:
                log.event(event)
            log.batch(result.batch)
            bar.update(min(result.batch["frames"] - bar.n if by_frames else len(result.episodes),
                           total - bar.n))
            phase = result.episodes[-1]["phases_visited"][-1] if result.episodes else "-"
            bar.set_postfix(frames=trainer.frames, success=f"{np.mean(recent) if recent else 0:.2f}",
                            phase=phase, orders=trainer.mechanism_orders())
            if interim and evaluation_due():
                evaluated, evaluated_frames = trainer.episodes, trainer.frames
                evaluate_now()
            if trainer.batches % config.train.checkpoint_every == 0:
                log.flush()  # the rows first: a checkpoint never counts a row that is not on disk
                checkpoints.save(trainer.state_dict(), trainer.batches)
        log.flush()
        checkpoints.save(trainer.state_dict(), trainer.batches)
        trainer.save_policy(run_dir / "policy.pt")
        try:
            plot_run(run_dir)
        except (ValueError, FileNotFoundError) as error:  # a plot is not worth losing the run over
            print(f"warning: no diagnostics plot: {error}", file=sys.stderr)
    except WorkerError as error:  # an environment process raised or died (train.env_workers)
        first, _, rest = str(error).partition("\n")
        raise SystemExit(f"training stopped: {first}. The last checkpoint is kept in "
                         f"{checkpoints.directory}; --resume continues from it.\n{rest}".rstrip()) from None
    finally:
        bar.close()
        log.close()
        trainer.close()
    return run_dir


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    quiet(args.verbose)
    started = time.perf_counter()
    try:
        config, run_dir = resolve_config(args)
        run_dir = train(config, run_dir, resume=bool(args.resume), progress=not args.no_progress,
                        rewrite_config=bool(args.resume and args.overrides))
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except (CheckpointError, DemonstrationsFailed) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except WorkerError as error:  # an environment process failed before training began
        first, _, rest = str(error).partition("\n")
        print(f"error: {first}{chr(10) + rest if rest else ''}", file=sys.stderr)
        return 1
    except OSError as error:  # the run folder cannot be created or written
        print(f"error: {error.filename or ''}: {error.strerror or error}", file=sys.stderr)
        return 1
    minutes = (time.perf_counter() - started) / 60
    print(f"run folder: {run_dir}  ({minutes:.1f} min)")
    if config.train.eval_episodes:
        from ahrm_stack.learning.rollouts import evaluate_run
        table = evaluate_run(run_dir, config.train.eval_episodes)
        print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
