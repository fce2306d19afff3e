"""The Kinova Gen2 backend in the full deploy loop, on the fake SDK: 20 Hz policy, 100 Hz sending,
limits and the command watchdog.

The scripted controller drives the fake-SDK arm through :class:`~ahrm_stack.deploy.DeployLoop`
(feedback → world model on a static scene → controller → safety filter → ``send_joint_speeds``)
paced to the wall clock for ``--duration`` s. Then the loop freezes ``--freezes`` times (it stops
ticking, as a hung process would); each time the USB thread's watchdog must stop the arm by itself.
(``benchmarks/bench_gen2_budget.py`` measures the USB budget: deadlines, the point rate, per-call
latency and fault stops over minutes.) Measured from
the fake SDK's own call log (CLOCK_MONOTONIC timestamps):

- every velocity command the arm received against the safety filter's velocity bound
  ((1 - margin) × the limit): goal 0 outside;
- the send rate, as the ratio of SendAdvanceTrajectory calls to policy ticks (goal 5 = 100/20);
- the watchdog's latency: from the frozen loop's command deadline (last fresh command +
  ``kinova_gen2.command_timeout`` periods) to the fake's recorded zero command: goal ≤ 20 ms.

Usage: python benchmarks/bench_kinova_gen2.py [--duration S] [--freezes N] [--quick]
Needs a C compiler (the fake SDK is compiled into a temporary folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

GOAL_LATENCY_MS = 20.0


def deploy_on_fake(duration: float, freezes: int, resume_ticks: int = 10) -> dict:
    """Run the deploy loop on the fake SDK; the figures of the module docstring."""
    from fake_kinova_sdk.fake import SERIAL, FakeSdk, session_library

    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.safety.filter import velocity_margin
    from ahrm_stack.deploy import backends

    library = session_library()
    fake = FakeSdk(library)
    config = load_config()
    fake.reset(position_deg=np.degrees(config.task.arm.home))
    settings = load_deploy_settings(realtime=True, telemetry="")
    # a missed deadline or late feedback (a loaded machine) is counted, not a stop: the figures
    # here are the USB thread's and the watchdog's
    settings = dataclasses.replace(settings, watchdog=dataclasses.replace(
        settings.watchdog, max_deadline_misses=10**9, max_feedback_age=10.0),
        kinova_gen2=dataclasses.replace(
        settings.kinova_gen2, library=str(library), serial=SERIAL,
        scene=str(ROOT / "configs" / "scenes" / "default.yaml")))
    arm = backends.get("kinova-gen2").make(config, settings)
    session = DeploySession.open(arm, config, None, settings)
    robot = session.world.robot
    bound_deg = np.degrees(robot.velocity_limit * (1.0 - velocity_margin(robot, config.safety)))
    arm.connect()
    try:
        loop = session.loop()
        loop.start()
        mark = fake.call_count()
        start_deg = fake.state()[0]
        ticks = 0
        for _ in range(max(1, int(round(duration / settings.period)))):
            if not loop.tick():
                raise RuntimeError(f"the deploy loop stopped: {loop.stop_reason}")
            ticks += 1
        # the first freeze starts now: reading the call log takes time, so it comes last
        end_mark, before = fake.call_count(), len(arm.watchdog_stops)
        moved_deg = float(np.abs(fake.state()[0] - start_deg).max())
        latencies = []
        for i in range(freezes):
            freeze_mark = end_mark
            if i:  # moving again before the next freeze (the watchdog latched: clear it first)
                arm.clear_faults()
                loop.resume()
                for _ in range(resume_ticks):
                    if not loop.tick():
                        raise RuntimeError(f"the deploy loop stopped: {loop.stop_reason}")
                before, freeze_mark = len(arm.watchdog_stops), fake.call_count()
            give_up = time.perf_counter() + arm.command_timeout + 2.0
            while len(arm.watchdog_stops) == before:  # the loop is frozen
                if time.perf_counter() > give_up:
                    bus = arm.bus
                    raise RuntimeError(
                        f"the watchdog did not stop the arm (freeze {i}: standing "
                        f"{arm.standing_command}, USB thread alive "
                        f"{bus is not None and bus.running})")
                time.sleep(0.01)
            stop = arm.watchdog_stops[before]
            # the watchdog's zero: the last zero command recorded before it noted the time
            zero = max((c for c in fake.calls(freeze_mark, "SendAdvanceTrajectory")
                        if not c.values.any() and c.t <= stop.sent_at), key=lambda c: c.t)
            latencies.append(zero.t - stop.deadline)
        sends = fake.calls(mark, "SendAdvanceTrajectory", until=end_mark)
        all_sends = fake.calls(mark, "SendAdvanceTrajectory")
        over = sum(int((np.abs(c.values) > bound_deg * (1 + 1e-6)).any()) for c in all_sends)
        gaps = np.diff([c.t for c in sends])
        return {"ticks": ticks, "sends": len(sends), "commands": len(all_sends), "over": over,
                "send_gap_p50_ms": float(np.median(gaps) * 1e3),
                "send_gap_p99_ms": float(np.percentile(gaps, 99) * 1e3),
                "moved_deg": moved_deg, "deadline_misses": loop.deadline_misses,
                "latencies_ms": np.asarray(latencies) * 1e3, "period": settings.period,
                "latency_p50_ms": float(np.percentile(loop.latencies, 50) * 1e3),
                "latency_p99_ms": float(np.percentile(loop.latencies, 99) * 1e3),
                "timeout_ms": arm.command_timeout * 1e3}
    finally:
        arm.disconnect()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="s of deploy loop")
    parser.add_argument("--freezes", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="2 s and 3 freezes")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.freezes = 2.0, 3
    logging.basicConfig(level=logging.ERROR)
    r = deploy_on_fake(args.duration, args.freezes)
    lat = r["latencies_ms"]
    print(f"deploy loop on the fake Gen2 SDK: {r['ticks']} policy ticks at "
          f"{1 / r['period']:g} Hz, {r['sends']} velocity commands sent "
          f"(gap p50 {r['send_gap_p50_ms']:.2f} ms, p99 {r['send_gap_p99_ms']:.2f} ms), "
          f"joints moved up to {r['moved_deg']:.1f} deg, deadline misses {r['deadline_misses']}, "
          f"tick latency p50 {r['latency_p50_ms']:.1f} ms p99 {r['latency_p99_ms']:.1f} ms")
    print(f"commands outside the filter's velocity bound: {r['over']} of {r['commands']} (goal 0)")
    print(f"watchdog ({r['timeout_ms']:.0f} ms): {len(lat)} freezes, zero command after the "
          f"deadline: median {np.median(lat):.2f} ms, max {lat.max():.2f} ms "
          f"(goal <= {GOAL_LATENCY_MS:g} ms: {'met' if lat.max() <= GOAL_LATENCY_MS else 'NOT met'})")
    print(f"ratio sends per policy tick: {r['sends'] / r['ticks']:.2f} (goal 100/20 = 5)")
    if r["over"] or not math.isfinite(lat.max()):
        sys.exit(1)


if __name__ == "__main__":
    main()
