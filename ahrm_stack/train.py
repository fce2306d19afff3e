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
``diagnostics.png`` (per-episode diagnostics: where a failing run fails). ``--resume`` continues a run
that was stopped or killed from its last checkpoint, reward-mechanism state included.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import yaml
from tqdm import tqdm

from ahrm_stack.config import Config, ConfigError, apply_overrides, config_from_dict, load_raw
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.checkpoint import CheckpointManager
from ahrm_stack.learning.diagnostics import plot_run
from ahrm_stack.learning.evaluation import EVAL_SEED_OFFSET, EvaluationTable, run_episodes
from ahrm_stack.learning.trainer import Trainer, TrainingDiverged

EPISODE_FIELDS = ["episode", "frames", "steps", "duration", "success", "time_to_success",
                  "touched_steps", "learning_return", "phase_steps", "phases_visited",
                  "component_sums", "closest_approach", "cube_displacement", "cube_travel",
                  "constraint_terminated", "interventions", "joint_limit_violations", "failure_mode",
                  "orders", "levels"]
BATCH_FIELDS = ["batch", "frames", "episodes", "loss_objective", "loss_critic", "loss_entropy",
                "entropy", "kl_approx", "bc_loss", "std", "updates", "grad_norm", "seconds"]

CLONE_POLICY = "policies/clone.pt"  # the warm-started policy before any PPO update (warm_start: bc)
EVALUATION_FIELDS = ["episode", "frames", "episodes", "successes", "success_rate", "touched_episodes",
                     "time_mean", "time_std", "interventions_per_episode", "joint_limit_violations"]


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m ahrm_stack.train", description=__doc__.split("\n\n")[0])
    parser.add_argument("overrides", nargs="*", help="dotted config overrides, key=value")
    parser.add_argument("--run-dir", help="run folder (default: <train.runs_dir>/<method>-seed<seed>-<time>)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser.parse_args(argv)


def resolve_config(args: argparse.Namespace) -> tuple[Config, dict, Path]:
    if args.resume:
        run_dir = Path(args.resume)
        path = run_dir / "config.yaml"
        if not path.is_file():
            raise ConfigError(f"--resume {run_dir}: no config.yaml there; is it a run folder?")
        raw = yaml.safe_load(path.read_text())
    else:
        raw = load_raw()
    apply_overrides(raw, args.overrides)
    config = config_from_dict(raw)
    if args.resume:
        return config, raw, Path(args.resume)
    if args.run_dir:
        run_dir = Path(args.run_dir)
    else:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = Path(config.train.runs_dir) / f"{config.mechanism.method}-seed{config.train.seed}-{stamp}"
    return config, raw, run_dir


class RunLog:
    """CSV, JSONL and TensorBoard logs of one run (appending on resume)."""

    def __init__(self, run_dir: Path) -> None:
        self.episodes = self._csv(run_dir / "episodes.csv", EPISODE_FIELDS)
        self.batches = self._csv(run_dir / "batches.csv", BATCH_FIELDS)
        self.evaluations = self._csv(run_dir / "evaluations.csv", EVALUATION_FIELDS)
        self.events = open(run_dir / "events.jsonl", "a")
        from torch.utils.tensorboard import SummaryWriter
        self.tb = SummaryWriter(str(run_dir / "tb"))

    @staticmethod
    def _csv(path: Path, fields: list[str]):
        new = not path.exists()
        handle = open(path, "a", newline="")
        writer = csv.DictWriter(handle, fieldnames=fields)
        if new:
            writer.writeheader()
        return handle, writer

    def episode(self, row: dict) -> None:
        self.episodes[1].writerow({k: row[k] for k in EPISODE_FIELDS})
        n = row["episode"]
        for key in ("success", "learning_return", "touched_steps", "closest_approach",
                    "cube_displacement", "interventions"):
            self.tb.add_scalar(f"episode/{key}", float(row[key]), n)
        for k in range(3):
            self.tb.add_scalar(f"phase{k + 1}/steps", row["phase_steps"][k], n)
            for i, name in enumerate(("avoid", "manipulate", "time")):
                self.tb.add_scalar(f"phase{k + 1}/{name}", row["component_sums"][k][i], n)
            self.tb.add_scalar(f"phase{k + 1}/level", row["levels"][k], n)

    def batch(self, row: dict) -> None:
        self.batches[1].writerow({k: row.get(k, "") for k in BATCH_FIELDS})
        for key in BATCH_FIELDS[3:]:
            if isinstance(row.get(key), float):
                self.tb.add_scalar(f"train/{key}", row[key], row["frames"])

    def evaluation(self, trainer, table) -> None:
        """One interim deterministic evaluation (``train.eval_every``)."""
        row = {"episode": trainer.episodes, "frames": trainer.frames, **dataclasses.asdict(table),
               "success_rate": table.success_rate}
        self.evaluations[1].writerow({k: row[k] for k in EVALUATION_FIELDS})
        self.evaluations[0].flush()
        self.tb.add_scalar("evaluation/success_rate", table.success_rate, trainer.episodes)

    def event(self, event) -> None:
        self.events.write(json.dumps({"episode": event.episode, "kind": event.kind,
                                      "phase": event.phase, "detail": event.detail}) + "\n")

    def flush(self) -> None:
        for handle, _ in (self.episodes, self.batches, self.evaluations):
            handle.flush()
        self.events.flush()
        self.tb.flush()

    def close(self) -> None:
        self.flush()
        for handle, _ in (self.episodes, self.batches, self.evaluations):
            handle.close()
        self.events.close()
        self.tb.close()


def train(config: Config, raw: dict, run_dir: Path, resume: bool, progress: bool = True) -> Path:
    """Run (or continue) training; returns the run folder."""
    run_dir.mkdir(parents=True, exist_ok=True)
    if not resume:
        if (run_dir / "checkpoints").exists() and any((run_dir / "checkpoints").iterdir()):
            raise ConfigError(f"{run_dir} already holds checkpoints; use --resume {run_dir}")
        (run_dir / "config.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    torch.set_num_threads(config.train.threads)
    checkpoints = CheckpointManager(run_dir / "checkpoints", config.train.keep_checkpoints)
    trainer = Trainer(config)
    if resume:
        state = checkpoints.load_latest()
        if state is None:
            print(f"{run_dir}: no checkpoint yet, starting from scratch", file=sys.stderr)
        else:
            trainer.load_state_dict(state)
            print(f"resumed {run_dir} at episode {trainer.episodes}, {trainer.frames} frames")
    log = RunLog(run_dir)
    bar = tqdm(total=config.train.episodes, initial=min(trainer.episodes, config.train.episodes),
               unit="ep", disable=not progress, dynamic_ncols=True)
    recent: list[bool] = []
    interim = bool(config.train.eval_every and config.train.eval_episodes)
    # built once: every interim evaluation replays the same evaluation seeds on this environment
    eval_env = PushOffEnv(config.task, config.safety, seed=EVAL_SEED_OFFSET) if interim else None

    def evaluate_now() -> None:
        """One interim deterministic evaluation, logged, with the policy it evaluated."""
        summaries = run_episodes(eval_env, trainer.modules.actor, config.train.eval_episodes)
        log.evaluation(trainer, EvaluationTable.from_summaries(summaries))
        trainer.save_policy(run_dir / "policies" / f"episode-{trainer.episodes:05d}.pt")

    evaluated = trainer.episodes
    try:
        if trainer.episodes == 0 and config.train.warm_start == "bc":
            trainer.warm_start()  # the clone, kept: the policy before any PPO update
            trainer.save_policy(run_dir / CLONE_POLICY)
            if trainer.warm_start_report is not None:
                print(f"warm start: {trainer.warm_start_report}")
            if interim:
                evaluate_now()  # the curve's first point
        elif interim and trainer.episodes == 0:
            evaluate_now()
        while trainer.episodes < config.train.episodes:
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
            bar.update(min(len(result.episodes), config.train.episodes - bar.n))
            phase = result.episodes[-1]["phases_visited"][-1] if result.episodes else "-"
            bar.set_postfix(frames=trainer.frames, success=f"{np.mean(recent) if recent else 0:.2f}",
                            phase=phase, orders=trainer.mechanism_orders())
            if interim and (trainer.episodes // config.train.eval_every
                            > evaluated // config.train.eval_every):
                evaluated = trainer.episodes
                evaluate_now()
            if trainer.batches % config.train.checkpoint_every == 0:
                log.flush()
                checkpoints.save(trainer.state_dict(), trainer.batches)
        log.flush()
        checkpoints.save(trainer.state_dict(), trainer.batches)
        trainer.save_policy(run_dir / "policy.pt")
        plot_run(run_dir)
    finally:
        bar.close()
        log.close()
        trainer.close()
    return run_dir


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        config, raw, run_dir = resolve_config(args)
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    run_dir = train(config, raw, run_dir, resume=bool(args.resume), progress=not args.no_progress)
    minutes = (time.perf_counter() - started) / 60
    print(f"run folder: {run_dir}  ({minutes:.1f} min)")
    if config.train.eval_episodes:
        from ahrm_stack.learning.evaluation import evaluate_run
        table = evaluate_run(run_dir, config.train.eval_episodes)
        print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
