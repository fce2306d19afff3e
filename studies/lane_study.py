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
import subprocess
import sys
from pathlib import Path

BEST = ["ppo.actor_init_scale=0.01", "task.rewards.avoid_margin=0.02"]  # scratch study, round 13
OWN_LANE = ["profile=scratch-own-lane", *BEST]
ARMS: dict[str, list[str]] = {
    # the baseline: world frame, any-bearing curriculum starts, lane clearances observed
    "own-lane-ahrm": [*OWN_LANE, "mechanism.method=ahrm"],
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
    args = parser.parse_args(argv)
    if args.command == "list":
        for name, overrides in ARMS.items():
            print(f"{name}: {' '.join(overrides)}")
        return 0
    command = run_command(args.arm, args.seed, args.frames, args.runs_dir, args.eval_every, args.resume)
    print(" ".join(command), flush=True)
    return subprocess.call(command)


if __name__ == "__main__":
    sys.exit(main())
