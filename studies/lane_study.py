"""Does a from-scratch policy choose its own lane? (issue 42, item 3; docs/lane-study.md)

    python studies/lane_study.py list
    python studies/lane_study.py run ARM --seed 0 [--frames 2000000] [--eval-every 200000]
                                 [--runs-dir /work/study-lane]
    python studies/lane_study.py run ARM --seed 0 --resume        # continue an interrupted run
    python studies/lane_study.py lanes RUN [--episodes 100]       # lane agreement of each policy
    python studies/lane_study.py summarise RUNS_DIR [--out docs/lane-study]

An arm is a list of config overrides on top of ``configs/``. The planner-free arms start from
``profile=scratch-own-lane`` (no ``lane_choice`` observation, no lane frame keyed on the planner,
near-cube curriculum starts at any bearing); ``assisted-*`` is the planner-assisted reference
(``profile=scratch``). Every arm adds the scratch study's best settings (round 13: the centred
initial actor, ``ppo.actor_init_scale=0.01``, and the 2 cm avoid margin), so that arms differ
only in what they name.

``run`` trains one arm and seed into ``RUNS_DIR/ARM-seedN`` (interim evaluations on the run's own
validation seeds, as every training does). ``lanes`` evaluates every interim policy of a run
(``policies/episode-*.pt``) and its final ``policy.pt`` when there is one on ``--episodes``
validation episodes of the run's own layouts (``python -m ahrm_stack.evaluate``, which reports the
lane agreement) into ``RUN/lanes/<policy>/``. ``summarise`` reads those folders and the runs'
CSV files (nothing typed by hand) and writes ``table.md`` (per run and evaluated policy: frames,
successes, touching, the lane the cube left by against the planner's plan, touching after a wrong
lane) to ``--out``. Validation seeds only: nothing here reads the test split.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import json
import shutil
import subprocess
import sys
from pathlib import Path

from ahrm_stack.log_copies import gzip_copy

BEST = ["ppo.actor_init_scale=0.01", "task.rewards.avoid_margin=0.02"]  # scratch study, round 13
OWN_LANE = ["profile=scratch-own-lane", *BEST]
ARMS: dict[str, list[str]] = {
    # the baseline: world frame, any-bearing curriculum starts, lane clearances observed
    "own-lane-ahrm": [*OWN_LANE, "mechanism.method=ahrm"],
    # + a symmetry keyed on the cube's own side of the table (not on the planner): the policy sees
    # every episode with its cube at x >= 0 (ppo.lane_frame: cube_side_no_joints)
    "own-lane-cubeside-ahrm": [*OWN_LANE, "ppo.lane_frame=cube_side_no_joints", "mechanism.method=ahrm"],
    # the same with the linear sum (does the hierarchy matter for the lane choice?)
    "own-lane-ls": [*OWN_LANE, "mechanism.method=ls"],
    # the planner-assisted reference (profile=scratch: lane_choice observed, lane frame, behind starts)
    "assisted-ahrm": ["profile=scratch", *BEST, "mechanism.method=ahrm"],
}
DEFAULT_RUNS = Path("/work/study-lane")


def run_command(arm: str, seed: int, frames: int, runs_dir: Path, eval_every: int, resume: bool) -> list[str]:
    """The training command of ``arm``'s run with ``seed`` (``resume``: continue its folder)."""
    run_dir = runs_dir / f"{arm}-seed{seed}"
    if resume:
        return [sys.executable, "-m", "ahrm_stack.train", "--resume", str(run_dir), "--no-progress"]
    return [sys.executable, "-m", "ahrm_stack.train", *ARMS[arm], f"train.seed={seed}",
            f"train.frames={frames}", f"train.eval_every_frames={eval_every}",
            "--run-dir", str(run_dir), "--no-progress"]


