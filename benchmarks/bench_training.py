"""Training throughput: the whole PPO loop against env-only collection of the same environments.

For each setting (by default two: one environment in the trainer's process, ``train.num_envs=1``;
and two environments in two worker processes, ``train.num_envs=2 train.env_workers=2``):

env only : the trainer's ``LeanCollector`` over the environments a second ``Trainer`` builds from the
           same config (other seeds): the training time limit (``train.time_limit``), the start
           curriculum's first level and the touch ending, in its process or an ``EnvPool`` of worker
           processes (:mod:`ahrm_stack.learning.pool`); the actions tanh(N(0, ``ppo.init_std``)), the
           initial policy's noise, with no network. Before 2026-12-04 these environments had the task's
           60 s episodes and its default starts with uniform random actions (so no resets and mostly
           phase 1 in a 2048-frame batch), and before 2026-12-03 a TorchRL ``Collector``;
training : ``Trainer.iteration`` (collection with the configured policy through its lean collection
           path — ``ppo.hidden_sizes``, 3x256 by default — GAE, PPO epochs with the BC anchor).

Both in frames per second, batches interleaved; prints per setting the ratio training/env (goal
>= 0.8), the absolute training rate (aim >= 1000 frames/s) and the projected wall time of the
300-episode run for 1200-step (unsuccessful) episodes — the worst case.

Usage: python benchmarks/bench_training.py [--batches N] [--settings S ...] [--quick] [key=value ...]
       a setting is a comma-separated override list, e.g. --settings "" "train.num_envs=2,train.env_workers=2";
       overrides for every setting go before --settings (after it they are read as settings), e.g.
       python benchmarks/bench_training.py profile=scratch --settings "" "task.episode.noslip_iterations=0"
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import torch  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.learning.collection import LeanCollector, RandomActor  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402

QUICK_OVERRIDES = ("ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "ppo.epochs=1",
                   "train.demo_episodes=1", "train.bc_epochs=1")
SETTINGS = ("", "train.num_envs=2,train.env_workers=2")
GOAL_RATIO, AIM_RATE = 0.8, 1000.0


def env_only(config) -> tuple[LeanCollector, Trainer]:
    """A random policy's collector over the environments a second trainer builds from ``config``
    (seed ``train.seed + 1``): the training time limit, the start curriculum at its first level and
    the touch ending, in the process or in an ``EnvPool`` of workers; actions ``tanh(N(0, init_std))``,
    the initial policy's noise. Returns the collector and that trainer (to close)."""
    source = Trainer(dataclasses.replace(config, train=dataclasses.replace(config.train, seed=config.train.seed + 1)),
                     collect_demos=False)
    source._set_touch_end()
    stepper = source.env if source.workers else source.envs
    action_dim = source.env.action_spec.shape[-1]
    actor = RandomActor(action_dim, std=config.ppo.init_std)
    return LeanCollector(stepper, actor, config.ppo.frames_per_batch), source


def measure(overrides: list[str], batches: int) -> dict:
    config = load_config(overrides)
    torch.set_num_threads(config.train.threads)
    trainer = Trainer(config)
    frames = config.ppo.frames_per_batch
    collector, source = env_only(config)
    collector.next()
    trainer.iteration()  # warm-up of both
    env_time = train_time = 0.0
    for _ in range(batches):
        t0 = time.perf_counter()
        collector.next()
        env_time += time.perf_counter() - t0
        t0 = time.perf_counter()
        trainer.iteration()
        train_time += time.perf_counter() - t0
    source.close()
    trainer.close()
    n = frames * batches
    return dict(config=config, env=n / env_time, train=n / train_time)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS),
                        help="comma-separated override lists, one per setting ('' = the config)")
    parser.add_argument("overrides", nargs="*", help="overrides for every setting")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 batch of 64 frames, 1 demonstration): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.batches = 1
        args.overrides = [*args.overrides, *QUICK_OVERRIDES]
    for setting in args.settings:
        extra = [o for o in setting.split(",") if o]
        result = measure([*args.overrides, *extra], args.batches)
        config, env_rate, train_rate = result["config"], result["env"], result["train"]
        ratio = train_rate / env_rate
        worst = config.train.episodes * config.task.max_steps / train_rate / 60
        print(f"setting: num_envs={config.train.num_envs} env_workers={config.train.env_workers} "
              f"({' '.join(extra) or 'the config'}); network {list(config.ppo.hidden_sizes)}, "
              f"{config.train.threads} thread(s), {config.ppo.frames_per_batch} frames/batch, "
              f"{config.ppo.epochs} epochs, {args.batches} batches")
        print(f"  env only (noise policy)  : {env_rate:7.0f} frames/s")
        print(f"  training loop            : {train_rate:7.0f} frames/s   (aim >= {AIM_RATE:.0f}: "
              f"{'met' if train_rate >= AIM_RATE else 'NOT met'})")
        print(f"  ratio training/env       : {ratio:.3f}   (goal >= {GOAL_RATIO}: "
              f"{'met' if ratio >= GOAL_RATIO else 'NOT met'})")
        print(f"  {config.train.episodes} episodes of {config.task.max_steps} steps at that rate: "
              f"{worst:.0f} min (worst case: no episode ends early)")


if __name__ == "__main__":
    main()
