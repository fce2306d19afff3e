"""Run the scripted mink pusher on seeded episodes and report each one.

Usage::

    python -m ahrm_stack.demo [--episodes N] [--layout fixed|random] [--seed S] [key=value ...]

Without ``--layout`` it runs both the fixed (jittered) and the randomised layouts. Episode ``i`` of
a layout uses seed ``S + i``. Trailing ``key=value`` arguments override ``configs/*.yaml``, e.g.
``scripted.push_speed=0.3``; ``--layout`` wins over a ``task.layout.mode`` override.

One line per episode: seed, success, the phases visited (e.g. ``1→2→3``), time to success (s),
the number of steps in which an obstacle was touched, and the controller's stages. Then a summary
per layout: successes, successes without touching, mean ± std time to success, wall time.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Sequence

import numpy as np

from ahrm_stack.cli import Parser, add_verbose_flag, quiet
from ahrm_stack.config import Config, ConfigError, load_config

LAYOUTS = ("fixed", "random")


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = Parser(prog="python -m ahrm_stack.demo",
                     description="Run the scripted mink pusher on seeded episodes.")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per layout (default 20)")
    parser.add_argument("--layout", choices=LAYOUTS, help="one layout mode (default: both)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides, e.g. scripted.push_speed=0.3")
    add_verbose_flag(parser)
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if not 0 <= args.seed <= 2**32 - 1 - args.episodes:
        parser.error(f"--seed must be in [0, 2**32 - 1 - episodes], got {args.seed}")
    return args


def _chain(items: list) -> str:
    """``[a, a, b, a]`` -> ``"a→b→a"`` (consecutive repeats collapsed)."""
    kept = [x for i, x in enumerate(items) if i == 0 or x != items[i - 1]]
    return "→".join(str(x) for x in kept)


def run_layout(config: Config, episodes: int, seed: int) -> dict:
    """Run ``episodes`` seeded episodes of ``config``; print a line each and a summary.

    Returns the counts and times (s) of the summary.
    """
    from ahrm_stack.env.episode_loop import scripted_episode  # heavy imports only once the CLI is valid
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask

    mode = config.task.layout.mode
    start = time.perf_counter()
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=seed, safety=config.safety)
    pusher = ScriptedPusher(task, config.scripted)
    print(f"== {mode} layout: {episodes} episodes, seeds {seed}..{seed + episodes - 1}")
    successes, clean, times = 0, 0, []
    for episode_seed in range(seed, seed + episodes):
        phases, stages, touches = [], [], 0
        for step in scripted_episode(runner, pusher, episode_seed):
            info, terminated = step.info, step.terminated
            phases.append(info.phase)
            stages.append(pusher.stage)
            touches += int(step.sent is not None and info.touched)
        successes += int(terminated)
        clean += int(terminated and touches == 0)
        if terminated:
            times.append(info.elapsed)
        when = f"{info.elapsed:5.2f} s" if terminated else "    - "
        print(f"seed {episode_seed:4d}  success {str(terminated):5s}  phases {_chain(phases):11s}  "
              f"time {when}  touching steps {touches:3d}  filter interventions "
              f"{runner.safety_stats.interventions:3d}  lane {pusher.lane}  "
              f"stages {_chain(stages)}")
    wall = time.perf_counter() - start
    mean = f"{np.mean(times):.2f} ± {np.std(times):.2f} s" if times else "-"
    print(f"-- {mode}: {successes}/{episodes} succeeded, {clean}/{episodes} without touching, "
          f"time to success {mean}, wall {wall:.1f} s")
    return {"episodes": episodes, "successes": successes, "clean": clean, "times": times,
            "wall": wall}


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    quiet(args.verbose)
    start = time.perf_counter()
    try:  # every config is checked before any simulator is built
        configs = [load_config([*args.overrides, f"task.layout.mode={mode}"])
                   for mode in ([args.layout] if args.layout else LAYOUTS)]
        for config in configs:
            run_layout(config, args.episodes, args.seed)
    except ConfigError as exc:  # includes a layout the sampler cannot satisfy
        print(f"python -m ahrm_stack.demo: error: {exc}", file=sys.stderr)
        return 2
    print(f"total wall time {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
