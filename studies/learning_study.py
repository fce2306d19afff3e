"""The learnability study (issue 5): named configurations, their runs, and the report.

    python studies/learning_study.py list
    python studies/learning_study.py run ROW --seed 0 [--episodes 300] [--runs-dir runs/study]
    python studies/learning_study.py report runs/study --out docs/learning-study

A row is a list of config overrides applied on top of ``configs/`` (``profile=paper`` is the
paper-faithful configuration). ``run`` trains one row and seed into ``RUNS_DIR/ROW-seedN`` with an
interim deterministic evaluation every ``--eval-every`` episodes. ``report`` reads the run folders
(nothing is typed in by hand) and writes ``table.md`` and the learning-curve PNGs.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from ahrm_stack import cli

VERTICAL = "task.arm.home_deg=[240,204.2,55.4,350.7,36.2,75]"  # the default start pose
ROWS: dict[str, list[str]] = {
    # the paper's configuration: joint actions, 3x1000, Table I hyper-parameters, no demonstrations
    "paper-ahrm": ["profile=paper", "mechanism.method=ahrm"],
    "paper-ls": ["profile=paper", "mechanism.method=ls"],
    # Cartesian actions from the vertical start pose, 3x256, from scratch
    "cartesian-scratch-ahrm": ["profile=paper", "task.action.mode=cartesian", VERTICAL,
                               "ppo.hidden_sizes=[256,256,256]", "ppo.learning_rate=3e-4",
                               "mechanism.method=ahrm"],
    # the defaults (configs/): demonstrations, BC warm start, anchored and KL-limited PPO
    "default-ahrm": ["mechanism.method=ahrm"],
    "default-ls": ["mechanism.method=ls"],
    # ablations of the defaults, one lever each
    "no-anchor-ahrm": ["mechanism.method=ahrm", "ppo.bc_coeff=0"],
    "no-demo-noise-ahrm": ["mechanism.method=ahrm", "train.demo_noise=0"],
    # the first candidate default: anchor 1, 40 noise-free demonstrations, 200 cloning epochs
    "anchor1-ahrm": ["mechanism.method=ahrm", "ppo.bc_coeff=1", "train.demo_noise=0",
                     "train.demo_episodes=40", "train.bc_epochs=200"],
    "normalized-advantage-ahrm": ["mechanism.method=ahrm", "ppo.normalize_advantage=true",
                                  "ppo.target_kl=0"],
    "no-kl-target-ahrm": ["mechanism.method=ahrm", "ppo.target_kl=0"],
    "joint-bc-ahrm": ["mechanism.method=ahrm", "task.action.mode=joint"],
    "two-envs-ahrm": ["mechanism.method=ahrm", "train.num_envs=2"],
    "wide-1000-ahrm": ["mechanism.method=ahrm", "ppo.hidden_sizes=[1000,1000,1000]"],
    "lr-1e-3-ahrm": ["mechanism.method=ahrm", "ppo.learning_rate=1e-3"],
    "entropy-0.01-ahrm": ["mechanism.method=ahrm", "ppo.entropy_coeff=0.01"],
    "batch-2048-epochs-10-ahrm": ["mechanism.method=ahrm", "ppo.frames_per_batch=2048",
                                  "ppo.epochs=10"],
    "std-scheduled-ahrm": ["mechanism.method=ahrm", "ppo.std_mode=scheduled", "ppo.init_std=0.3",
                           "ppo.final_std=0.05", "ppo.std_schedule_frames=20000"],
    "no-obs-norm-ahrm": ["mechanism.method=ahrm", "ppo.normalize_observations=false"],
}


def run(row: str, seed: int, episodes: int, runs_dir: Path, eval_every: int) -> int:
    """Train (or resume) one row's run in ``RUNS_DIR/ROW-seedN`` through the training library, then
    its final evaluation, as ``python -m ahrm_stack.train`` with the printed arguments would."""
    from ahrm_stack.learning.rollouts import evaluate_run
    from ahrm_stack.learning.training import exit_status, resolve_config, train
    if row not in ROWS:
        print(f"error: unknown row {row!r}; rows: {sorted(ROWS)}", file=sys.stderr)
        return 2
    run_dir = runs_dir / f"{row}-seed{seed}"
    resume = (run_dir / "checkpoints").is_dir()
    if resume:
        overrides = [f"train.episodes={episodes}"]
        args = ["--resume", str(run_dir), "--no-progress", *overrides]
    else:
        overrides = [*ROWS[row], f"train.seed={seed}", f"train.episodes={episodes}", f"train.eval_every={eval_every}"]
        args = [*overrides, "--run-dir", str(run_dir), "--no-progress"]
    print("python -m ahrm_stack.train " + " ".join(args))
    try:
        config, run_dir = resolve_config(overrides, run_dir, resume=run_dir if resume else None)
        run_dir = train(config, run_dir, resume=resume, progress=False, rewrite_config=resume)
    except Exception as error:
        return exit_status(error)
    print(f"run folder: {run_dir}")
    if config.train.eval_episodes:
        print(evaluate_run(run_dir, config.train.eval_episodes))
    return 0


# ---------------------------------------------------------------------------------------------- report
def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def summarize(run_dir: Path) -> dict:
    """One run folder's figures: training successes, first success, touches, wall time, evaluations."""
    episodes = _rows(run_dir / "episodes.csv")
    batches = _rows(run_dir / "batches.csv")
    evaluations = _rows(run_dir / "evaluations.csv")
    if not evaluations:  # the final evaluation only: train's, or the experiment grid's
        import yaml
        for final_path in (run_dir / "evaluation.yaml", run_dir / "eval" / "evaluation.json"):
            if final_path.is_file():
                final = yaml.safe_load(final_path.read_text())
                evaluations = [{**final, "episode": len(episodes)}]
                break
    success = [row["success"] == "True" for row in episodes]
    first = next((i + 1 for i, ok in enumerate(success) if ok), None)
    evals = {int(row["episode"]): (int(row["successes"]), int(row["episodes"]),
                                   int(row["touched_episodes"]), float(row["time_mean"]))
             for row in evaluations}

    def eval_at(target: int):
        """The first interim evaluation at or after ``target`` episodes (the batch that crossed it)."""
        later = [e for e in evals if e >= target]
        return evals[min(later)] if later else None

    return {
        "run": run_dir.name,
        "episodes": len(episodes),
        "train_successes": sum(success),
        "first_success": first,
        "touching_episodes": sum(int(row["touched_steps"]) > 0 for row in episodes),
        "constraint_terminations": sum(row["constraint_terminated"] == "True" for row in episodes),
        "ppo_minutes": sum(float(row["seconds"]) for row in batches) / 60,
        # wall clock: the run folder's config (written at start) to its last episode row
        "wall_minutes": ((run_dir / "episodes.csv").stat().st_mtime
                         - (run_dir / "config.yaml").stat().st_mtime) / 60,
        "eval_0": evals.get(0),
        "eval_300": eval_at(300),
        "eval_600": eval_at(600),
        "success": success,
        "evals": sorted(evals.items()),
    }


