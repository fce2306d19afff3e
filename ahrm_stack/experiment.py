"""The four-method experiment: train and evaluate AHRM, MHRM, FHRM and LS over several seeds with
identical budgets, on Ray, then write the report (``ahrm_stack.report``).

    python -m ahrm_stack.experiment [--methods ahrm mhrm fhrm ls] [--seeds 3] [--episodes 300] [--frames N]
                                    [--out DIR] [--address RAY_ADDRESS] [--config key=value ...]

Defaults come from ``configs/experiment.yaml``. ``--config`` overrides go to the training config
(``task.episode.duration=30``), to ``experiment.*`` (``experiment.eval_episodes=10``) or to
``video.*`` (``video.width=320``). Every (method, seed) run is one Ray task (``cpus_per_run`` CPUs;
a local Ray instance by default, a cluster with ``--address``) that trains in-process
(``ahrm_stack.learning.training.train``) into ``OUT/runs/<method>-seed<seed>/``, then evaluates the frozen
deterministic policy (``eval/``, and the suite) on ``experiment.split``'s seeds (``validation`` by
default; ``test``, the sealed split, is read only here, after training, once per policy, and
recorded in the test ledger) and, for the first seed, renders one
evaluation episode to ``OUT/videos/<method>.mp4``. A finished run writes ``done.json`` and is skipped on a rerun; a run
stopped during training resumes from its last checkpoint, and those start first; the others start
seed by seed (every method of seed 0, then of seed 1, ...), so that a grid stopped part-way holds
whole seeds of every method; a failed run writes ``failed.json`` (the
error text, also in the report) and the others go on. The scripted controller's row is one more
task (``OUT/scripted/``). Each run's output goes to its ``log.txt``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from ahrm_stack.cli import Parser, add_verbose_flag, quiet
from ahrm_stack.config import ConfigError, ExperimentConfig, VideoConfig, load_extra
from ahrm_stack.experiment_grid import FAILED, GRID, build_grid, check_finished, run_grid, write_json


def _parse(argv: Sequence[str]) -> argparse.Namespace:
    parser = Parser(prog="python -m ahrm_stack.experiment", description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", nargs="+", help="reward mechanisms (default: configs/experiment.yaml)")
    parser.add_argument("--seeds", type=int, help="training seeds 0..N-1 per method")
    parser.add_argument("--episodes", type=int, help="training episodes per run (with frames 0)")
    parser.add_argument("--frames", type=int, help="training frames per run (0: --episodes decides)")
    parser.add_argument("--out", default="runs/experiment", help="the grid and report folder")
    parser.add_argument("--address", help="Ray cluster address (default: a local Ray instance)")
    parser.add_argument("--config", nargs="*", default=[], metavar="key=value",
                        help="overrides: training config keys, experiment.*, video.*")
    parser.add_argument("--no-video", action="store_true", help="no evaluation videos")
    parser.add_argument("--report-only", action="store_true", help="rewrite the report, run nothing")
    add_verbose_flag(parser)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse(sys.argv[1:] if argv is None else argv)
    quiet(args.verbose)
    from ahrm_stack.env.video import RenderError
    try:
        grid = build_grid(args)
        experiment = load_extra(ExperimentConfig, "experiment", grid["experiment_overrides"])
        video = load_extra(VideoConfig, "video", grid["video_overrides"])
        out = Path(grid["out"])
        out.mkdir(parents=True, exist_ok=True)
        check_finished(grid)
        write_json(out / GRID, grid)
        if not args.report_only:
            if not args.no_video and experiment.video_episode >= 0:
                from ahrm_stack.env.video import select_gl_backend
                select_gl_backend(video.gl_backends)  # inherited by the Ray workers
            started = time.perf_counter()
            from ahrm_stack.report import budget
            print(f"experiment: {len(grid['runs'])} runs ({', '.join(grid['methods'])} x "
                  f"{grid['seeds']} seeds, {budget(grid)}) -> {out}", flush=True)
            run_grid(grid, experiment, args.address)
            print(f"grid finished in {(time.perf_counter() - started) / 60:.1f} min")
        from ahrm_stack.report import write_report
        report = write_report(out, experiment)
    except (ConfigError, RenderError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"report: {report}")
    failed = [r for r in grid["runs"] if (Path(r["run_dir"]) / FAILED).is_file()]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