def _frames_by_policy(run_dir: Path) -> dict[str, int]:
    """Frames collected when each policy of a run was saved: ``episode-N`` from the interim
    evaluations (``evaluations.csv``: episode, frames), ``policy`` (the final one) from the last
    batch."""
    frames: dict[str, int] = {}
    with open(run_dir / "evaluations.csv") as handle:
        for row in csv.DictReader(handle):
            frames[f"episode-{int(row['episode']):05d}"] = int(row["frames"])
    if (run_dir / "batches.csv").is_file():  # the final policy: after the last batch
        with open(run_dir / "batches.csv") as handle:
            rows = list(csv.DictReader(handle))
        frames["policy"] = int(rows[-1]["frames"]) if rows else 0
    return frames


def lanes(run_dir: Path, episodes: int) -> list[Path]:
    """Evaluate every saved policy of ``run_dir`` (and the scripted controller once) on
    ``episodes`` validation episodes of the run's own layouts, with the lane agreement, into
    ``RUN/lanes/<policy>/``; a policy already evaluated on as many episodes is skipped. Returns
    the folders written."""
    from ahrm_stack.evaluation import evaluate

    written = []
    policies = [*sorted((run_dir / "policies").glob("episode-*.pt")), run_dir / "policy.pt"]
    for policy in [None, *(p for p in policies if p.is_file())]:
        out = run_dir / "lanes" / ("scripted" if policy is None else policy.stem)
        done = out / "evaluation.json"
        if done.is_file() and json.loads(done.read_text())["episodes"] == episodes:
            continue
        evaluate(run_dir, episodes, out=out, quiet=True, scripted=policy is None, policy_file=policy,
                 split="validation")
        written.append(out)
        print(f"written: {out}", flush=True)
    return written


def _run_dirs(paths: list[Path]) -> list[Path]:
    """Run folders (holding ``config.yaml``) among ``paths`` and their sub-folders."""
    found = []
    for path in paths:
        if (path / "config.yaml").is_file():
            found.append(path)
        elif path.is_dir():
            found += sorted(p for p in path.iterdir() if (p / "config.yaml").is_file())
    return found


DATA_FILES = ("config.yaml", "evaluations.csv", "batches.csv")
GZIPPED = ("episodes.csv", "events.jsonl")  # large: copied gzipped


def collect(runs: list[Path], out: Path) -> list[Path]:
    """Copy each run's data files (and its ``lanes/*/evaluation.{json,csv}``) to ``OUT/runs/<run>/``
    (``episodes.csv`` and ``events.jsonl`` gzipped); returns the copies' run folders. The table is
    built from them."""
    copies = []
    for run_dir in runs:
        target = out / "runs" / run_dir.name
        target.mkdir(parents=True, exist_ok=True)
        for name in (*DATA_FILES, *(f"{n}.gz" for n in GZIPPED)):
            if (run_dir / name).is_file():
                shutil.copyfile(run_dir / name, target / name)
        for name in GZIPPED:
            if (run_dir / name).is_file():
                gzip_copy(run_dir / name, target / f"{name}.gz")
        for evaluation in sorted((run_dir / "lanes").glob("*/evaluation.json")):
            folder = target / "lanes" / evaluation.parent.name
            folder.mkdir(parents=True, exist_ok=True)
            for name in ("evaluation.json", "evaluation.csv"):
                shutil.copyfile(evaluation.parent / name, folder / name)
        copies.append(target)
    return copies


def _training_success(run_dir: Path, frames: int, window: int = 200) -> str:
    """Success share of the last ``window`` training episodes that ended by ``frames``."""
    path = run_dir / "episodes.csv.gz"
    if not path.is_file():
        return "–"
    with gzip.open(path, "rt") as handle:
        rows = [row for row in csv.DictReader(handle) if int(row.get("frames") or 0) <= frames]
    last = rows[-window:]
    return f"{sum(row['success'] == 'True' for row in last) / len(last):.2f}" if last else "–"


