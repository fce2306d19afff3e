"""False alarms and runaway detection of the deploy loop's velocity e-stop on the Gen2 path.

The Gen2 adapter's joint velocities are position differences over at least
``kinova_gen2.velocity_window`` s (one 20 Hz period in a run); the loop e-stops when a joint reads
over (1 + ``watchdog.velocity_tolerance``) x its velocity limit on ``watchdog.velocity_alarm_ticks``
consecutive ticks (ahrm_stack/deploy/loop.py, mirrored in :func:`alarms`). With Gaussian angle
noise sigma each reading is v_true + (n_k - n_ref) / dt: what matters is sigma / dt. So the run is
time-scaled by ``--scale`` (10): ticks every period / scale, the window / scale, the fake's latency /
scale and sigma / scale give the same velocity distribution in 1 / scale of the time (the achieved
tick spacing is reported, times scale). The scaling is pessimistic: a read's stamp lags the
fake's sample by the thread's wake-up (~0.1-1 ms on a loaded machine: 1-2 % of a 50 ms period, 20 %
of a 5 ms one), an error in dt that real time does not have; at x20 on a load of 5.7 it made 4
false e-stops in 40,000 ticks, even at 1x noise, where the noise alone cannot (9 sigma).

Conditions, ``--ticks`` ticks at the limit and a tenth of that held still (the easier case), on
the fake SDK through :class:`~ahrm_stack.hardware.kinova_gen2.KinovaGen2Arm`:
angle noise at 1x (the level whose one-period difference is the fake's 1 deg/s velocity-feedback
noise, tests/test_kinova_gen2_estop.py BASE_NOISE) and 3x; the arm held still, and moving by itself
at exactly its velocity limit on every joint (the fastest a filtered command moves it: the worst
normal case). Reported: readings over the alarm, e-stops (false alarms). Then ``--runaways`` runaways
at 1.5x the limit on one joint, at 1x and 3x noise, in real time (not scaled: a read's stamp lags
the fake's sample by the thread's wake-up, ~0.1-1 ms on a loaded machine, which is 1-2 % of a 50 ms
period but 20-40 % of a period scaled by 20, and reads a runaway as slower): the ticks from its
start to the e-stop.

Usage: python benchmarks/bench_gen2_estop.py [--ticks N] [--scale S] [--runaways N] [--quick]
Needs a C compiler (the fake SDK is compiled into a temporary folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402


def alarms(speeds: np.ndarray, alarm: np.ndarray, ticks: int) -> tuple[int, int, list[int]]:
    """The loop's rule over ``speeds`` (ticks x joints, rad/s): readings over ``alarm``, e-stops
    (a joint over it on ``ticks`` consecutive readings; the count restarts after each) and the tick
    index of each e-stop."""
    over = np.abs(speeds) > alarm
    run = np.zeros(speeds.shape[1], dtype=int)
    fired: list[int] = []
    for k, row in enumerate(over):
        run = np.where(row, run + 1, 0)
        if (run >= ticks).any():
            fired.append(k)
            run[:] = 0
    return int(over.sum()), len(fired), fired


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=10_000)
    parser.add_argument("--scale", type=float, default=10.0)
    parser.add_argument("--runaways", type=int, default=10)
    parser.add_argument("--quick", action="store_true", help="300 ticks, 2 runaways (CI)")
    args = parser.parse_args(argv)
    if args.quick:
        args.ticks, args.runaways = 300, 2

    from fake_kinova_sdk import fake as fake_module

    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.robot import describe, make_arm
    from ahrm_stack.hardware.kinova_gen2 import KinovaGen2Arm

    config = load_config()
    settings = load_deploy_settings(realtime=True, telemetry="")
    robot = describe(config.task.robot, make_arm(config.task.robot))
    library = str(fake_module.session_library())
    fake = fake_module.FakeSdk(Path(library))
    limit = robot.velocity_limit
    alarm = limit * (1 + settings.watchdog.velocity_tolerance)
    ticks = settings.watchdog.velocity_alarm_ticks
    base = fake_module.VELOCITY_NOISE * settings.period / math.sqrt(2.0)  # deg

    def run(noise: float, drift_deg_s: np.ndarray, count: int, scale: float,
            stop_on_alarm: bool = False):
        period = settings.period / scale
        gen2 = dataclasses.replace(settings.kinova_gen2, library=library, serial=fake_module.SERIAL,
                                   velocity_window=settings.kinova_gen2.velocity_window / scale)
        fake.reset(position_deg=np.degrees(config.task.arm.home),
                   latency=fake_module.LATENCY / scale)
        fake.set_position_noise(noise / scale)
        arm = KinovaGen2Arm(robot, gen2, command_timeout_s=1.0)
        arm.connect()
        speeds, stamps = [], []
        fired = False
        try:
            arm.refresh_feedback()
            time.sleep(2 * period)
            fake.set_drift(drift_deg_s)
            next_tick = time.perf_counter()
            run_length = np.zeros(len(limit), dtype=int)
            for _ in range(count):
                frame = arm.refresh_feedback()
                speeds.append(frame.velocity)
                stamps.append(frame.timestamp)
                run_length = np.where(np.abs(frame.velocity) > alarm, run_length + 1, 0)
                if stop_on_alarm and (run_length >= ticks).any():
                    arm.apply_emergency_stop()
                    fired = True
                    break
                next_tick += period
                time.sleep(max(0.0, next_tick - time.perf_counter()))
        finally:
            fake.set_drift(np.zeros(6))
            arm.disconnect()
        return np.array(speeds), np.diff(stamps), fired

    print(f"# bench_gen2_estop: {args.ticks} ticks per condition, time-scaled x{args.scale:g}; "
          f"alarm (1 + {settings.watchdog.velocity_tolerance:g}) x limit on {ticks} ticks in a row; "
          f"1x angle noise = {base:.4f} deg")
    print("condition                 | ticks | spacing p50/p99 (ms, x scale) | readings over | e-stops")
    false_alarms = 0
    total = 0
    for level in (1.0, 3.0):
        for motion, drift, count in (("held still", np.zeros(6), max(100, args.ticks // 10)),
                                     ("at the limit", np.degrees(limit), args.ticks)):
            speeds, gaps, _ = run(level * base, drift, count, args.scale)
            total += len(speeds)
            over, fired, _ = alarms(speeds[1:], alarm, ticks)  # the first: the drift just began
            false_alarms += fired
            spacing = np.percentile(gaps, [50, 99]) * 1e3 * args.scale
            print(f"{level:g}x noise, {motion:12s} | {len(speeds):5d} | "
                  f"{spacing[0]:6.1f} / {spacing[1]:6.1f}             | {over:13d} | {fired}")
    runaway = np.zeros(6)
    runaway[0] = 1.5 * math.degrees(limit[0])
    missed = 0
    for level in (1.0, 3.0):
        fired_after = []
        for _ in range(args.runaways):
            speeds, _, fired = run(level * base, runaway, 10 * ticks, 1.0, stop_on_alarm=True)
            fired_after.append(len(speeds))
            missed += not fired
        counts = np.bincount(fired_after)
        spread = ", ".join(f"tick {k}: {n}" for k, n in enumerate(counts) if n)
        print(f"runaway at 1.5x the limit (joint 0, {level:g}x noise), {args.runaways} runs: e-stop on "
              f"{spread} of the runaway (configured: {ticks} in a row; one more when it began "
              f"between two reads; a noisy reading under the alarm restarts the count)")
    print(f"ratio false e-stops per tick: {false_alarms / total:.2e}")
    return 1 if false_alarms or missed else 0


if __name__ == "__main__":
    sys.exit(main())
