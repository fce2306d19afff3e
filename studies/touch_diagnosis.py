"""Why a policy touched obstacles on the suite (issue 14): replay each touching episode and name the
first touch and the lane.

    python studies/touch_diagnosis.py RUN_DIR [--policy-file policies/clone.pt] [--suite RUN_DIR/suite]
    python studies/touch_diagnosis.py RUN_DIR --own 40   # the run's own evaluation episodes

For every family folder of a suite evaluation (``python -m ahrm_stack.evaluate RUN_DIR --suite``),
the episodes whose ``touched_steps`` > 0 are replayed with the same seeds and the run's
deterministic policy. At the first touching step it prints what is in contact with an obstacle
(``cube``, ``pusher``, ``arm`` or ``none``: the obstacle only moving), how far the cube has moved,
the lane the policy is pushing along (the sign of the cube's x displacement) and the lane the
scripted controller plans for that episode (:func:`ahrm_stack.env.layout.choose_lane`). It ends
with the counts. ``--own N`` replays instead the first N episodes of the run's own deterministic
evaluation (its distribution, the evaluation seeds) and names the first touch of those that touch.
Replays only; nothing is written.
"""

from __future__ import annotations

import argparse
import csv
from collections import Counter
from pathlib import Path
from typing import Iterator

import numpy as np

from ahrm_stack.env.episode_loop import Step, episode
from ahrm_stack.env.layout_catalog import run_config_in_layout
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, load_policy, policy_act
from ahrm_stack.run_config import load_run_config


def _first_touch(runner: TaskRunner, steps: Iterator[Step], task: PushOffTask) -> dict | None:
    """Run the episode ``steps`` (of a policy on ``runner``) until its first touching step (None:
    none)."""
    physics = runner.physics
    obstacles = {int(physics.bind(o.geom).element_id) for o in task.obstacles}
    cube = int(physics.bind(task.cube.geom).element_id)
    pusher = {int(g) for g in physics.bind(task.pusher.mjcf_model.find_all("geom")).element_id}
    table = {int(g) for g in physics.bind(task.root_entity.mjcf_model.find_all("geom")).element_id}
    cube_body = int(physics.bind(task.cube.geom).bodyid)
    next(steps)  # the reset
    start = physics.data.xpos[cube_body, :2].copy()
    for step in steps:
        info = step.info
        if info.touched:
            kinds = set()
            for contact in physics.data.contact[:physics.data.ncon]:
                pair = {int(contact.geom1), int(contact.geom2)}
                if not pair & obstacles:
                    continue
                other = pair - obstacles
                if not other:
                    kinds.add("obstacle")
                    continue
                geom = other.pop()
                if geom == cube:
                    kinds.add("cube")
                elif geom in pusher:
                    kinds.add("pusher")
                elif geom not in table:
                    kinds.add("arm")
            moved = physics.data.xpos[cube_body, :2] - start
            return {"kinds": ",".join(sorted(kinds)) or "none", "moved": moved,
                    "lane": "+x" if moved[0] > 0 else "-x", "time": info.elapsed}
    return None


def _replay(name: str, config, offset: int, episodes, policy, counts: Counter, lanes: Counter,
            quiet_clean: bool = False) -> None:
    """Replay ``episodes`` (indices from ``offset``) and count each one's first touch."""
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=offset, safety=config.safety)
    planner = ScriptedPusher(task, config.scripted)
    for i in episodes:
        steps = episode(runner, offset + i, policy_act(runner, policy), planner.reset)
        touch = _first_touch(runner, steps, task)
        if touch is None:
            if not quiet_clean:
                print(f"{name} episode {i}: no touch on replay")
            continue
        counts[touch["kinds"]] += 1
        lanes["same lane" if touch["lane"] == planner.lane else "other lane"] += 1
        print(f"{name} episode {i}: t={touch['time']:.2f} s, touch {touch['kinds']}, "
              f"cube moved {np.round(touch['moved'], 3).tolist()} m, policy's lane "
              f"{touch['lane']}, planned {planner.lane}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--policy-file", type=Path, default=None,
                        help="relative to RUN_DIR (default: policy.pt)")
    parser.add_argument("--suite", type=Path, default=None, help="default: RUN_DIR/suite")
    parser.add_argument("--own", type=int, default=0, metavar="N",
                        help="replay the run's own first N evaluation episodes instead of a suite")
    args = parser.parse_args(argv)
    run = args.run_dir
    policy_file = run / args.policy_file if args.policy_file else None
    suite = args.suite or run / "suite"
    _, policy = load_policy(run, policy_file)
    counts: Counter = Counter()
    lanes: Counter = Counter()
    if args.own:
        _replay("own", load_run_config(run), VALIDATION_SEED_OFFSET, range(args.own), policy, counts, lanes,
                quiet_clean=True)
    else:
        for family_dir in sorted(p for p in suite.iterdir() if p.is_dir()):
            with open(family_dir / "evaluation.csv") as handle:
                rows = list(csv.DictReader(handle))
            touching = [i for i, row in enumerate(rows) if int(row["touched_steps"]) > 0]
            if not touching:
                continue
            config, entry = run_config_in_layout(run, family_dir.name)
            _replay(family_dir.name, config, entry.seed_offset, touching, policy, counts, lanes)
    print(f"first touches: {dict(counts)}; lanes: {dict(lanes)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
