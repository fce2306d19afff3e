"""Evaluate a trained policy or the scripted controller: the paper's Table II metrics (spec §7).

    python -m ahrm_stack.evaluate RUN_DIR [--episodes 40] [--layout NAME] [--split validation|test]
                                  [--out DIR] [--video PATH [--video-episodes 0,1]]
    python -m ahrm_stack.evaluate --policy scripted [--episodes 40] [--layout NAME] ...
                                  [--config key=value ...]
    python -m ahrm_stack.evaluate RUN_DIR --suite [--split test]

Episodes use fresh seeds (never used in training) and the deterministic policy (the distribution's
mode), or the mink scripted controller, on the nominal task (no real arm's imperfections; a
family's cube mass and friction factors when it sets them). Every command passes through the
safety filter. Prints the table and writes ``evaluation.csv`` (one row per episode) and
``evaluation.json`` (the table, its split, seeds and the layout's training support) to ``--out``
(default: the run folder, or ``runs/scripted-eval`` for the scripted controller; a ``test``
subfolder of the run, or ``runs/scripted-eval-test``, for ``--split test``).

``--split``: the seeds of ``configs/seeds.yaml`` the episodes use. ``validation`` (the default)
is what interim evaluations, checkpoint choice, studies and benchmarks use; ``test`` is sealed:
only this final evaluation of a frozen policy reads it (and the experiment's final table, through
it), each read is appended to the test ledger (``configs/seeds.yaml`` ``test_ledger``; ``python -m
ahrm_stack.test_ledger``), and a policy's second read of a set is refused unless ``--reason TEXT``
says why (recorded beside it). Every output names its split.

``--layout`` names an entry of ``configs/layouts.yaml``: ``fixed`` / ``random`` (the run's own
modes), fixed layouts (``default``, ``mirrored``, ``corridor``, ``offset_cube``) or held-out random
layouts on reserved seeds (``heldout``, ``heldout_far`` with a wider radial range).
``--video PATH`` renders the chosen evaluation episodes (``--video-episodes``, default the first)
offscreen into one MP4 (``configs/video.yaml``: camera, size, frames per control step); rendering
only reads the simulation, so the episodes are the same with or without it.

The command line only: the evaluation itself is :mod:`ahrm_stack.evaluation`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ahrm_stack.cli import Parser, add_verbose_flag, quiet
from ahrm_stack.config import ConfigError
from ahrm_stack.evaluation import evaluate, evaluate_suite
from ahrm_stack.seeds import SPLITS


def _episode_list(text: str) -> list[int]:
    try:
        values = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected episode numbers like 0,1 — got {text!r}") from None
    if not values or values[0] < 0:
        raise argparse.ArgumentTypeError(f"expected episode numbers >= 0 like 0,1 — got {text!r}")
    return values


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = Parser(prog="python -m ahrm_stack.evaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", nargs="?", help="a training run folder (with policy.pt)")
    parser.add_argument("--policy", choices=["scripted"], help="evaluate the scripted controller")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--layout", help="a layout name of configs/layouts.yaml (default: the config's mode)")
    parser.add_argument("--split", choices=list(SPLITS), default="validation",
                        help="the seeds: validation (default) or the sealed test split (final evaluation "
                             "of a frozen policy only)")
    parser.add_argument("--reason", default="", metavar="TEXT",
                        help="why a policy reads a test set it has read before (recorded in the test "
                             "ledger, python -m ahrm_stack.test_ledger); refused without it")
    parser.add_argument("--out", help="folder for evaluation.csv and evaluation.json")
    parser.add_argument("--video", metavar="PATH", help="render the chosen episodes into this MP4")
    parser.add_argument("--video-episodes", type=_episode_list, default=[0], metavar="I,J",
                        help="evaluation episodes (0-based) in the video (default: 0)")
    parser.add_argument("--config", nargs="*", default=[], metavar="key=value",
                        help="config overrides (profile=NAME among them) applied to the run's "
                             "config, or to configs/ for --policy scripted, e.g. task.robot=j2s6s200")
    parser.add_argument("--suite", action="store_true",
                        help="every family of the evaluation suite (layouts.yaml, suite: true), with "
                             "the scripted controller on the same episodes; writes suite.md/json")
    parser.add_argument("--robustness", action="store_true",
                        help="--suite, then the robustness evaluation through the deploy loop "
                             "(python -m ahrm_stack.robustness, jaco2, same episode count) in its report")
    parser.add_argument("--no-scripted", action="store_true",
                        help="--suite without the scripted controller's columns")
    parser.add_argument("--policy-file", metavar="PT",
                        help="another policy of the run, e.g. RUN_DIR/policies/episode-00000.pt")
    parser.add_argument("--video-config", nargs="*", default=[], metavar="key=value",
                        help="overrides of configs/video.yaml, e.g. width=320 height=240")
    add_verbose_flag(parser)
    args = parser.parse_args(argv)
    if (args.run_dir is None) == (args.policy is None):
        parser.error("give either RUN_DIR or --policy scripted")
    if args.reason and args.split != "test":
        parser.error("--reason is for a re-read of the sealed test split: give it with --split test")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.robustness and not (args.suite and args.run_dir):
        parser.error("--robustness joins a run's --suite report: give RUN_DIR and --suite")
    if args.suite and (args.layout or args.video):
        parser.error("--suite evaluates every family: no --layout or --video with it")
    if args.policy_file and not args.run_dir:
        parser.error("--policy-file needs RUN_DIR (the run's config)")
    if args.video and args.video_episodes[-1] >= args.episodes:
        parser.error(f"--video-episodes {args.video_episodes} must be < --episodes ({args.episodes})")
    return args


def main(argv: list[str] | None = None) -> int:
    args = _parse(sys.argv[1:] if argv is None else argv)
    quiet(args.verbose)
    from ahrm_stack.env.video import RenderError
    from ahrm_stack.learning.checkpoint import CheckpointError
    try:
        if args.suite:
            evaluate_suite(Path(args.run_dir) if args.run_dir else None, args.episodes,
                           Path(args.out) if args.out else None, args.config,
                           with_scripted=not args.no_scripted,
                           policy_file=Path(args.policy_file) if args.policy_file else None,
                           robustness=args.robustness, split=args.split, reason=args.reason)
            return 0
        evaluate(Path(args.run_dir) if args.run_dir else None, args.episodes, args.layout,
                 Path(args.out) if args.out else None, Path(args.video) if args.video else None,
                 args.video_episodes, args.video_config, overrides=args.config,
                 policy_file=Path(args.policy_file) if args.policy_file else None, split=args.split,
                 reason=args.reason)
    except (ConfigError, RenderError, CheckpointError) as error:  # a refused pickle among them
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
