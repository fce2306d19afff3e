"""The safety filter with the distance rows' fast path against the routine it replaced, in one run.

Two filters on the same scene, one with the shipped ``DistanceLimit`` (fast: coal functors and
transforms set up once, the rows assembled in a few array operations), one with the reference
routine of ``tests/distance_rows_reference.py`` (one ``signed_distance`` per pair, a fresh coal
result each, rows assembled pair by pair). They are called alternately on the same inputs (so a
loaded machine slows both alike), and their commands are compared bit for bit; then the distance
rows alone (``DistanceLimit.rows``) the same way. "wall" is perf_counter, "cpu" the thread's CPU
time (it leaves out the time the process was not running, which decides the wall-clock p99 on a
loaded machine). Cases:

* default      — the shipped configs/safety.yaml (table, workspace, table distance and self rows)
                 on the states of a random-policy episode (bench_safety.record_stream);
* 8 obstacles  — plus the obstacle rows, in bench_safety's crowded scene (the four obstacles
                 around the pusher; 8 obstacle rows per call).

Usage: python benchmarks/bench_distance_rows.py [--repeats R] [--steps N] [--quick]
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402

from bench_safety import build, filter_bench_setup, percentiles  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def reference_module():
    """tests/distance_rows_reference.py (the routine before the fast path)."""
    spec = importlib.util.spec_from_file_location("distance_rows_reference",
                                                  ROOT / "tests" / "distance_rows_reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def with_reference_rows(safety, scene, reference):
    """Give ``safety`` the reference distance rows (on its own kinematics snapshot)."""
    fast = safety.distances
    snapshot = safety._snapshot
    frames = {name: snapshot.model.frames[f].parentFrame for name, f in zip(fast.part_names, fast._part_frames)}
    safety.distances = reference.ReferenceDistanceLimit(
        scene, snapshot, frames, fast.safe_distance, fast.activation_distance, fast.max_obstacle_rows,
        fast.horizon, fast.self_pairs)
    return safety


def alternate(fast, slow, inputs, repeats):
    """Per-call wall-clock and CPU times (s; the thread's CPU time leaves out the time the
    process was not running, which dominates the wall-clock p99 on a loaded machine) of both
    filters, called alternately on the same inputs, and how many commands differed."""
    times = {fast: ([], []), slow: ([], [])}
    differ = 0
    wall, cpu = time.perf_counter, time.thread_time
    for repeat in range(repeats):
        for k, (q, dq, u_nom, u_prev) in enumerate(inputs):
            commands = []
            for safety in ((fast, slow) if (k + repeat) % 2 else (slow, fast)):
                start, start_cpu = wall(), cpu()
                result = safety(q, dq, u_nom, u_prev=u_prev)
                end_cpu, end = cpu(), wall()
                times[safety][0].append(end - start)
                times[safety][1].append(end_cpu - start_cpu)
                commands.append(result.command)
            differ += not np.array_equal(commands[0], commands[1])
    return times[fast], times[slow], differ


def alternate_rows(fast, slow, inputs, repeats, obstacles):
    """Per-call CPU times (s) of the two filters' distance rows alone (``DistanceLimit.rows``
    after the kinematics update), alternately on the same joint positions."""
    times: dict = {fast: [], slow: []}
    config = fast.config
    for repeat in range(repeats):
        for k, (q, *_) in enumerate(inputs):
            for safety in ((fast, slow) if (k + repeat) % 2 else (slow, fast)):
                safety._snapshot.update(q)
                start = time.thread_time()
                safety.distances.rows(safety._snapshot, config.table_distance_rows, obstacles,
                                      config.self_collision_rows)
                times[safety].append(time.thread_time() - start)
    return times[fast], times[slow]


def main() -> None:
    args, cfg, runner, stream, scene, crowd = filter_bench_setup(__doc__.splitlines()[0])
    reference = reference_module()

    print(f"safety filter per call, fast distance rows against the reference routine, called "
          f"alternately, {args.repeats} x {args.steps} calls per case; times in microseconds")
    print(f"{'rows':12s} {'':4s} {'fast p50':>9s} {'fast p99':>9s} {'ref p50':>9s} {'ref p99':>9s} "
          f"{'p50 ratio':>9s} {'p99 ratio':>9s}  commands differing")
    ratios = []
    for name, changes, inputs, case_scene in (("default", {}, stream, None),
                                              ("8 obstacles", {"obstacle_rows": True}, crowd, scene)):
        if case_scene is None:
            case_scene = runner.task.make_collision_scene(runner.physics)
        fast = build(runner, cfg.safety, changes, scene=case_scene)
        slow = with_reference_rows(build(runner, cfg.safety, changes, scene=case_scene), case_scene, reference)
        fast_times, slow_times, differ = alternate(fast, slow, inputs, args.repeats)
        for clock, f_times, s_times in (("wall", fast_times[0], slow_times[0]),
                                        ("cpu", fast_times[1], slow_times[1])):
            f50, f99 = percentiles(f_times)
            s50, s99 = percentiles(s_times)
            ratios.append((f"{name} {clock}", s50 / f50, s99 / f99))
            print(f"{name:12s} {clock:4s} {f50:9.1f} {f99:9.1f} {s50:9.1f} {s99:9.1f} {s50 / f50:8.2f}x "
                  f"{s99 / f99:8.2f}x  {differ} of {len(f_times)}")
        f_rows, s_rows = alternate_rows(fast, slow, inputs, args.repeats, bool(changes))
        (f50, f99), (s50, s99) = percentiles(f_rows), percentiles(s_rows)
        ratios.append((f"{name} rows", s50 / f50, s99 / f99))
        print(f"{name:12s} {'rows':4s} {f50:9.1f} {f99:9.1f} {s50:9.1f} {s99:9.1f} {s50 / f50:8.2f}x "
              f"{s99 / f99:8.2f}x  (the distance rows alone, CPU time)")
    print("ratio reference/fast (p50, p99): " + ", ".join(f"{n} {a:.2f}x {b:.2f}x" for n, a, b in ratios))
    try:
        load = os.getloadavg()[0]
        print(f"load average (1 min) at the end: {load:.2f} on {os.cpu_count()} cores")
    except OSError:
        pass


if __name__ == "__main__":
    main()
