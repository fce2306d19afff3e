"""Training one reward mechanism with PPO: the configuration, the run folder and the training loop.

:func:`resolve_config` reads and validates the configuration (``configs/`` with overrides, or a
resumed run's ``config.yaml``) and names the run folder; :func:`train` runs (or continues) the
training into it: warm start, PPO iterations with logs, checkpoints and interim evaluations on the
validation split, and at the end ``policy.pt`` and ``diagnostics.png``. The command line is
``python -m ahrm_stack.train`` (:mod:`ahrm_stack.train`).
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from ahrm_stack.config import Config, ConfigError, load_config
from ahrm_stack.run_config import load_run_config

# torchrl announces its own deprecations at import, and dm_control turns every DeprecationWarning
# on (warnings.simplefilter('always')): on stderr they would bury a one-line error. The warnings
# of these imports are recorded and dropped; the warning filters are restored afterwards.
with warnings.catch_warnings(record=True):
    import torch
    from tqdm import tqdm

    from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager
    from ahrm_stack.learning.diagnostics import plot_run
    from ahrm_stack.learning.run_folder import CLONE_POLICY, RunLog, WallTime, start_run
    from ahrm_stack.learning.interim import Evaluated, InterimEvaluations
    from ahrm_stack.learning.pool import WorkerError
    from ahrm_stack.learning.trainer import DemonstrationsFailed, Trainer, TrainingDiverged
    from ahrm_stack.safety.constraints.base import ConstraintDefinitionError
    from ahrm_stack.safety.filter import SafetyFilterError


def exit_status(error: Exception) -> int:
    """For a command line around :func:`resolve_config` and :func:`train`: print the message of a
    failure the user can act on (``error: ...`` on stderr, one line but for a worker's own report)
    and return its exit status; re-raise any other error (a bug)."""
    failed = failure(error)
    if failed is None:
        raise error
    print(failed[1], file=sys.stderr)
    return failed[0]


def failure(error: BaseException) -> tuple[int, str] | None:
    """The exit status and the message (``error: ...``, one line but for a worker's own report) of
    a failure of :func:`resolve_config` or :func:`train` that the user can act on: 2 for the
    configuration, 1 for a checkpoint, the demonstrations, an environment process that failed
    before training began, or a run folder that cannot be created or written; None for any other
    error (a bug: let it raise)."""
    if isinstance(error, ConfigError):
        return 2, f"error: {error}"
    if isinstance(error, (CheckpointError, DemonstrationsFailed)):
        return 1, f"error: {error}"
    if isinstance(error, WorkerError):
        first, _, rest = str(error).partition("\n")
        return 1, f"error: {first}{chr(10) + rest if rest else ''}"
    if isinstance(error, OSError):
        return 1, f"error: {error.filename or ''}: {error.strerror or error}"
    return None


def resolve_config(overrides: Sequence[str] = (), run_dir: str | Path | None = None,
                   resume: str | Path | None = None) -> tuple[Config, Path]:
    """The validated configuration (``configs/`` or, with ``resume``, that run's ``config.yaml``,
    with the ``overrides``) and the run folder (``resume``, ``run_dir``, or by default
    ``<train.runs_dir>/<method>-seed<seed>-<time>``): what ``python -m ahrm_stack.train`` trains.
    Raises :class:`ConfigError` on a bad key or value, or a ``resume`` that is not a run folder."""
    if resume:
        run_dir = Path(resume)
        path = run_dir / "config.yaml"
        if not run_dir.is_dir():
            raise ConfigError(f"--resume {run_dir}: no such folder")
        if not path.is_file():
            raise ConfigError(f"--resume {run_dir}: no config.yaml there; is it a run folder? (a run "
                              "killed before writing it has nothing to resume: start it again)")
        return load_run_config(run_dir, list(overrides)), run_dir
    config = load_config(list(overrides))
    if run_dir:
        run_dir = Path(run_dir)
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
    timing = WallTime.read(run_dir) if resume else WallTime()  # where the run's wall time went (timing.json)

    def logged(episodes: int, frames: int, evaluated: Evaluated) -> None:
        log.evaluation(episodes, frames, evaluated.table)
        timing.add_evaluation(evaluated.seconds, evaluated.steps)

    # every interim evaluation replays the same evaluation seeds on one environment, here or in a
    # worker process beside training (train.eval_beside)
    evaluations = InterimEvaluations(config, run_dir, config.train.eval_beside, logged) if interim else None

    def evaluate_now() -> None:
        """One interim deterministic evaluation of the policy now, saved first (what the row evaluated)."""
        assert evaluations is not None
        policy_file = run_dir / "policies" / f"episode-{trainer.episodes:05d}.pt"
        with timing.waiting():
            trainer.save_policy(policy_file)
            evaluations.ask(trainer.modules.actor, policy_file, trainer.episodes, trainer.frames)

    def checkpoint_state() -> dict:
        """The trainer's state, and the interim evaluations still running beside it (a resumed
        run asks for them again)."""
        return {**trainer.state_dict(), "pending_evaluations": evaluations.pending() if evaluations else []}

    def ask_pending() -> None:
        """A resumed run's evaluations that its checkpoint recorded as pending, asked again unless
        their row was written after the checkpoint."""
        if evaluations is None or restored.state is None:
            return
        logged_episodes = log.evaluation_episodes()
        for item in restored.state.get("pending_evaluations", []):
            policy_file = Path(item["policy_file"])
            if item["episodes"] in logged_episodes:
                continue
            if not policy_file.is_file():
                print(f"warning: {policy_file} is gone: its interim evaluation is not made again", file=sys.stderr)
                continue
            evaluations.ask_saved(policy_file, item["episodes"], item["frames"])

    def drain(wait: bool) -> None:
        if evaluations is not None:
            with timing.waiting():
                evaluations.drain(wait)

    evaluated, evaluated_frames = trainer.episodes, trainer.frames

    def evaluation_due() -> bool:
        return bool((every and trainer.episodes // every > evaluated // every)
                    or (every_frames and trainer.frames // every_frames > evaluated_frames // every_frames))

    try:
        ask_pending()
        if trainer.batches == 0 and config.train.warm_start == "bc":
            trainer.warm_start()  # the clone, kept: the policy before any PPO update
            trainer.save_policy(run_dir / CLONE_POLICY)
            if trainer.warm_start_report is not None:
                print(f"warm start: {trainer.warm_start_report}")
        timing.start()
        if interim and trainer.batches == 0:
            evaluate_now()  # the curve's first point
        while not trainer.finished():
            try:
                frames_before = trainer.frames
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
            timing.add_batch(result.batch["seconds"], trainer.frames - frames_before)  # this batch's own
            # frames (a run resumed from before timing.json existed counts from its resume on)
            bar.update(min(result.batch["frames"] - bar.n if by_frames else len(result.episodes),
                           total - bar.n))
            phase = result.episodes[-1]["phases_visited"][-1] if result.episodes else "-"
            bar.set_postfix(frames=trainer.frames, success=f"{np.mean(recent) if recent else 0:.2f}",
                            phase=phase, orders=trainer.mechanism_orders())
            if interim and evaluation_due():
                evaluated, evaluated_frames = trainer.episodes, trainer.frames
                evaluate_now()
            drain(wait=False)
            if trainer.batches % config.train.checkpoint_every == 0:
                timing.write(run_dir)
                log.flush()  # the rows first: a checkpoint never counts a row that is not on disk
                checkpoints.save(checkpoint_state(), trainer.batches)
        drain(wait=True)
        log.flush()
        checkpoints.save(checkpoint_state(), trainer.batches)
        trainer.save_policy(run_dir / "policy.pt")
        timing.write(run_dir)
        try:
            plot_run(run_dir)
        except (ValueError, FileNotFoundError) as error:  # a plot is not worth losing the run over
            print(f"warning: no diagnostics plot: {error}", file=sys.stderr)
    except WorkerError as error:  # an environment process raised or died (train.env_workers)
        first, _, rest = str(error).partition("\n")
        raise SystemExit(f"training stopped: {first}. The last checkpoint is kept in "
                         f"{checkpoints.directory}; --resume continues from it.\n{rest}".rstrip()) from None
    finally:
        if evaluations is not None:
            evaluations.close()
        bar.close()
        log.close()
        trainer.close()
    return run_dir