def table(copies: list[Path]) -> str:
    """``table.md`` from the collected copies: per run the interim evaluations (40 validation
    episodes) and the lane evaluations, each row with its frames."""
    lines = ["Generated by `python studies/lane_study.py summarise` from the run data in `runs/` "
             "(validation split only). Planner-free arms: `own-lane-*` (profile=scratch-own-lane); "
             "planner-assisted: `assisted-*` (profile=scratch).", "",
             "## Interim evaluations (the run's own layouts, 40 validation episodes, 60 s)", "",
             "| run | frames | successes | touching | training success (last 200 episodes) |", "|---|---|---|---|---|"]
    for run_dir in copies:
        with open(run_dir / "evaluations.csv") as handle:
            for row in csv.DictReader(handle):
                lines.append(f"| {run_dir.name} | {int(row['frames']):,} | {row['successes']}/{row['episodes']} | "
                             f"{row['touched_episodes']} | {_training_success(run_dir, int(row['frames']))} |")
    lines += ["", "## Lane agreement (each saved policy on the same validation episodes; the scripted "
              "controller's row on them too)", "",
              "| run | policy | frames | successes | touching | pushed | left by the planned lane | "
              "touching after the planned lane | touching after a wrong lane |",
              "|---|---|---|---|---|---|---|---|---|"]
    for run_dir in copies:
        frames = _frames_by_policy(run_dir) if (run_dir / "evaluations.csv").is_file() else {}
        results = []
        for path in (run_dir / "lanes").glob("*/evaluation.json"):
            name = path.parent.name
            results.append((-1 if name == "scripted" else frames.get(name, -2), name, json.loads(path.read_text())))
        for at, name, result in sorted(results):
            lane = result["lanes"]
            share = f"{lane['agreeing']}/{lane['pushed']} ({lane['agreement']:.0%})" if lane["pushed"] else "0/0"
            when = "–" if at < 0 else f"{at:,}"
            lines.append(f"| {run_dir.name} | {name} | {when} | {result['successes']}/{result['episodes']} | "
                         f"{result['touched_episodes']} | {lane['pushed']} | {share} | "
                         f"{lane['touched_agreeing']}/{lane['agreeing']} | {lane['touched_disagreeing']}/"
                         f"{lane['disagreeing']} |")
    return "\n".join(lines) + "\n"


def summarise(runs: list[Path], out: Path) -> Path:
    """Collect the runs' data into ``OUT/runs/`` and write ``OUT/table.md`` from the copies."""
    copies = collect(_run_dirs(runs), out)
    (out / "table.md").write_text(table(copies))
    return out / "table.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list")
    p_run = sub.add_parser("run")
    p_run.add_argument("arm", choices=sorted(ARMS))
    p_run.add_argument("--seed", type=int, default=0)
    p_run.add_argument("--frames", type=int, default=2_000_000)
    p_run.add_argument("--eval-every", type=int, default=200_000, help="frames between interim evaluations")
    p_run.add_argument("--runs-dir", type=Path, default=DEFAULT_RUNS)
    p_run.add_argument("--resume", action="store_true")
    p_lanes = sub.add_parser("lanes", help="lane agreement of every saved policy of a run")
    p_lanes.add_argument("run_dir", type=Path)
    p_lanes.add_argument("--episodes", type=int, default=100)
    p_summary = sub.add_parser("summarise", help="collect the runs' data and write table.md")
    p_summary.add_argument("runs", type=Path, nargs="+", help="run folders, or folders of them")
    p_summary.add_argument("--out", type=Path, default=Path("docs/lane-study"))
    args = parser.parse_args(argv)
    if args.command == "lanes":
        lanes(args.run_dir, args.episodes)
        return 0
    if args.command == "summarise":
        print(f"written: {summarise(args.runs, args.out)}")
        return 0
    if args.command == "list":
        for name, overrides in ARMS.items():
            print(f"{name}: {' '.join(overrides)}")
        return 0
    command = run_command(args.arm, args.seed, args.frames, args.runs_dir, args.eval_every, args.resume)
    print(" ".join(command), flush=True)
    return subprocess.call(command)


if __name__ == "__main__":
    sys.exit(main())
