"""Latency of the QP safety filter per call, and its share of one environment control step.

Rows of the table (each for daqp and for the persistent OSQP workspace):

* box          — hard bounds only (position, velocity, acceleration): coupled rows off;
* table+ws     — plus the table and workspace rows of the tip and the wrist (the spec's training rows);
* no self      — default without the self-collision rows (the default before they existed);
* default      — the shipped configs/safety.yaml: plus the table distance rows (pusher, links) and
                 the self-collision rows (coal);
* 8 obstacles  — default plus obstacle rows, in a scene where the four obstacles crowd the pusher
                 and wrist so that 8 robot-obstacle pairs are within the activation distance.

"hot" latencies replay the same inputs back to back (the filter alone, caches warm), wall clock
and the thread's CPU time ("cpu": it leaves out the time the process was not running, which decides
the wall-clock p99 on a loaded 2-core machine); "in loop" latencies are measured inside a
random-policy episode, alternating with ``runner.step_only`` (the real use: MuJoCo evicts the
filter's working set between calls), and the step share is sum(filter time) / sum(step_only time)
over that episode. "default cart" is the default rows in Cartesian mode (tip-velocity requests, the
training's action mode). For daqp the filter's fast path (every input finite) is then timed against
its general path (``SafetyFilter._filter_general``, the per-call routine before the fast path, which
still takes non-finite inputs) on the same inputs, called alternately; their commands must agree
bit for bit.
Usage: python benchmarks/bench_safety.py [--repeats R] [--steps N] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.env.control_step import make_task_filter  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402

VARIANTS = {
    "box": dict(table_rows=False, workspace_rows=False, table_distance_rows=False,
                self_collision_rows=False),
    "table+ws": dict(table_distance_rows=False, self_collision_rows=False),
    "no self": dict(self_collision_rows=False),
    "default": {},
    "8 obstacles": dict(obstacle_rows=True),
    "default cart": {},
}
GOALS_US = {("daqp", "table+ws"): 50.0, ("daqp", "8 obstacles"): 150.0}


def build(runner, config, changes, scene=None):
    task = runner.task
    config = dataclasses.replace(config, **changes)
    if scene is None and (config.table_distance_rows or config.obstacle_rows or config.self_collision_rows):
        scene = task.make_collision_scene(runner.physics)
    return make_task_filter(task, config, scene=scene)


def record_stream(runner, config, steps, seed=0):
    """(q, dq, u_nom, u_prev) of a random-policy episode through the default filter."""
    runner.reset()
    task = runner.task
    safety = build(runner, config, {})
    joints = runner.physics.bind(task.arm.joints)
    rng = np.random.default_rng(seed)
    stream, u_nom = [], np.zeros(6)
    for step in range(steps):
        if step % 20 == 0:
            u_nom = rng.uniform(-1.5, 1.5, 6) * task.robot.velocity_limit
            u_nom[5] = 0.0
        q, dq = np.array(joints.qpos), np.array(joints.qvel)
        stream.append((q, dq, u_nom.copy(), safety.previous_command))
        runner.step_only(safety(q, dq, u_nom).command)
    return stream


def crowded_scene(runner):
    """The pusher pointing down 5 cm above the table with the four obstacles around it, and the
    joint positions of that pose (damped least squares)."""
    task, kin = runner.task, runner.task.kinematics
    tip = kin.element_frame_id(task.pusher.tip_site)
    table = task.config.table.height
    target = np.array([0.0, 0.15, table + 0.05])
    q = np.asarray(task.config.arm.home, dtype=float)
    for goal in (target + [0, 0, 0.2], target):
        for _ in range(300):
            kin.update(q)
            p, rotation = kin.frame_pose(tip)
            error = np.r_[goal - p, np.cross(rotation[:, 2], [0.0, 0.0, -1.0])]
            jac = kin.frame_jacobian(tip)
            q = q + jac.T @ np.linalg.solve(jac @ jac.T + 1e-6 * np.eye(6), error)
    scene = task.make_collision_scene(runner.physics)
    half = np.asarray(task.config.obstacles.size) / 2
    offsets = np.array([[0.075, 0.0], [-0.075, 0.0], [0.0, 0.075], [0.0, -0.075]])
    centers = np.c_[target[:2] + offsets, np.full(4, table + half[2])]
    scene.update_objects(np.array([3.0, 3.0, table]), np.eye(3), centers, np.tile(np.eye(3), (4, 1, 1)))
    return scene, q


def percentiles(samples):
    us = np.asarray(samples) * 1e6
    return float(np.percentile(us, 50)), float(np.percentile(us, 99))


def cartesian_inputs(runner, stream, seed=3):
    """The recorded states with random tip-velocity requests (m/s, within the action's scale)."""
    rng = np.random.default_rng(seed)
    speed = runner.task.config.action.cartesian_max_speed
    return [(q, dq, rng.uniform(-speed, speed, 3), u_prev) for q, dq, _, u_prev in stream]


def hot_latency(safety, inputs, repeats, cartesian=False):
    """Per-call wall-clock and CPU times (s), the QP solver's part of each (s), and the mean
    number of obstacle rows built per call."""
    times, cpu, solve, rows = [], [], [], []
    call = safety.cartesian if cartesian else safety
    wall_clock, cpu_clock = time.perf_counter, time.thread_time
    for _ in range(repeats):
        for q, dq, request, u_prev in inputs:
            start, start_cpu = wall_clock(), cpu_clock()
            result = call(q, dq, request, u_prev=u_prev)
            end_cpu, end = cpu_clock(), wall_clock()
            times.append(end - start)
            cpu.append(end_cpu - start_cpu)
            solve.append(result.solve_time)
            rows.append(sum(name.startswith("obstacle:") for name in safety.last_rows))
    return times, cpu, solve, float(np.mean(rows))


def fast_against_general(safety, inputs, repeats, cartesian=False):
    """CPU times (s) per call of the filter's fast path (``safety``'s call) and of its general
    path on the same inputs, called alternately, and how many commands differ."""
    fast, general, differ = [], [], 0
    cpu_clock = time.thread_time
    fast_call = safety.cartesian if cartesian else safety
    for repeat in range(repeats):
        for k, (q, dq, request, u_prev) in enumerate(inputs):
            commands = []
            for path in ((0, 1) if (k + repeat) % 2 else (1, 0)):
                start = cpu_clock()
                if path == 0:
                    result = fast_call(q, dq, request, u_prev=u_prev)
                else:
                    result = safety._filter_general(q, dq, request, cartesian, None, u_prev)
                (fast if path == 0 else general).append(cpu_clock() - start)
                commands.append(result.command)
            differ += not np.array_equal(commands[0], commands[1])
    return fast, general, differ


def in_loop(runner, safety, steps, seed=1, cartesian=False):
    """Filter and step_only times (s) per control step of one random-policy episode (joint
    requests, or tip velocities with ``cartesian``)."""
    runner.reset()
    safety.reset()
    task = runner.task
    joints = runner.physics.bind(task.arm.joints)
    rng = np.random.default_rng(seed)
    filter_times, step_times, u_nom = [], [], np.zeros(6)
    call = safety.cartesian if cartesian else safety
    speed = task.config.action.cartesian_max_speed
    for step in range(steps):
        if step % 20 == 0:
            u_nom = rng.uniform(-1.5, 1.5, 6) * task.robot.velocity_limit
            u_nom[5] = 0.0
            if cartesian:
                u_nom = rng.uniform(-speed, speed, 3)
        q, dq = np.array(joints.qpos), np.array(joints.qvel)
        start = time.perf_counter()
        command = call(q, dq, u_nom).command
        middle = time.perf_counter()
        runner.step_only(command)
        filter_times.append(middle - start)
        step_times.append(time.perf_counter() - middle)
    return np.array(filter_times), np.array(step_times)


def crowded_inputs(runner, steps: int):
    """The crowded scene and ``steps`` filter inputs in it: joint positions (rad) within 0.02 of
    its pose, zero velocity, random requests (rad/s, within the velocity limits, and half of them)."""
    scene, q_crowd = crowded_scene(runner)
    rng = np.random.default_rng(2)
    limit = runner.task.robot.velocity_limit
    return scene, [(q_crowd + rng.uniform(-0.02, 0.02, 6), np.zeros(6), rng.uniform(-1, 1, 6) * limit,
                    rng.uniform(-0.5, 0.5, 6) * limit) for _ in range(steps)]


def filter_bench_setup(description: str):
    """The filter benchmarks' command line (``--repeats``, ``--steps``, ``--quick``: 40 steps, 1
    repeat, also from ``AHRM_BENCH_QUICK=1``) and inputs: returns (args, config, runner, the
    recorded scripted stream, the crowded scene, its inputs)."""
    parser = argparse.ArgumentParser(description=description)
    cli.add_verbose_flag(parser)
    parser.add_argument("--repeats", type=int, default=5, help="replays of the recorded inputs")
    parser.add_argument("--steps", type=int, default=600, help="control steps recorded / in loop")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (40 steps, 1 repeat): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.steps = 1, 40
    cfg = load_config()
    runner = TaskRunner(PushOffTask(cfg.task), seed=0)
    stream = record_stream(runner, cfg.safety, args.steps)
    return (args, cfg, runner, stream, *crowded_inputs(runner, args.steps))


def main() -> None:
    args, cfg, runner, stream, scene, crowd_inputs = filter_bench_setup(__doc__.splitlines()[0])
    cart_inputs = cartesian_inputs(runner, stream)

    print(f"safety filter latency, {args.repeats} x {args.steps} calls per row (hot) and one "
          f"{args.steps}-step random-policy episode per row (in loop); times in microseconds; "
          f"load average (1 min) {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"{'solver':6s} {'rows':12s} {'hot p50':>8s} {'hot p99':>8s} {'cpu p50':>8s} {'cpu p99':>8s} "
          f"{'QP p50':>7s} {'loop p50':>9s} {'loop p99':>9s} {'step p50':>9s} {'share':>7s}  goal")
    results, paths = {}, {}
    for solver in ("daqp", "osqp"):
        for name, changes in VARIANTS.items():
            changes = dict(changes, solver=solver)
            cartesian = name.endswith("cart")
            if name == "8 obstacles":
                safety = build(runner, cfg.safety, changes, scene=scene)
                inputs = crowd_inputs
            else:
                safety = build(runner, cfg.safety, changes)
                inputs = cart_inputs if cartesian else stream
            hot, cpu, solve, obstacle_rows = hot_latency(safety, inputs, args.repeats, cartesian)
            if name == "8 obstacles":
                loop_filter, loop_step = np.array([np.nan]), np.array([np.nan])
            else:
                loop_filter, loop_step = in_loop(runner, safety, args.steps, cartesian=cartesian)
            if solver == "daqp":
                paths[name] = fast_against_general(safety, inputs, max(1, args.repeats // 2), cartesian)
            hot50, hot99 = percentiles(hot)
            cpu50, cpu99 = percentiles(cpu)
            loop50, loop99 = percentiles(loop_filter)
            step50 = float(np.median(loop_step) * 1e6)
            share = float(loop_filter.sum() / loop_step.sum())
            goal = GOALS_US.get((solver, name))
            mark = "" if goal is None else (f"p99 <= {goal:.0f}: {'met' if hot99 <= goal else 'NOT met'}"
                                            f" (cpu: {'met' if cpu99 <= goal else 'NOT met'})")
            if name == "8 obstacles":
                mark += f" ({obstacle_rows:.1f} obstacle rows per call)"
            elif solver == "daqp":
                mark += ("  " if mark else "") + f"share <= 5%: {'met' if share <= 0.05 else 'NOT met'}"
            results[(solver, name)] = (hot50, hot99, loop50, share, percentiles(solve)[0])
            print(f"{solver:6s} {name:12s} {hot50:8.1f} {hot99:8.1f} {cpu50:8.1f} {cpu99:8.1f} "
                  f"{results[(solver, name)][4]:7.1f} {loop50:9.1f} {loop99:9.1f} {step50:9.1f} {share:7.1%}  {mark}")
    print("ratios osqp / daqp (hot p50): " + ", ".join(
        f"{name} {results[('osqp', name)][0] / results[('daqp', name)][0]:.1f}x" for name in VARIANTS))
    print("ratio default / no self (hot p50, daqp): "
          f"{results[('daqp', 'default')][0] / results[('daqp', 'no self')][0]:.2f}x; in loop "
          f"{results[('daqp', 'default')][2] / results[('daqp', 'no self')][2]:.2f}x")
    print("ratios in-loop / hot (p50, daqp): " + ", ".join(
        f"{name} {results[('daqp', name)][2] / results[('daqp', name)][0]:.1f}x"
        for name in VARIANTS if name != "8 obstacles"))
    print("ratios filter call / its QP solve (hot p50, daqp): " + ", ".join(
        f"{name} {results[('daqp', name)][0] / max(results[('daqp', name)][4], 1e-3):.0f}x" for name in VARIANTS))
    gc_share = []
    for name in ("table+ws", "default"):
        safety = build(runner, cfg.safety, dict(VARIANTS[name], solver="daqp"))
        cpu_on = hot_latency(safety, stream, args.repeats)[1]
        gc.disable()
        try:
            cpu_off = hot_latency(safety, stream, args.repeats)[1]
        finally:
            gc.enable()
        gc_share.append(f"{name} {percentiles(cpu_on)[1]:.1f} / {percentiles(cpu_off)[1]:.1f} us")
    print("garbage collector: hot cpu p99 with it on / off (daqp): " + ", ".join(gc_share))
    print("general / fast path, daqp, CPU time, called alternately (p50, p99; commands differing):")
    for name, (fast, general, differ) in paths.items():
        (f50, f99), (g50, g99) = percentiles(fast), percentiles(general)
        print(f"  {name:12s} fast {f50:6.1f} / {f99:6.1f}  general {g50:6.1f} / {g99:6.1f}  "
              f"ratio {g50 / f50:.2f}x / {g99 / f99:.2f}x  {differ} of {len(fast)}")


if __name__ == "__main__":
    main()
