"""Deploy loop latency (feedback received → command sent) and missed deadlines, at 20 Hz and 100 Hz.

The scripted controller (or a policy run's, ``--checkpoint``) drives the sim backend paced to the
wall clock (``--realtime``, the default) for ``--duration`` s per rate (the issue's figure is
60 s; 10 s keeps it short); a new seeded episode starts whenever the cube is off the table. The
watchdog tolerates misses here so that they are counted instead of ending the run.

The "tick" is the loop's latency window, feedback received -> command sent (checks, perception,
world model, controller, safety filter, the adapter's send), wall clock. The sim backend's physics
is not in it: the simulated arm applies a command at its stamp on its next call and steps while
the loop sleeps (ahrm_stack/sim_arm.py), as a real arm moves on its own (before 2026-12-02 the send
stepped the physics up to the send time inside the window). The same window is also given in the
loop thread's CPU time, which leaves out the time the OS gave other processes. Besides the whole
tick it times the three costly parts inside it, in the same run: the world model's update (the
task's measurement: FK, phase geometry, contacts), the controller (mink IK, or the policy's
observation and forward pass) and the QP safety filter (obstacle rows on; differential IK for a
cartesian policy), each as p50 / p99 and as its share of the summed tick time; and the garbage
collections that ran inside a tick (the loop collects between ticks).
Goals: whole-tick p99 ≤ 1 ms; no missed deadline at 20 Hz.

Usage: python benchmarks/bench_deploy.py [--duration S] [--rates 20 100] [--fast] [--checkpoint RUN]
       [--policy-file PT] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import logging
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402

from ahrm_stack.deploy import load_controller_config, load_deploy_settings  # noqa: E402
from ahrm_stack.deploy.session import DeploySession  # noqa: E402
from ahrm_stack.hardware.protocol import FastClock, WallClock  # noqa: E402
from ahrm_stack.sim_arm import SimArm  # noqa: E402

GOAL_P99_MS = 1.0


class _Timed:
    """Wraps a callable and records the wall time of each call (s) made while ``active()``."""

    def __init__(self, inner, active=lambda: True) -> None:
        self.inner, self.active, self.times = inner, active, []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return self.inner(*args, **kwargs)
        finally:
            if self.active():
                self.times.append(time.perf_counter() - start)


class _GcTimes:
    """Python's garbage collections (gc.callbacks): the wall time (s) of those that start while
    ``active()`` (inside a tick) in ``times``, of the others (between ticks, set-up) in ``outside``."""

    def __init__(self, active) -> None:
        self.active, self.times, self.outside, self._start, self._inside = active, [], [], None, False

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._start, self._inside = time.perf_counter(), self.active()
        elif self._start is not None:
            (self.times if self._inside else self.outside).append(time.perf_counter() - self._start)
            self._start = None


class _CpuWindow:
    """The loop thread's CPU time (``time.thread_time``, s) from each tick's feedback received to
    its command sent: the latency window's own work, without the time the scheduler gave other
    processes (on a loaded machine the wall-clock figures are mostly that)."""

    def __init__(self, arm, ticking: list) -> None:
        self.times, self._start, self._ticking = [], None, ticking
        refresh, send = arm.refresh_feedback, arm.send_joint_speeds

        def refreshed():
            frame = refresh()
            self._start = time.thread_time() if self._ticking[0] else None
            return frame

        def sent(speeds):
            command = send(speeds)
            if self._start is not None and self._ticking[0]:
                self.times.append(time.thread_time() - self._start)
            self._start = None
            return command

        arm.refresh_feedback, arm.send_joint_speeds = refreshed, sent


def _flagged(call, flag: list):
    """``call`` with ``flag[0]`` true while it runs."""
    def flagged():
        flag[0] = True
        try:
            return call()
        finally:
            flag[0] = False
    return flagged


def _ms(values) -> tuple[float, float, float]:
    v = np.asarray(values) * 1e3
    return (float(np.percentile(v, 50)), float(np.percentile(v, 99)), float(v.max())) if v.size \
        else (float("nan"),) * 3


def bench_rate(rate: float, duration: float, realtime: bool, checkpoint, policy_file=None) -> dict:
    settings = load_deploy_settings(rate_hz=rate, realtime=realtime, telemetry="")
    settings = dataclasses.replace(settings, watchdog=dataclasses.replace(
        settings.watchdog, max_deadline_misses=10**9))
    config, actor = load_controller_config(checkpoint, policy_file=policy_file)
    clock = WallClock() if realtime else FastClock()
    arm = SimArm(config.task, seed=0, clock=clock)
    session = DeploySession.open(arm, config, actor, settings, world_seed=0)
    world = session.world
    loop = None  # the loop of the current episode: only its ticks are timed, not its start()
    in_tick = lambda: loop is not None and loop._started  # noqa: E731
    controller = session.controller = _Timed(session.controller, in_tick)
    session.world.update = _Timed(session.world.update, in_tick)  # the loop calls self.world.update(...)
    latencies, filter_times = [], []
    ticking = [False]  # inside a DeployLoop.tick call (the loop collects garbage between ticks)
    collections = _GcTimes(lambda: ticking[0])
    gc.callbacks.append(collections)
    misses = ticks = episodes = successes = 0
    stops = []
    arm.connect()
    cpu = _CpuWindow(arm, ticking)
    left = duration
    while left > 1e-9:
        arm.reset_scene(seed=episodes)
        loop = session.loop()
        # The loop calls self._solve: the filter, or its cartesian entry (differential IK).
        loop._solve = solve = _Timed(loop._solve, in_tick)
        loop.tick = _flagged(loop.tick, ticking)
        summary = loop.run(left)
        episodes += 1
        successes += summary.success
        latencies += loop.latencies
        filter_times += solve.times
        misses += loop.deadline_misses
        ticks += summary.ticks
        left -= max(summary.duration, loop.period)
        if not summary.success and "duration" not in summary.stop_reason:
            stops.append(summary.stop_reason)
            break
    arm.disconnect()
    gc.callbacks.remove(collections)
    total = float(np.sum(latencies)) or float("nan")
    share = {name: float(np.sum(t)) / total for name, t in
             (("world", world.update.times), ("controller", controller.times), ("filter", filter_times))}
    return dict(rate=rate, ticks=ticks, episodes=episodes, successes=successes, misses=misses,
                step=_ms(latencies), world=_ms(world.update.times), controller=_ms(controller.times),
                filter=_ms(filter_times), share=share, stops=stops, cpu=_ms(cpu.times),
                gc=(len(collections.times), float(np.sum(collections.times)) / total,
                    max(collections.times, default=0.0) * 1e3, len(collections.outside),
                    max(collections.outside, default=0.0) * 1e3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--duration", type=float, default=10.0, help="s per rate (default 10)")
    parser.add_argument("--rates", type=float, nargs="+", default=[20.0, 100.0])
    parser.add_argument("--fast", action="store_true", help="unpaced (deadlines then count only "
                        "computation)")
    parser.add_argument("--checkpoint", help="a policy run folder instead of the scripted controller")
    parser.add_argument("--policy-file", help="with --checkpoint: another policy of that run "
                        "(e.g. RUN/policies/episode-N.pt)")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 s at 20 Hz, unpaced): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.rates, args.fast = 1.0, [20.0], True
    logging.basicConfig(level=logging.ERROR)
    for logger in ("ahrm_stack.deploy", "ahrm_stack.env.runner"):
        logging.getLogger(logger).setLevel(logging.ERROR)
    mode = "fast" if args.fast else "realtime"
    name = "policy" if args.checkpoint else "scripted"
    print(f"deploy loop, sim backend, {name} controller, {mode}, {args.duration:g} s per rate")
    print(f"{'rate':>7} {'ticks':>6} {'eps':>4} {'ok':>3} {'missed':>6} | "
          f"{'tick p50/p99/max ms':>22} | {'world p50/p99':>15} | {'controller p50/p99':>18} | "
          f"{'filter p50/p99':>15}")
    for rate in args.rates:
        r = bench_rate(rate, args.duration, not args.fast, args.checkpoint, args.policy_file)
        step, world, ctrl, filt = r["step"], r["world"], r["controller"], r["filter"]
        print(f"{rate:5.0f}Hz {r['ticks']:6d} {r['episodes']:4d} {r['successes']:3d} "
              f"{r['misses']:6d} | {step[0]:6.3f} / {step[1]:6.3f} / {step[2]:6.3f} | "
              f"{world[0]:6.3f} / {world[1]:6.3f} | {ctrl[0]:7.3f} / {ctrl[1]:7.3f} | "
              f"{filt[0]:6.3f} / {filt[1]:6.3f}")
        share = r["share"]
        print(f"        the same window in the loop thread's CPU time: p50 {r['cpu'][0]:.3f} / p99 "
              f"{r['cpu'][1]:.3f} / max {r['cpu'][2]:.3f} ms (the rest of the wall time: waiting for "
              f"the CPU)")
        print(f"        share of the summed tick time: world model {share['world']:.0%}, controller "
              f"{share['controller']:.0%}, safety filter {share['filter']:.0%}, the rest (adapter, "
              f"checks) {1 - sum(share.values()):.0%}")
        count, gc_share, gc_worst, between, between_worst = r["gc"]
        print(f"        garbage collections inside ticks: {count} ({gc_share:.1%} of the summed tick "
              f"time, the longest {gc_worst:.3f} ms); outside them (between ticks, set-up): "
              f"{between}, the longest {between_worst:.3f} ms")
        for stop in r["stops"]:
            print(f"        stopped early: {stop}")
        verdict = "met" if step[1] <= GOAL_P99_MS else "NOT met"
        print(f"        goal whole-tick p99 <= {GOAL_P99_MS:g} ms: {verdict}"
              + (f"; goal 0 missed deadlines at 20 Hz: {'met' if r['misses'] == 0 else 'NOT met'}"
                 if rate == 20 else ""))


if __name__ == "__main__":
    main()
