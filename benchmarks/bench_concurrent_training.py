"""Training on the whole machine: one run alone, one run with worker processes, N runs side by side.

A single training run steps its environments in its own process; two ways use more cores:
``train.env_workers`` (one run, its environments in worker processes, :mod:`ahrm_stack.learning.pool`)
and running several runs at once (what the experiment grid does: ``configs/experiment.yaml``
``cpus_per_run: 1``, so as many runs at a time as the machine has CPUs). Measured in one invocation,
each condition in fresh processes (spawned), one after the other:

alone       : one run of the config;
workers     : one run with ``train.num_envs=N train.env_workers=N`` (N = ``--runs``);
side by side: N runs of the config at once, seeds ``train.seed + k``.

Each process builds its trainer, runs one untimed iteration (the warm start, if any, happens there),
waits for the others at a barrier, then times ``Trainer.iteration`` until one of them has done
``--batches``; the others stop after the iteration they are in. A process's rate counts the frames
of the iterations it finished before the first run finished, and the iteration it was in then pro
rata of its time (so the frames counted were collected while all N ran). Prints frames/s per
condition (side by side: each run and the sum) and the ratios of the sums to alone: side by side /
alone is the parallel speed-up of whole runs (N at best). The issue's aim is >= 1000 frames/s on
this 2-core machine.

The setup's demonstrations and behaviour cloning are made brief (``SETUP``: they are untimed; the BC
anchor's cost per update does not depend on their number, but the cloned policy's episodes differ).

Usage: python benchmarks/bench_concurrent_training.py [--runs N] [--batches B] [--quick] [key=value ...]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from queue import Empty

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

from _scripted import QUICK_TRAINING  # noqa: E402

SETUP = ("train.demo_episodes=20", "train.bc_epochs=2")
AIM_RATE = 1000.0


def run(overrides: list[str], batches: int, barrier, stop, results, index: int) -> None:
    """One training run in this process; puts (index, frames per batch, the barrier's release time,
    the end time of each timed iteration) on ``results``, times from ``time.perf_counter`` (one clock
    for all processes here), or (index, the error's line) when it fails."""
    cli.quiet_argv()
    try:
        import torch

        from ahrm_stack.config import load_config
        from ahrm_stack.learning.trainer import Trainer

        config = load_config(overrides)
        torch.set_num_threads(config.train.threads)
        trainer = Trainer(config)
        try:
            trainer.iteration()  # untimed: the warm start, first-call costs
            barrier.wait()
            start = time.perf_counter()
            ends: list[float] = []
            while len(ends) < batches and not stop.is_set():
                trainer.iteration()
                ends.append(time.perf_counter())
            stop.set()
        finally:
            trainer.close()
        results.put((index, config.ppo.frames_per_batch, start, ends))
    except BaseException as error:  # noqa: BLE001 - reported by the parent, which exits
        barrier.abort()  # the others must not wait for this one
        stop.set()
        results.put((index, f"{type(error).__name__}: {error}"))


def condition(overrides: list[list[str]], batches: int) -> list[float]:
    """Runs the given runs at once (one process each, non-daemonic: a run may start worker
    processes); each one's frames/s over the iterations that ended before the first run finished."""
    context = multiprocessing.get_context("spawn")
    barrier, stop, queue = context.Barrier(len(overrides)), context.Event(), context.Queue()
    processes = [context.Process(target=run, args=(o, batches, barrier, stop, queue, k))
                 for k, o in enumerate(overrides)]
    for process in processes:
        process.start()
    results: dict[int, tuple] = {}
    while len(results) < len(processes):
        try:
            item = queue.get(timeout=1.0)
        except Empty:  # a run that died without a word (a signal, the OOM killer) must not hang this
            dead = [k for k, p in enumerate(processes) if k not in results and not p.is_alive()]
            if dead and queue.empty():
                for process in processes:
                    process.kill()
                code = processes[dead[0]].exitcode
                raise SystemExit(f"run {dead[0]} ended without a result (exit code {code})") from None
            continue
        results[item[0]] = item[1:]
    for process in processes:
        process.join()
    failed = [f"run {k}: {r[0]}" for k, r in sorted(results.items()) if len(r) == 1]
    if failed:
        raise SystemExit("; ".join(failed))
    first_done = min(ends[-1] for _, _, ends in results.values())
    rates = []
    for k in range(len(overrides)):
        frames, start, ends = results[k]
        done, previous = 0.0, start  # iterations done by first_done: the one in progress pro rata
        for end in ends:
            if end <= first_done:
                done, previous = done + 1.0, end
            else:
                done += (first_done - previous) / (end - previous)
                break
        rates.append(frames * done / (first_done - start))
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--runs", type=int, default=os.cpu_count() or 2,
                        help="N: runs side by side and worker processes (default: the CPU count)")
    parser.add_argument("--batches", type=int, default=4, help="timed iterations of the first run to finish")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 batch of 64 frames, 1 demonstration): checks that the benchmark works")
    parser.add_argument("overrides", nargs="*", help="config overrides for every run")
    args = parser.parse_args()
    if args.runs < 2:
        raise SystemExit(f"--runs must be >= 2, got {args.runs}")
    if args.batches < 1:
        raise SystemExit(f"--batches must be >= 1, got {args.batches}")
    base = [*SETUP, *args.overrides]
    if args.quick:
        args.batches, base = 1, [*base, *QUICK_TRAINING]
    from ahrm_stack.config import ConfigError, load_config

    try:  # one line naming the bad key before any process starts
        config = load_config(base)
        load_config([*base, f"train.num_envs={args.runs}", f"train.env_workers={args.runs}"])
    except ConfigError as error:
        raise SystemExit(str(error)) from None
    n = args.runs
    print(f"{n} runs / workers; network {list(config.ppo.hidden_sizes)}, {config.ppo.frames_per_batch} "
          f"frames/batch, {config.ppo.epochs} epochs, {config.train.threads} thread(s) per run "
          f"({config.train.update_threads} for the update), {args.batches} timed batches; overrides: "
          f"{' '.join(args.overrides) or 'none'}")
    alone = condition([base], args.batches)[0]
    workers = condition([[*base, f"train.num_envs={n}", f"train.env_workers={n}"]], args.batches)[0]
    seed = config.train.seed
    side = condition([[*base, f"train.seed={seed + k}"] for k in range(n)], args.batches)
    total = sum(side)
    print(f"  alone                : {alone:7.0f} frames/s")
    print(f"  {n} env workers        : {workers:7.0f} frames/s   (ratio to alone {workers / alone:.3f})")
    print(f"  {n} runs side by side  : {total:7.0f} frames/s in all ({', '.join(f'{r:.0f}' for r in side)})")
    print(f"  parallel speed-up of runs (side by side / alone): {total / alone:.3f} of {n}")
    best = max(total, workers)
    print(f"  best use of the machine: {best:.0f} frames/s (aim >= {AIM_RATE:.0f}: "
          f"{'met' if best >= AIM_RATE else 'NOT met'})")


if __name__ == "__main__":
    main()