def _fmt_eval(value) -> str:
    if value is None:
        return "–"
    successes, n, touched, time_mean = value
    time = f", {time_mean:.2f} s" if successes else ""
    return f"{successes}/{n} ({touched} touching{time})"


def report(runs_dir: Path, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    groups: dict[str, list[dict]] = defaultdict(list)
    for run_dir in sorted(p for p in runs_dir.iterdir() if (p / "episodes.csv").is_file()):
        row = run_dir.name.rsplit("-seed", 1)[0]
        groups[row].append(summarize(run_dir))
    lines = ["Seeds: the validation split of configs/seeds.yaml (studies never read the sealed split).", "",
             "| row | seed | episodes | training successes | first success (episode) | "
             "touching episodes | deterministic eval before PPO | at 300 | at 600 | "
             "wall minutes (collection + updates) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row, runs in groups.items():
        for summary in runs:
            lines.append(
                f"| {row} | {summary['run'].rsplit('-seed', 1)[1]} | {summary['episodes']} | "
                f"{summary['train_successes']} | {summary['first_success'] or 'never'} | "
                f"{summary['touching_episodes']} | {_fmt_eval(summary['eval_0'])} | "
                f"{_fmt_eval(summary['eval_300'])} | {_fmt_eval(summary['eval_600'])} | "
                f"{summary['wall_minutes']:.1f} ({summary['ppo_minutes']:.1f}) |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    (out / "summary.json").write_text(json.dumps(
        {row: [{k: v for k, v in s.items() if k != "success"} for s in runs]
         for row, runs in groups.items()}, indent=1))

    _plot_curves(plt, {row: runs for row, runs in groups.items() if row in KEY_ROWS},
                 out / "learning-curves.png")
    _plot_curves(plt, groups, out / "learning-curves-all.png")
    print((out / "table.md").read_text())


KEY_ROWS = ("default-ahrm", "default-ls", "anchor1-ahrm", "no-anchor-ahrm", "no-demo-noise-ahrm",
            "paper-ahrm")  # the rows the study's findings rest on


def _plot_curves(plt, groups: dict[str, list[dict]], path: Path) -> None:
    """Training success (rolling 20) and deterministic evaluations per row, seeds in one colour."""
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(10, 8), sharex=True)
    colours = plt.get_cmap("tab20").colors
    for i, (row, runs) in enumerate(groups.items()):
        colour = colours[(2 * i) % 20 if i < 10 else (2 * i + 1) % 20]
        for j, summary in enumerate(runs):
            success = np.asarray(summary["success"], dtype=float)
            if len(success) == 0:
                continue
            window = min(20, len(success))
            rolling = np.convolve(success, np.ones(window) / window, mode="valid")
            top.plot(np.arange(window, len(success) + 1), rolling, color=colour,
                     alpha=0.9 - 0.3 * j, label=row if j == 0 else None)
            if summary["evals"]:
                x, values = zip(*summary["evals"])
                bottom.plot(x, [v[0] / v[1] for v in values], "o-", color=colour,
                            alpha=0.9 - 0.3 * j, label=row if j == 0 else None)
    top.set_ylabel("training success (rolling 20 episodes)")
    bottom.set_ylabel("deterministic evaluation success")
    bottom.set_xlabel("training episode")
    for axis in (top, bottom):
        axis.set_ylim(-0.05, 1.05)
        axis.axhline(0.9, color="grey", lw=0.8, ls="--")
        axis.grid(alpha=0.3)
    top.legend(fontsize=8, loc="lower right")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cli.add_verbose_flag(parser)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list")
    run_parser = sub.add_parser("run")
    run_parser.add_argument("row")
    run_parser.add_argument("--seed", type=int, default=0)
    run_parser.add_argument("--episodes", type=int, default=300)
    run_parser.add_argument("--eval-every", type=int, default=50)
    run_parser.add_argument("--runs-dir", type=Path, default=Path("runs/study"))
    report_parser = sub.add_parser("report")
    report_parser.add_argument("runs_dir", type=Path)
    report_parser.add_argument("--out", type=Path, default=Path("docs/learning-study"))
    args = parser.parse_args(argv)
    cli.quiet(args.verbose)
    if args.command == "list":
        for name, overrides in ROWS.items():
            print(f"{name}: {' '.join(overrides)}")
        return 0
    if args.command == "run":
        return run(args.row, args.seed, args.episodes, args.runs_dir, args.eval_every)
    report(args.runs_dir, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
