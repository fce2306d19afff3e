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
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from ahrm_stack.cli import add_verbose_flag, quiet
from ahrm_stack.config import Config, ConfigError, load_config
from ahrm_stack.run_config import load_run_config

# torchrl announces its own deprecations at import, and dm_control turns every DeprecationWarning
# on (warnings.simplefilter('always')): on stderr they would bury a one-line error. The warnings
# of these imports are recorded and dropped; the warning filters are restored afterwards.
with warnings.catch_warnings(record=True):
    import torch
    from tqdm import tqdm

    from ahrm_stack.env.realism import nominal
    from ahrm_stack.env.torchrl_env import PushOffEnv
    from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager
    from ahrm_stack.learning.diagnostics import plot_run
    from ahrm_stack.learning.run_folder import CLONE_POLICY, RunLog, start_run
    from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, EvaluationTable, run_episodes
    from ahrm_stack.learning.pool import WorkerError
    from ahrm_stack.learning.trainer import DemonstrationsFailed, Trainer, TrainingDiverged
    from ahrm_stack.safety.constraints.base import ConstraintDefinitionError
    from ahrm_stack.safety.filter import SafetyFilterError


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
        restored = start_run(config, run_dir, resume, rewrite_config, checkpoints, trainer)
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
