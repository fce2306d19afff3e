"""Bare physics step vs the full task step, timed in one run on the same composer model.

bare: ``physics.step(substeps)`` only (25 MuJoCo steps of 2 ms = one 0.05 s control step).
full: the task's control step — actuation, the same physics, Pinocchio FK of the pusher, phase and
boundary distance (FCL / closed form), contacts, reward components, success — plus the flat
observation. Also shown: the TorchRL ``EnvBase.step`` (tensors, specs) for reference.

The two are interleaved in blocks so that machine noise hits both alike; the ratio is the figure.
Usage: python benchmarks/bench_env_step.py [--steps N] [--blocks B]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402
from ahrm_stack.env.torchrl_env import PushOffEnv  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="control steps per block")
    parser.add_argument("--blocks", type=int, default=10)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_config()
    runner = TaskRunner(PushOffTask(cfg.task), seed=0)
    runner.reset()
    substeps = cfg.task.substeps
    rng = np.random.default_rng(0)
    limits = runner.task.robot.velocity_limit
    commands = rng.uniform(-0.3, 0.3, (args.steps, 6)) * limits
    env = PushOffEnv(cfg.task, cfg.safety, seed=0)
    td = env.reset()

    bare = full = torchrl = 0.0
    for _ in range(args.blocks):
        runner.reset()
        t0 = time.perf_counter()
        for i in range(args.steps):
            runner.physics.data.ctrl[:6] = commands[i]
            runner.physics.step(substeps)
        bare += time.perf_counter() - t0
        runner.reset()
        t0 = time.perf_counter()
        for i in range(args.steps):
            runner.step_only(commands[i])
            runner.flat_observation()
        full += time.perf_counter() - t0
        td = env.reset()
        t0 = time.perf_counter()
        for i in range(args.steps):
            td["action"] = torch.as_tensor(commands[i][:5] / limits[:5], dtype=torch.float32)
            td = env.step(td)["next"]
        torchrl += time.perf_counter() - t0
    n = args.steps * args.blocks
    bare_rate, full_rate, torchrl_rate = n / bare, n / full, n / torchrl
    print(f"bare physics step : {bare_rate:8.0f} control steps/s ({bare / n * 1e6:7.1f} us)")
    print(f"full task step    : {full_rate:8.0f} control steps/s ({full / n * 1e6:7.1f} us)")
    print(f"TorchRL env.step  : {torchrl_rate:8.0f} control steps/s ({torchrl / n * 1e6:7.1f} us)")
    print(f"ratio full/bare   : {full_rate / bare_rate:.3f}   (goal >= 0.9)")
    print(f"ratio torchrl/bare: {torchrl_rate / bare_rate:.3f}")


if __name__ == "__main__":
    main()
