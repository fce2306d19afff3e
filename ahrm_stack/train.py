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

The command line only: the training itself is :mod:`ahrm_stack.learning.training`.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

from ahrm_stack.cli import Parser, add_verbose_flag, quiet

# torchrl and dm_control warn at import (see ahrm_stack.learning.training): recorded and dropped.
with warnings.catch_warnings(record=True):
    from ahrm_stack.learning.training import exit_status, resolve_config, train


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = Parser(prog="python -m ahrm_stack.train", description=__doc__.split("\n\n")[0])
    parser.add_argument("overrides", nargs="*", help="dotted config overrides, key=value")
    parser.add_argument("--run-dir", help="run folder (default: <train.runs_dir>/<method>-seed<seed>-<time>)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_verbose_flag(parser)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    quiet(args.verbose)
    started = time.perf_counter()
    try:
        config, run_dir = resolve_config(args.overrides, args.run_dir, args.resume)
        run_dir = train(config, run_dir, resume=bool(args.resume), progress=not args.no_progress,
                        rewrite_config=bool(args.resume and args.overrides))
    except Exception as error:
        return exit_status(error)
    minutes = (time.perf_counter() - started) / 60
    print(f"run folder: {run_dir}  ({minutes:.1f} min)")
    if config.train.eval_episodes:
        from ahrm_stack.learning.rollouts import evaluate_run
        table = evaluate_run(run_dir, config.train.eval_episodes)
        print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
