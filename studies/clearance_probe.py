"""How close a policy steers the cube and the pusher to the obstacles (issue 18, round 13): near misses
next to touches.

    python studies/clearance_probe.py RUN_DIR [--policy-file policies/X.pt] [--episodes 200] [--out FILE.csv]
    python studies/clearance_probe.py RUN_DIR --scripted [--episodes 200]   # the controller, same episodes
    python studies/clearance_probe.py --pair A.csv B.csv   # two --out files of the same episodes

Replays the first N episodes of the run's own deterministic evaluation (its configuration, the
evaluation seeds: the episodes of ``python -m ahrm_stack.evaluate RUN_DIR``) with the run's policy, or
with the scripted controller (``--scripted``, as ``evaluate --policy scripted`` drives it), and measures
every step's clearance — the smallest distance of the cube and of the pusher to any obstacle
(:class:`ahrm_stack.env.clearance.Clearance`, exact within ``--reach``) — whatever the run's own
``task.rewards.avoid_margin``: the measurement sets the margin to ``--reach`` in a copy of the
configuration, which changes f1 only, and neither the policy's actions nor the physics. Prints per
margin how many episodes came that close, with successes and touching episodes; ``--out`` writes one
row per episode. Nothing else is written. ``--pair`` compares two such files episode by episode: per
margin the episodes that came that close in each, the discordant ones (only A / only B) and the
exact sign test of them.
"""

from __future__ import annotations

import argparse
import csv
import functools
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np

from ahrm_stack.env.episode_loop import episode, scripted_episode
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, load_policy, policy_act
from ahrm_stack.run_config import load_run_config

MARGINS = (0.005, 0.01, 0.02, 0.03)  # m, the near-miss thresholds reported


def probe(run_dir: Path, episodes: int, policy_file: Path | None, scripted: bool, reach: float) -> list[dict]:
    """One row per episode: success, touched steps, the smallest cube and pusher clearance (m)."""
    config = load_run_config(run_dir, [f"task.rewards.avoid_margin={reach!r}"])
    policy = None if scripted else load_policy(run_dir, policy_file)[1]
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=VALIDATION_SEED_OFFSET, safety=config.safety)
    controller = ScriptedPusher(task, config.scripted) if scripted else None
    rows = []
    for i in range(episodes):
        seed = VALIDATION_SEED_OFFSET + i
        steps = (scripted_episode(runner, controller, seed) if controller is not None
                 else episode(runner, seed, policy_act(runner, policy)))
        cube_min = pusher_min = math.inf
        touched = 0
        for step in steps:
            if step.sent is None:
                continue
            info = step.info
            touched += int(info.touched)
            cube_min, pusher_min = min(cube_min, info.cube_clearance), min(pusher_min, info.pusher_clearance)
        rows.append({"episode": i, "success": int(info.success), "touched_steps": touched,
                     "cube_clearance": cube_min, "pusher_clearance": pusher_min})
    return rows


def summary(rows: list[dict]) -> list[str]:
    n = len(rows)
    nearest = np.array([min(r["cube_clearance"], r["pusher_clearance"]) for r in rows])
    lines = [f"episodes {n}: successes {sum(r['success'] for r in rows)}, touching "
             f"{sum(r['touched_steps'] > 0 for r in rows)}; nearest approach (cube or pusher) quantiles "
             f"10/25/50 %: {', '.join(f'{100 * q:.2f}' for q in np.quantile(nearest, [0.1, 0.25, 0.5]))} cm"]
    for margin in MARGINS:
        near = [r for r, d in zip(rows, nearest) if d < margin]
        cube = sum(r["cube_clearance"] < margin for r in rows)
        lines.append(f"within {100 * margin:.1f} cm: {len(near)} episodes (cube {cube}, pusher "
                     f"{sum(r['pusher_clearance'] < margin for r in rows)}), of them touching "
                     f"{sum(r['touched_steps'] > 0 for r in near)}, successes {sum(r['success'] for r in near)}")
    return lines


class PairError(ValueError):
    """Two files ``--pair`` cannot compare."""


@functools.cache
def _scratch_study():
    """studies/scratch_study.py, loaded once (its exact sign test)."""
    spec = importlib.util.spec_from_file_location("scratch_study", Path(__file__).with_name("scratch_study.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def pair(path_a: Path, path_b: Path) -> list[str]:
    """Near misses of two probes of the same episodes (``--out`` files), episode by episode."""
    nearest = []
    for path in (path_a, path_b):
        try:
            with open(path) as handle:
                rows = list(csv.DictReader(handle))
            nearest.append([min(float(r["cube_clearance"]), float(r["pusher_clearance"])) for r in rows])
        except (OSError, KeyError, ValueError) as error:
            raise PairError(f"{path}: not a clearance probe's CSV ({type(error).__name__}: {error})") from None
    a, b = nearest
    if len(a) != len(b):
        raise PairError(f"{path_a} has {len(a)} episodes, {path_b} {len(b)}: not the same episodes")
    lines = [f"{len(a)} episodes; A = {path_a}, B = {path_b}"]
    for margin in MARGINS:
        only_a = sum(x < margin <= y for x, y in zip(a, b))
        only_b = sum(y < margin <= x for x, y in zip(a, b))
        lines.append(f"within {100 * margin:.1f} cm: A {sum(x < margin for x in a)}, B {sum(y < margin for y in b)}; "
                     f"discordant {only_a} / {only_b}, sign test p = {_scratch_study().sign_test(only_a, only_b):.2g}")
    return lines


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]  # --pair before argparse: it takes no run folder
    if argv[:1] == ["--pair"]:
        try:
            if len(argv) != 3:
                raise PairError("usage: clearance_probe.py --pair A.csv B.csv")
            print("\n".join(pair(Path(argv[1]), Path(argv[2]))))
        except PairError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--policy-file", type=Path, default=None, help="relative to RUN_DIR (default: policy.pt)")
    parser.add_argument("--scripted", action="store_true", help="the scripted controller instead of the policy")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--reach", type=float, default=0.05, help="m; clearances are exact below this")
    parser.add_argument("--out", type=Path, default=None, help="per-episode CSV")
    args = parser.parse_args(argv)
    if not (args.run_dir / "config.yaml").is_file():
        parser.error(f"{args.run_dir}: no config.yaml there; is it a run folder?")
    if args.episodes < 1 or not args.reach > 0:
        parser.error(f"--episodes must be >= 1 and --reach > 0 m, got {args.episodes} and {args.reach}")
    policy_file = args.run_dir / args.policy_file if args.policy_file else None
    rows = probe(args.run_dir, args.episodes, policy_file, args.scripted, args.reach)
    print("\n".join(summary(rows)))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
