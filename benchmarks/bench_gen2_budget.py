"""The Kinova Gen2 USB budget: the deploy loop at 20 Hz on the realistic fake SDK, for minutes, with
faults.

The scripted controller drives the fake-SDK arm (``tests/fake_kinova_sdk``: ``--latency-ms`` per
call, 3 ms by default, one call at a time, the 2,000-point trajectory FIFO run at 100 Hz, noisy
velocity feedback) through :class:`~ahrm_stack.deploy.DeployLoop` on a static scene, paced to the
wall clock at ``--rate`` Hz for ``--duration`` s (600 by default, the issue's 10 minutes; ``--quick``
10 s, a fault every 2.5 s). Between ticks the garbage collector runs as in ``DeployLoop.run``. Every ``--fault-every`` s
a fault is injected, in turn: a logged system error, the e-stop (both seen by the status poll), the
USB link lost; the loop stops, the fault is released, the adapter reconnected or cleared, the loop
resumed. Misses and late feedback are counted, never a stop.

Figures (goals of issue 41 in brackets), from the loop's records, the USB thread's own timings and
the fake's call log (CLOCK_MONOTONIC, the clock of ``time.perf_counter``):

- missed command deadlines [0 in 10 minutes at 20 Hz] and the loop's tick latency; for the ticks
  that missed, where their time went: the garbage collection after the previous tick, the tick
  starting late (the OS ran something else when the loop's sleep ended), the position read (the
  USB: waiting for the bus and the call), the rest (checks, world model, controller, filter) and
  handing the command over;
- the point rate the arm received while a command stood [>= 99 Hz]; the time its FIFO stood empty
  meanwhile (starved) and the FIFO's peak;
- each SDK function's latency as the USB thread measured it (p50 / p99 / max), and how long a tick's
  position read waited for the bus, with the most calls that were ahead of it (design: 2);
- per fault: from its detection to zero velocity and an empty FIFO on the arm [within one period],
  from the stopping tick's start to the loop's stop, the FIFO after the stop [empty], and from the
  injection to the detection (the status poll's period bounds it).

The ratio line compares the two rates of the run: points the arm received per policy tick (goal
100/20 = 5). Exit status 1 only when a stop left points in the FIFO or a fault did not stop the loop.

Usage: python benchmarks/bench_gen2_budget.py [--duration S] [--rate HZ] [--fault-every S]
       [--latency-ms MS] [--quick]
Needs a C compiler (the fake SDK is compiled into a temporary folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
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

FUNCTIONS = ("GetAngularPosition", "SendAdvanceTrajectory", "EraseAllTrajectories", "GetSensorsInfo",
             "GetSystemErrorCount", "GetAngularForce")


@dataclasses.dataclass
class FaultRecord:
    kind: str
    injected: float  # perf_counter s
    detected: float
    arm_stopped_ms: float  # detection -> zero + erase on the arm (lost link: its queued motion)
    loop_stopped_ms: float  # the stopping tick's start -> the loop's stop
    ticks: int  # ticks from the injection to the stop
    fifo_after: int  # points in the arm's FIFO after the stop


def _starved(arrivals: np.ndarray, until: float, point: float) -> tuple[float, float]:
    """s the FIFO stood empty between the first arrival and ``until``, and the longest such gap, for
    points arriving at ``arrivals`` (s, sorted), each ``point`` s of motion (the fake's rule)."""
    idle, longest, end = 0.0, 0.0, arrivals[0]
    for t in arrivals:
        gap = t - end
        if gap > 0:
            idle, longest = idle + gap, max(longest, gap)
        end = max(end, t) + point
    tail = until - end
    if tail > 0:
        idle, longest = idle + tail, max(longest, tail)
    return idle, longest


def budget_run(duration: float, rate_hz: float = 20.0, fault_every: float = 30.0,
               latency: float = 0.003) -> dict:
    """The deploy loop on the fake SDK for ``duration`` s at ``rate_hz``, a fault every
    ``fault_every`` s; the figures of the module docstring."""
    from fake_kinova_sdk.fake import SERIAL, FakeSdk, session_library

    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import DeployLoop, load_deploy_settings
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.deploy import backends
    from ahrm_stack.hardware.kinova_gen2 import SYSTEM_ERROR_TYPES
    from ahrm_stack.hardware.kinova_gen2.bus import POINT_PERIOD

    library = session_library()
    fake = FakeSdk(library)
    config = load_config()
    fake.reset(position_deg=np.degrees(config.task.arm.home), latency=latency)
    settings = load_deploy_settings(realtime=True, telemetry="", rate_hz=rate_hz)
    settings = dataclasses.replace(
        settings, watchdog=dataclasses.replace(settings.watchdog, max_deadline_misses=10**9,
                                               max_feedback_age=10.0),
        progress=dataclasses.replace(settings.progress, timeout=0.0),  # a static cube: no progress
        kinova_gen2=dataclasses.replace(settings.kinova_gen2, library=str(library), serial=SERIAL,
                                        scene=str(ROOT / "configs" / "scenes" / "default.yaml")))
    gen2, period = settings.kinova_gen2, settings.period
    most_ticks = math.ceil(1.0 / gen2.status_rate_hz / period) + 3
    kinds = [("system error", lambda: fake.inject_error(
                  SYSTEM_ERROR_TYPES.index("errorlog_Actuator_Temperature")), lambda: None),
             ("e-stop", lambda: fake.set_estop(True), lambda: fake.set_estop(False)),
             ("link lost", lambda: fake.set_unplugged(True), lambda: fake.set_unplugged(False))]
    arm = backends.get("kinova-gen2").make(config, settings)
    session = DeploySession.open(arm, config, None, settings)  # the scripted controller; reset by each loop
    arm.connect()
    mark = fake.call_count()
    faults: list[FaultRecord] = []
    segments: list[tuple[float, float]] = []  # (start, end) perf_counter s of motion
    problems: list[str] = []
    buses = [arm.bus]  # one per connection: their records
    parts: list[tuple[float, float, float, float, float, float, bool]] = []  # per tick
    stamps: dict[str, float] = {}
    refresh, send = arm.refresh_feedback, arm.send_joint_speeds

    def timed_refresh():
        stamps["asked"] = time.perf_counter()
        frame = refresh()
        stamps["read"] = time.perf_counter()
        return frame

    def timed_send(speeds):
        stamps["sending"] = time.perf_counter()
        sent = send(speeds)
        stamps["sent"] = time.perf_counter()
        return sent

    arm.refresh_feedback, arm.send_joint_speeds = timed_refresh, timed_send
    collecting = gc.isenabled()
    try:
        loop = session.loop()
        loop.start()
        if collecting:
            gc.freeze()
            gc.disable()
        start = time.perf_counter()
        segment_start = start
        next_fault = start + fault_every
        collected = 0.0  # s the collection before this tick took
        while time.perf_counter() < start + duration:
            stamps.clear()
            scheduled, misses = loop.next_tick_time, loop.deadline_misses
            if not loop.tick():
                problems.append(f"the loop stopped by itself: {loop.stop_reason}")
                break
            if len(stamps) == 4:
                parts.append((collected, scheduled, stamps["asked"], stamps["read"], stamps["sending"],
                              stamps["sent"], loop.deadline_misses > misses))
            if collecting:
                began = time.perf_counter()
                DeployLoop._collect_garbage()
                collected = time.perf_counter() - began
            if time.perf_counter() < next_fault:
                continue
            kind, inject, release = kinds[len(faults) % len(kinds)]
            bus, stops = arm.bus, len(arm.fault_stops)
            injected = time.perf_counter()
            segments.append((segment_start, injected))
            inject()
            ticks = 0
            while ticks < most_ticks:
                started = max(time.perf_counter(), loop.next_tick_time)
                ticks += 1
                if not loop.tick():
                    break
            else:
                problems.append(f"{kind}: the loop still ran {most_ticks} ticks after it")
                break
            if len(arm.fault_stops) <= stops:
                problems.append(f"{kind}: no stop recorded by the adapter ({loop.stop_reason})")
                break
            stop = arm.fault_stops[stops]
            if stop.stopped_at is not None:
                arm_stopped = stop.stopped_at - stop.detected_at
            else:  # the lost link: the arm runs out of the points it holds
                arm_stopped = bus.fifo_end - stop.detected_at
                time.sleep(max(0.0, bus.fifo_end + 0.005 - time.perf_counter()))
            fifo = fake.fifo_count()
            if fifo:
                problems.append(f"{kind}: {fifo} points left in the FIFO after the stop")
            faults.append(FaultRecord(kind, injected, stop.detected_at, arm_stopped * 1e3,
                                      (loop.stopped_at - started) * 1e3, ticks, fifo))
            release()
            if not arm.is_connected:
                arm.connect()
                buses.append(arm.bus)
            arm.clear_faults()
            loop.resume()
            segment_start = time.perf_counter()
            next_fault = segment_start + fault_every
        end = time.perf_counter()
        segments.append((segment_start, end))
        times = arm.call_times
    finally:
        if collecting:
            gc.unfreeze()
            gc.enable()
        arm.disconnect()
    calls = fake.calls(mark)
    points = np.array([c.t for c in calls if c.function == "SendAdvanceTrajectory"])
    received, moving, idle, longest = 0, 0.0, 0.0, 0.0
    for first, last in segments:
        inside = points[(points >= first) & (points < last)]
        if inside.size < 2:
            continue
        received += inside.size
        moving += last - inside[0]
        starved, gap = _starved(inside, last, POINT_PERIOD)
        idle, longest = idle + starved, max(longest, gap)
    latencies = {name: times.of(name) * 1e3 for name in FUNCTIONS} if times is not None else {}
    waits = [w for bus in buses if bus is not None for w in bus.waits]
    ahead = np.array([w.calls_ahead for w in waits])
    table = np.array([row[1:6] for row in parts]).reshape(-1, 5)
    missed = np.array([row[6] for row in parts], dtype=bool)
    breakdown = {"collection before": np.array([row[0] for row in parts]) * 1e3}
    breakdown.update({name: np.diff(table[:, k:k + 2], axis=1)[:, 0] * 1e3
                      for k, name in enumerate(("late start", "position read", "checks to the filter",
                                                "command handover"))})
    return {"duration": end - start, "breakdown": breakdown, "missed": missed, "rate_hz": rate_hz,
            "period": period, "ticks": loop.summary().ticks,
            "deadline_misses": loop.deadline_misses, "tick_ms": np.asarray(loop.latencies) * 1e3,
            "point_rate_hz": received / moving if moving else math.nan,
            "starved_ms_per_s": idle / moving * 1e3 if moving else math.nan,
            "longest_gap_ms": longest * 1e3, "fifo_peak": fake.fifo_peak(), "dropped": fake.dropped(),
            "points": received, "latencies_ms": latencies,
            "read_wait_ms": np.array([w.seconds for w in waits]) * 1e3,
            "calls_ahead": int(ahead.max()) if ahead.size else 0,
            "within_design": float(np.mean(ahead <= 2)) if ahead.size else math.nan,
            "faults": faults, "problems": problems, "latency_ms": latency * 1e3,
            "status_rate_hz": gen2.status_rate_hz}


def _spread(values: np.ndarray) -> str:
    if not len(values):
        return "none"
    p50, p99 = np.percentile(values, [50, 99])
    return f"p50 {p50:.2f} / p99 {p99:.2f} / max {np.max(values):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=600.0, help="s of deploy loop (default 600)")
    parser.add_argument("--rate", type=float, default=20.0, help="control rate, Hz")
    parser.add_argument("--fault-every", type=float, default=30.0, help="s between injected faults")
    parser.add_argument("--latency-ms", type=float, default=3.0, help="ms per SDK call on the fake")
    parser.add_argument("--quick", action="store_true", help="10 s, a fault every 2.5 s")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.fault_every = 10.0, 2.5
    logging.basicConfig(level=logging.ERROR)
    for name in ("ahrm_stack.hardware.kinova_gen2", "ahrm_stack.deploy"):  # the injected faults' stops: expected
        logging.getLogger(name).setLevel(logging.CRITICAL)
    r = budget_run(args.duration, args.rate, args.fault_every, args.latency_ms * 1e-3)
    period_ms = r["period"] * 1e3
    load = os.getloadavg()[0]
    print(f"Gen2 USB budget on the fake SDK ({r['latency_ms']:g} ms per call, one at a time): the deploy "
          f"loop at {r['rate_hz']:g} Hz for {r['duration']:.0f} s; load average (1 min) at the end "
          f"{load:.2f} on {os.cpu_count()} cores")
    print(f"deadlines: {r['ticks']} ticks, {r['deadline_misses']} missed (goal 0); tick latency "
          f"(feedback -> command, ms) {_spread(r['tick_ms'])}")
    missed = r["missed"]
    print(f"  where a tick's time went, ms, all ticks | the {int(missed.sum())} ticks that missed (median, max):")
    for name, values in r["breakdown"].items():
        tail = (f"{np.median(values[missed]):.2f}, {values[missed].max():.2f}" if missed.any() else "-")
        print(f"    {name:22s} {_spread(values)} | {tail}")
    print(f"points: the arm received {r['point_rate_hz']:.2f} Hz while a command stood (goal >= 99 Hz; "
          f"{r['points']} points); its FIFO stood empty {r['starved_ms_per_s']:.2f} ms/s (longest "
          f"{r['longest_gap_ms']:.1f} ms); FIFO peak {r['fifo_peak']} points, {r['dropped']} dropped")
    for name, values in r["latencies_ms"].items():
        print(f"  {name:22s} {len(values):6d} calls, ms {_spread(values)}")
    print(f"a caller's call (the tick's position read) waited for the bus: ms {_spread(r['read_wait_ms'])}; "
          f"<= 2 calls ahead of it in {r['within_design'] * 100:.2f} % of {len(r['read_wait_ms'])} calls, "
          f"at most {r['calls_ahead']} (design: 2, more only behind a stop)")
    faults = r["faults"]
    if faults:
        arm_ms = np.array([f.arm_stopped_ms for f in faults])
        loop_ms = np.array([f.loop_stopped_ms for f in faults])
        seen_ms = np.array([(f.detected - f.injected) * 1e3 for f in faults])
        empty = all(f.fifo_after == 0 for f in faults)
        met = arm_ms.max() <= period_ms and loop_ms.max() <= period_ms
        kinds = ", ".join(sorted({f"{f.kind} x{sum(g.kind == f.kind for g in faults)}" for f in faults}))
        print(f"faults: {len(faults)} ({kinds}); detection -> arm stopped ms {_spread(arm_ms)}; "
              f"stopping tick -> loop stopped ms {_spread(loop_ms)} (goal <= {period_ms:g} ms: "
              f"{'met' if met else 'NOT met'}); FIFO empty after every stop: {'yes' if empty else 'NO'}; "
              f"injection -> detection ms {_spread(seen_ms)} (status poll at {r['status_rate_hz']:g} Hz)")
    else:
        print("faults: none injected (run longer than --fault-every)")
    for problem in r["problems"]:
        print(f"PROBLEM: {problem}")
    print(f"ratio arm points per policy tick: {r['point_rate_hz'] / r['rate_hz']:.3f} "
          f"(goal 100/{r['rate_hz']:g} = {100 / r['rate_hz']:g})")
    if r["problems"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
