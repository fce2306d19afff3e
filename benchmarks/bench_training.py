"""Training throughput: the whole PPO loop against environment-only collection, in one run.

env only : a TorchRL ``Collector`` over the same environment with a random policy;
training   : ``Trainer.iteration`` (collection with the configured policy — ``ppo.hidden_sizes``,
             3x256 by default, 3x1000 with ``ppo.hidden_sizes=[1000,1000,1000]`` — GAE, PPO epochs).
Both in frames per second, interleaved; prints the ratio and the projected wall time of the default
300-episode run at the measured training rate for 1200-step (unsuccessful) episodes — the worst case.

Usage: python benchmarks/bench_training.py [--batches N] [--quick] [key=value overrides]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import torch  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.env.torchrl_env import PushOffEnv  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402


QUICK_OVERRIDES = ("ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "ppo.epochs=1",
                   "train.demo_episodes=1", "train.bc_epochs=1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("overrides", nargs="*")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 batch of 64 frames, 1 demonstration): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.batches = 1
        args.overrides = [*args.overrides, *QUICK_OVERRIDES]
    config = load_config(args.overrides)
    torch.set_num_threads(config.train.threads)
    trainer = Trainer(config)
    env = PushOffEnv(config.task, config.safety, seed=1)
    frames = config.ppo.frames_per_batch
    collector = Collector(env, None, frames_per_batch=frames, total_frames=-1)
    batches = iter(collector)
    next(batches)
    trainer.iteration()  # warm-up of both
    env_time = train_time = 0.0
    for _ in range(args.batches):
        t0 = time.perf_counter()
        next(batches)
        env_time += time.perf_counter() - t0
        t0 = time.perf_counter()
        trainer.iteration()
        train_time += time.perf_counter() - t0
    collector.shutdown()
    trainer.close()
    n = frames * args.batches
    env_rate, train_rate = n / env_time, n / train_time
    worst = config.train.episodes * config.task.max_steps / train_rate / 60
    print(f"network {list(config.ppo.hidden_sizes)}, {config.train.threads} thread(s), "
          f"{frames} frames/batch, {config.ppo.epochs} epochs")
    print(f"env only (random policy) : {env_rate:7.0f} frames/s")
    print(f"training loop            : {train_rate:7.0f} frames/s")
    print(f"ratio training/env       : {train_rate / env_rate:.3f}   (goal >= 0.5)")
    print(f"{config.train.episodes} episodes of {config.task.max_steps} steps at that rate: "
          f"{worst:.0f} min (worst case: no episode ends early; goal <= 20 min)")


if __name__ == "__main__":
    main()
