"""The PPO update per mini-batch: TorchRL's ClipPPOLoss against the lean plain-torch loss.

One batch collected by the trainer on the task (``profile=scratch`` by default: 2048 frames, 256-sample
mini-batches, 3x256 networks, the lane frame), GAE applied, the trainer's replay buffer filled; then,
interleaved on the same mini-batches and the same parameters (no optimiser step, so both see the same
network every time):

ClipPPOLoss : ``make_loss``'s ``ClipPPOLoss`` (what the trainer ran before 2026-12-04);
lean        : :class:`~ahrm_stack.learning.lean_loss.LeanClipPPOLoss` (what it runs now).

For each: the forward pass, and forward + backward + gradient clip (the part of the trainer's update that
differs), median over the mini-batches in milliseconds; the ratio ClipPPOLoss/lean; and the largest
relative difference between the two in the loss values and the gradients (equal to float32 rounding).

Usage: python benchmarks/bench_loss.py [--repeats N] [--quick] [key=value ...]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402
import torch  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.learning.lean_loss import lean_loss_for  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402

QUICK_OVERRIDES = ("ppo.frames_per_batch=128", "ppo.mini_batch_size=64")


def _timed(loss, batch, parameters, max_norm: float) -> tuple[float, float, list[torch.Tensor], torch.Tensor]:
    """(forward ms, forward+backward+clip ms, gradients, total loss) of one mini-batch."""
    for p in parameters:
        p.grad = None
    started = time.perf_counter()
    losses = loss(batch)
    total = losses["loss_objective"] + losses["loss_critic"]
    forward = time.perf_counter()
    total.backward()
    torch.nn.utils.clip_grad_norm_(parameters, max_norm)
    done = time.perf_counter()
    grads = [p.grad.clone() for p in parameters]
    return (forward - started) * 1e3, (done - started) * 1e3, grads, total.detach()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="passes over the batch's mini-batches")
    parser.add_argument("--quick", action="store_true", help="a small batch, one pass (CI)")
    parser.add_argument("--verbose", action="store_true")
    parser.add_argument("overrides", nargs="*", help="config overrides (default: profile=scratch)")
    args = parser.parse_args()
    overrides = args.overrides or ["profile=scratch"]
    if args.quick:
        overrides = [*overrides, *QUICK_OVERRIDES]
        args.repeats = 1
    config = load_config(overrides)
    trainer = Trainer(config, collect_demos=False)
    try:
        lean = lean_loss_for(config.ppo, trainer.modules)
        if lean is None:
            raise SystemExit("bench_loss: the lean loss does not apply to these settings (an entropy bonus?)")
        data = trainer._collect()
        with torch.no_grad():
            trainer.advantage(data)
        trainer.buffer.extend(data.reshape(-1))
        parameters = list(trainer.loss.parameters())
        times: dict[str, list[tuple[float, float]]] = {"ClipPPOLoss": [], "lean": []}
        worst_loss = worst_grad = 0.0
        warm = trainer.buffer.sample()  # first calls (allocations, lazy init) are not timed
        _timed(trainer.loss, warm, parameters, config.ppo.max_grad_norm)
        _timed(lean, warm, parameters, config.ppo.max_grad_norm)
        for _ in range(args.repeats):
            for _ in range(max(1, config.ppo.frames_per_batch // config.ppo.mini_batch_size)):
                batch = trainer.buffer.sample()
                f0, t0, g0, l0 = _timed(trainer.loss, batch, parameters, config.ppo.max_grad_norm)
                f1, t1, g1, l1 = _timed(lean, batch, parameters, config.ppo.max_grad_norm)
                times["ClipPPOLoss"].append((f0, t0))
                times["lean"].append((f1, t1))
                worst_loss = max(worst_loss, float((l1 - l0).abs() / l0.abs().clamp_min(1e-12)))
                for a, b in zip(g1, g0):
                    worst_grad = max(worst_grad, float((a - b).abs().max() / b.abs().max().clamp_min(1e-12)))
        median = {name: np.median(np.array(rows), axis=0) for name, rows in times.items()}
        print(f"PPO update per mini-batch of {config.ppo.mini_batch_size} samples, "
              f"{len(times['lean'])} mini-batches, networks {list(config.ppo.hidden_sizes)}")
        print(f"{'loss':<12} {'forward ms':>11} {'fwd+bwd+clip ms':>16}")
        for name, (forward, whole) in median.items():
            print(f"{name:<12} {forward:>11.2f} {whole:>16.2f}")
        ratio_forward = median["ClipPPOLoss"][0] / median["lean"][0]
        ratio_whole = median["ClipPPOLoss"][1] / median["lean"][1]
        print(f"ratio ClipPPOLoss/lean: forward {ratio_forward:.2f}x, forward+backward+clip {ratio_whole:.2f}x")
        print(f"largest relative difference: loss {worst_loss:.1e}, gradient {worst_grad:.1e}")
    finally:
        trainer.close()


if __name__ == "__main__":
    main()
