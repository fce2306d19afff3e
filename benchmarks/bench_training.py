"""Training throughput: the whole PPO loop against env-only collection of the same environments.

For each setting (by default two: one environment in the trainer's process, ``train.num_envs=1``;
and two environments in two worker processes, ``train.num_envs=2 train.env_workers=2``):

env only : the trainer's ``LeanCollector`` with a random policy over the same environments, built
           the way the trainer builds them (in its process, or an ``EnvPool`` of worker processes,
           :mod:`ahrm_stack.learning.pool`); before 2026-12-03 a TorchRL ``Collector`` (a SerialEnv or
           a ParallelEnv), which made env-only slower and the ratio easier;
training : ``Trainer.iteration`` (collection with the configured policy through its lean collection
           path — ``ppo.hidden_sizes``, 3x256 by default — GAE, PPO epochs with the BC anchor).

Both in frames per second, batches interleaved; prints per setting the ratio training/env (goal
>= 0.8), the absolute training rate (aim >= 1000 frames/s) and the projected wall time of the
300-episode run for 1200-step (unsuccessful) episodes — the worst case.

Usage: python benchmarks/bench_training.py [--batches N] [--settings S ...] [--quick] [key=value ...]
       a setting is a comma-separated override list, e.g. --settings "" "train.num_envs=2,train.env_workers=2"
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import torch  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.env.torchrl_env import PushOffEnv  # noqa: E402
from ahrm_stack.learning.collection import LeanCollector, RandomActor  # noqa: E402
from ahrm_stack.learning.mechanisms import RewardMechanism  # noqa: E402
from ahrm_stack.learning.pool import EnvPool  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402
from ahrm_stack.seeds import training_seeds  # noqa: E402

QUICK_OVERRIDES = ("ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "ppo.epochs=1",
                   "train.demo_episodes=1", "train.bc_epochs=1")
SETTINGS = ("", "train.num_envs=2,train.env_workers=2")
GOAL_RATIO, AIM_RATE = 0.8, 1000.0


def env_only(config) -> tuple[LeanCollector, EnvPool | None]:
    """A random policy's collector over the environments of ``config``, built as the trainer builds
    them (other seeds); and the pool to close, if any."""
    seeds = training_seeds(config.train.seed + 1, config.train.num_envs)
    if config.train.env_workers > 1:
        pool = EnvPool(config, seeds)
        stepper: EnvPool | list[PushOffEnv] = pool
        action_dim = pool.action_spec.shape[-1]
    else:
        pool = None
        mechanism = RewardMechanism(config.mechanism)  # the reward as in training
        stepper = [PushOffEnv(config.task, config.safety, seed=seed, mechanism=mechanism) for seed in seeds]
        action_dim = stepper[0].action_spec.shape[-1]
    return LeanCollector(stepper, RandomActor(action_dim), config.ppo.frames_per_batch), pool


def measure(overrides: list[str], batches: int) -> dict:
    config = load_config(overrides)
    torch.set_num_threads(config.train.threads)
    trainer = Trainer(config)
    frames = config.ppo.frames_per_batch
    collector, pool = env_only(config)
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
    if pool is not None:
        pool.close()
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
        print(f"  env only (random policy) : {env_rate:7.0f} frames/s")
        print(f"  training loop            : {train_rate:7.0f} frames/s   (aim >= {AIM_RATE:.0f}: "
              f"{'met' if train_rate >= AIM_RATE else 'NOT met'})")
        print(f"  ratio training/env       : {ratio:.3f}   (goal >= {GOAL_RATIO}: "
              f"{'met' if ratio >= GOAL_RATIO else 'NOT met'})")
        print(f"  {config.train.episodes} episodes of {config.task.max_steps} steps at that rate: "
              f"{worst:.0f} min (worst case: no episode ends early)")


if __name__ == "__main__":
    main()
