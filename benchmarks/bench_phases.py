"""Phase geometry of a tilted pusher: the fast routine against the reference routine, in one run.

``phase_geometry`` (phase, boundary distance x, clipped region distances) on the same inputs, run
twice: as shipped (the certified fast path, :func:`ahrm_stack.kinematics.cylinder_box._fast_distance`,
with the reference routine behind it) and with the fast path switched off (the reference routine
alone: alternating projections + the candidate-direction search, the routine before the fast path).
Inputs: every control step of the scripted controller's episodes (phases 1-3; recorded through the
task step) and random tilted pusher poses (tilt up to 0.5 rad, the tip in and around B_target).
Prints per-call median / p90 / max (us) of both, the ratio of medians, how many calls fell back to
the reference, and the largest difference between the two results (m).
Goals: fast median <= 20 us, max <= 100 us; results equal to 1e-9 m.

Usage: python benchmarks/bench_phases.py [--episodes N] [--random N] [--repeats R] [--quick]
"""

from __future__ import annotations

import math
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402

import ahrm_stack.env.task as task_module  # noqa: E402
import ahrm_stack.kinematics.cylinder_box as cylinder_box  # noqa: E402
from _scripted import layout_configs, quick_parser, quiet, record  # noqa: E402
from ahrm_stack.kinematics.phases import Cylinder, phase_geometry  # noqa: E402

GOAL_MEDIAN_US, GOAL_MAX_US = 20.0, 100.0


def scripted_inputs(episodes: int) -> list[tuple]:
    """(scene, pusher, clip) of every phase_geometry call of the scripted episodes (``episodes``
    per layout mode)."""
    calls = []
    shipped = task_module.phase_geometry

    def spy(scene, pusher, clip):
        calls.append((scene, pusher, clip))
        return shipped(scene, pusher, clip)

    task_module.phase_geometry = spy
    try:
        for config in layout_configs():
            record(config, episodes)
    finally:
        task_module.phase_geometry = shipped
    return calls


def random_inputs(template: tuple, count: int, seed: int = 0) -> list[tuple]:
    """Random tilted pushers (the task's size) with the tip in and around B_target of the first
    scripted scene; the obstacle scene is that scene's."""
    scene, pusher, clip = template
    rng = np.random.default_rng(seed)
    xlo, ylo, zlo, xhi, yhi, zhi = scene._target_bounds
    out = []
    for _ in range(count):
        tilt = rng.uniform(-0.5, 0.5, 2)
        angle = float(np.hypot(*tilt))
        k = np.array([tilt[0], tilt[1], 0.0]) / max(angle, 1e-12)
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        yaw = rng.uniform(0, 2 * math.pi)
        rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
        rotation = rz @ (np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx)
        rotation = rotation @ np.diag([1.0, -1.0, -1.0])  # axis pointing down, like the pusher
        tip = np.array([rng.uniform(xlo - 0.03, xhi + 0.03), rng.uniform(ylo - 0.03, yhi + 0.03),
                        rng.uniform(zlo + 0.005, zhi + 0.05)])
        center = tip - pusher.half_length * rotation[:, 2]
        out.append((scene, Cylinder(center, rotation, pusher.radius, pusher.half_length), clip))
    return out


def timed(inputs: list[tuple], repeats: int) -> tuple[np.ndarray, list]:
    """Per-call times (s, the minimum over ``repeats`` per input) and the results."""
    times = np.full(len(inputs), np.inf)
    results = []
    for r in range(repeats):
        for i, (scene, pusher, clip) in enumerate(inputs):
            start = time.perf_counter()
            out = phase_geometry(scene, pusher, clip)
            times[i] = min(times[i], time.perf_counter() - start)
            if r == 0:
                results.append(out)
    return times, results


def reference_only():
    """Context: the fast path off (every distance by the reference routine)."""
    class _Off:
        def __enter__(self):
            self.saved = cylinder_box._fast_distance
            cylinder_box._fast_distance = lambda cd, b: None

        def __exit__(self, *exc):
            cylinder_box._fast_distance = self.saved
    return _Off()


def count_fallbacks(inputs: list[tuple]) -> tuple[int, int]:
    """(exact distance queries, those the fast path handed to the reference routine)."""
    counts = [0, 0]
    fast = cylinder_box._fast_distance

    def counting(cd, b):
        counts[0] += 1
        d = fast(cd, b)
        counts[1] += d is None
        return d

    cylinder_box._fast_distance = counting
    try:
        for scene, pusher, clip in inputs:
            phase_geometry(scene, pusher, clip)
    finally:
        cylinder_box._fast_distance = fast
    return counts[0], counts[1]


def report(name: str, inputs: list[tuple], repeats: int) -> bool:
    with reference_only():
        ref_t, ref_out = timed(inputs, repeats)
    fast_t, fast_out = timed(inputs, repeats)
    queries, fallbacks = count_fallbacks(inputs)
    same_phase = all(a[0] == b[0] for a, b in zip(fast_out, ref_out))
    diff = max(max(abs(a[1] - b[1]), float(np.abs(a[2] - b[2]).max())) for a, b in zip(fast_out, ref_out))
    f_us, r_us = fast_t * 1e6, ref_t * 1e6
    tilted = sum(cylinder_box._tilt_sine(p) > cylinder_box.UPRIGHT_TOL for _, p, _ in inputs)
    print(f"{name}: {len(inputs)} calls ({tilted} tilted), phases 1/2/3: "
          + "/".join(str(sum(o[0] == k for o in fast_out)) for k in (1, 2, 3)))
    print(f"  reference : median {np.median(r_us):7.1f} us  p90 {np.percentile(r_us, 90):7.1f}  "
          f"max {r_us.max():7.1f}")
    print(f"  fast      : median {np.median(f_us):7.1f} us  p90 {np.percentile(f_us, 90):7.1f}  "
          f"max {f_us.max():7.1f}   ({fallbacks}/{queries} exact queries fell back)")
    print(f"  ratio reference/fast (medians): {np.median(r_us) / np.median(f_us):.1f}x   "
          f"phases equal: {same_phase}   max |difference| {diff:.2g} m")
    ok = same_phase and diff <= 2e-9
    met = np.median(f_us) <= GOAL_MEDIAN_US and f_us.max() <= GOAL_MAX_US
    print(f"  goal median <= {GOAL_MEDIAN_US:g} us, max <= {GOAL_MAX_US:g} us: {'met' if met else 'NOT met'}")
    return ok


def main() -> None:
    parser = quick_parser(__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=3, help="scripted episodes per layout mode (default 3)")
    parser.add_argument("--random", type=int, default=2000, help="random tilted poses (default 2000)")
    parser.add_argument("--repeats", type=int, default=5, help="timing repeats; each call's minimum counts")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.random, args.repeats = 1, 50, 1
    quiet()
    scripted = scripted_inputs(args.episodes)
    ok = report(f"scripted controller, {args.episodes} episodes per layout mode", scripted, args.repeats)
    ok &= report("random tilted poses", random_inputs(scripted[0], args.random), args.repeats)
    if not ok:
        raise SystemExit("fast and reference routines disagree")


if __name__ == "__main__":
    main()
