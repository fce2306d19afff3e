"""What a second process buys on this machine: the same work alone, then in N processes at once.

Each process runs a fixed amount of work of the kinds a training step is made of — MuJoCo steps of
resting boxes on a plane and a pure-Python loop — and reports its seconds. Run alone, then N at once
(N = ``--processes``, default the CPU count), in one run; prints each kind's per-process slow-down and
the **parallel speed-up** (N x alone / slowest of the N), the ceiling on what worker processes
(``train.env_workers``, :mod:`ahrm_stack.learning.pool`) or side-by-side runs can gain over one
process. On a machine whose vCPUs are SMT siblings of one physical core it is well below N.

Usage: python benchmarks/bench_cores.py [--processes N] [--repeats R] [--quick]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time

BOXES = ''.join(f'<body pos="{0.1 * i} 0 .05"><freejoint/><geom type="box" size=".04 .04 .04"/></body>'
                for i in range(6))
MODEL = f'<mujoco><worldbody><geom type="plane" size="1 1 .1"/>{BOXES}</worldbody></mujoco>'


def work(scale: float) -> dict[str, float]:
    """Seconds of each kind of work (the amounts times ``scale``)."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(MODEL)
    data = mujoco.MjData(model)
    out = {}
    started = time.perf_counter()
    for _ in range(int(20_000 * scale)):
        mujoco.mj_step(model, data)
    out["mujoco"] = time.perf_counter() - started
    started = time.perf_counter()
    total = 0
    for i in range(int(5_000_000 * scale)):
        total += i * i
    out["python"] = time.perf_counter() - started
    return out


def _child(scale: float, queue) -> None:
    queue.put(work(scale))


def together(processes: int, scale: float) -> list[dict[str, float]]:
    """``work`` in ``processes`` processes started at once."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    children = [context.Process(target=_child, args=(scale, queue)) for _ in range(processes)]
    for child in children:
        child.start()
    results = [queue.get() for _ in children]
    for child in children:
        child.join()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, default=os.cpu_count() or 2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (a tenth of the work, once): checks that the benchmark works")
    args = parser.parse_args()
    scale = 0.1 if args.quick else 1.0
    repeats = 1 if args.quick else args.repeats
    alone: dict[str, list[float]] = {}
    slowest: dict[str, list[float]] = {}
    for _ in range(repeats):  # alternating, so that drift in the machine's load hits both alike
        for kind, seconds in together(1, scale)[0].items():
            alone.setdefault(kind, []).append(seconds)
        results = together(args.processes, scale)
        for kind in results[0]:
            slowest.setdefault(kind, []).append(max(r[kind] for r in results))
    print(f"{os.cpu_count()} CPUs; {args.processes} processes at once against one alone, {repeats} repeats "
          f"(median seconds)")
    for kind in alone:
        one, many = sorted(alone[kind])[len(alone[kind]) // 2], sorted(slowest[kind])[len(slowest[kind]) // 2]
        print(f"  {kind:7s}: alone {one:6.3f} s, {args.processes} at once {many:6.3f} s (x{many / one:.2f} each); "
              f"parallel speed-up {args.processes * one / many:.2f} of {args.processes}")


if __name__ == "__main__":
    main()
