"""Collection: TorchRL's Collector against the trainer's LeanCollector, same environments and policy.

Two trainers of the same configuration (same seeds), one collecting with TorchRL's ``Collector``
over a ``SerialEnv`` (``tests/torchrl_reference.py``, the oracle the tests hold it to), one with
:class:`~ahrm_stack.learning.collection.LeanCollector`; their batches are identical
(``tests/test_collection.py``). Batches alternate between the two; prints frames/s of each, the
ratio lean/TorchRL and the per-frame time saved.

Usage: python benchmarks/bench_collection.py [--batches N] [--quick] [key=value ...]
       (default: train.num_envs=4, ppo.frames_per_batch=1024, the configured network)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import torch  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.learning.collection import LeanCollector  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # the reference lives with the tests
from torchrl_reference import ReferenceTrainer  # noqa: E402

DEFAULTS = ("train.num_envs=4", "ppo.frames_per_batch=1024", "train.warm_start=none", "ppo.bc_coeff=0")
QUICK = ("ppo.frames_per_batch=64", "ppo.mini_batch_size=32")


def _trainer(overrides: list[str], lean: bool) -> Trainer:
    trainer = (Trainer if lean else ReferenceTrainer)(load_config(overrides))
    trainer._collect()  # builds the collector (with lean: LeanCollector) and warms it up
    assert isinstance(trainer._collector, LeanCollector) == lean
    return trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--batches", type=int, default=6)
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 batch of 64 frames): checks that the benchmark works")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    overrides = [*DEFAULTS, *args.overrides]
    if args.quick:
        args.batches, overrides = 1, [*overrides, *QUICK]
    config = load_config(overrides)
    torch.set_num_threads(config.train.threads)
    torchrl, lean = _trainer(overrides, False), _trainer(overrides, True)
    seconds = {"torchrl": 0.0, "lean": 0.0}
    for _ in range(args.batches):
        for name, trainer in (("torchrl", torchrl), ("lean", lean)):
            started = time.perf_counter()
            trainer._collect()
            seconds[name] += time.perf_counter() - started
    torchrl.close()
    lean.close()
    frames = args.batches * config.ppo.frames_per_batch
    rate = {name: frames / s for name, s in seconds.items()}
    saved = (seconds["torchrl"] - seconds["lean"]) / frames * 1e6
    print(f"{config.train.num_envs} environments, {config.ppo.frames_per_batch} frames/batch, "
          f"network {list(config.ppo.hidden_sizes)}, action mode {config.task.action.mode}, "
          f"{args.batches} batches each, alternating")
    print(f"  TorchRL Collector : {rate['torchrl']:7.0f} frames/s")
    print(f"  LeanCollector     : {rate['lean']:7.0f} frames/s")
    print(f"  ratio lean/TorchRL: {rate['lean'] / rate['torchrl']:.3f}  ({saved:.0f} us saved per frame)")


if __name__ == "__main__":
    main()
