"""Does the USB budget fit on this arm? ``python -m ahrm_stack.deploy --backend kinova-gen2 --check``.

Kinova's figures ("several ms" per call, one call at a time, kinova-ros issue 233) are not this
arm's, this cable's or this computer's. :func:`check_link` connects as deploy does and, **with the
arm held still** (zero velocities only), measures:

1. a held-still loop: ``check_calls`` control ticks at the configured rate, each one position read
   (``refresh_feedback``, timed from request to frame) and a zero-velocity command, while the USB
   thread sends its points and polls the status as in a run; the points the arm received per s;
2. ``check_calls`` calls of each SDK function the loop uses (``GetAngularPosition``,
   ``SendAdvanceTrajectory`` with a zero point, ``EraseAllTrajectories``, ``GetSensorsInfo``,
   ``GetSystemErrorCount``, ``GetAngularForce``) and ``GetAngularVelocity``, each timed on the USB
   thread;
3. the firmware's velocity feedback at rest (noise; the loop does not use it) against the loop's
   position-difference velocity;

then disconnects (zero, erase, StopControlAPI, CloseAPI) and judges (:func:`judge`) at the
configured rates, each line a pass or a fail with its figures:

- **bus load**: the share of each second the USB is busy, ``send_rate_hz`` x t(point) + the
  control rate x t(position) + ``status_rate_hz`` x (t(sensors) + t(error count) + t(torques)),
  medians, at most :data:`MAX_BUS_LOAD` (the rest absorbs the slow calls and the stops); with
  ``torque_each_tick`` the torques are read at the control rate, not the status poll's (and the
  held-still loop's ticks read them too, so the tick's p99 below includes them);
- **the tick**: the held-still loop's position read, p99, at most :data:`MAX_READ_SHARE` of the
  command deadline (``watchdog.command_deadline`` periods): the rest is perception's, the
  controller's and the safety filter's (their p99 is 2-7 ms on this project's machines);
- **the points**: a point held back by one call in progress still reaches the arm before its FIFO
  runs dry (two calls' p99 within ``send_ahead``), and the held-still loop's arm received at least
  :data:`MIN_POINT_SHARE` of ``send_rate_hz``.

Nothing here moves the arm: the only trajectory points are zero velocities.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING

import numpy as np

from ahrm_stack.hardware.call_stats import CallStats

if TYPE_CHECKING:
    from ahrm_stack.hardware.kinova_gen2.arm import KinovaGen2Arm

MAX_BUS_LOAD = 0.5  # share of each second the USB may be busy
MAX_READ_SHARE = 0.5  # share of the command deadline a tick's position read may take (p99)
MIN_POINT_SHARE = 0.99  # share of send_rate_hz the arm must receive
#: the functions timed, in the order reported; the loop's status poll is the last three but one
TIMED = ("GetAngularPosition", "SendAdvanceTrajectory", "EraseAllTrajectories", "GetSensorsInfo",
         "GetSystemErrorCount", "GetAngularForce", "GetAngularVelocity")
STATUS_CALLS = ("GetSensorsInfo", "GetSystemErrorCount", "GetAngularForce")
__all__ = ["MAX_BUS_LOAD", "MAX_READ_SHARE", "MIN_POINT_SHARE", "STATUS_CALLS", "TIMED", "CallStats", "Measurement",
           "Rates", "Verdict", "check_link", "judge", "measure", "report"]


@dataclasses.dataclass(frozen=True)
class Measurement:
    """What :func:`measure` found on the arm."""

    serial: str
    calls: dict[str, CallStats]  # by function
    read: CallStats  # the held-still loop's refresh_feedback, request -> frame
    ticks: int
    point_rate_hz: float  # points the arm received per s during the held-still loop
    raw_velocity_std: float  # deg/s, GetAngularVelocity at rest (all joints)
    derived_velocity_std: float  # deg/s, the loop's position-difference velocity at rest


@dataclasses.dataclass(frozen=True)
class Rates:
    """The configured rates the budget is judged at."""

    control_hz: float  # deploy.rate_hz
    command_deadline: float  # s after a tick its command must be sent
    send_rate_hz: float  # kinova_gen2.send_rate_hz
    send_ahead: float  # s, kinova_gen2.send_ahead
    status_rate_hz: float  # kinova_gen2.status_rate_hz
    torque_each_tick: bool  # kinova_gen2.torque_each_tick: the torques read with every tick


@dataclasses.dataclass(frozen=True)
class Verdict:
    """The judgement: a line per rule (``lines``), and whether all passed."""

    lines: tuple[str, ...]
    fits: bool


def measure(arm: "KinovaGen2Arm", rate_hz: float, calls: int) -> Measurement:
    """The measurements of the module docstring on a connected ``arm``, held still."""
    period = 1.0 / rate_hz
    zero = np.zeros(arm.num_joints)
    bus = arm.bus
    assert bus is not None
    reads, velocities = [], []
    arm.send_joint_speeds(zero)  # from rest: the first point is out when this returns
    points, t0 = bus.points, time.perf_counter()
    for k in range(calls):
        time.sleep(max(0.0, t0 + k * period - time.perf_counter()))
        asked = time.perf_counter()
        frame = arm.refresh_feedback()
        reads.append(time.perf_counter() - asked)
        velocities.append(frame.velocity)
        arm.send_joint_speeds(zero)
    elapsed = time.perf_counter() - t0
    received = bus.points - points
    arm.stop()
    times = arm.time_calls(calls)
    raw = arm.raw_velocities(calls)
    return Measurement(
        serial=arm.serial, calls={name: CallStats.of(times.of(name)[-calls:]) for name in TIMED},
        read=CallStats.of(np.asarray(reads)), ticks=calls, point_rate_hz=received / elapsed,
        raw_velocity_std=float(np.degrees(raw).std()),
        derived_velocity_std=float(np.degrees(np.asarray(velocities[1:])).std()))


def judge(m: Measurement, rates: Rates) -> Verdict:
    """The three rules of the module docstring at ``rates``."""
    c = m.calls
    tick_calls = ("GetAngularPosition", "GetAngularForce") if rates.torque_each_tick else ("GetAngularPosition",)
    load = (rates.send_rate_hz * c["SendAdvanceTrajectory"].p50
            + rates.control_hz * sum(c[name].p50 for name in tick_calls)
            + rates.status_rate_hz * sum(c[name].p50 for name in STATUS_CALLS if name not in tick_calls)) * 1e-3
    polled = len([name for name in STATUS_CALLS if name not in tick_calls])
    deadline_ms = rates.command_deadline * 1e3
    read_limit = MAX_READ_SHARE * deadline_ms
    held_back = max(s.p99 for name, s in c.items() if name != "GetAngularVelocity") + c["SendAdvanceTrajectory"].p99
    ahead_ms = rates.send_ahead * 1e3
    point_limit = MIN_POINT_SHARE * rates.send_rate_hz
    rules = [
        (load <= MAX_BUS_LOAD,
         f"bus load {load * 100:.0f} % of each second ({rates.send_rate_hz:g} points/s, "
         f"{rates.control_hz:g} position{' and torque' if rates.torque_each_tick else ''} reads/s, "
         f"{rates.status_rate_hz:g} status polls/s of {polled} calls; "
         f"limit {MAX_BUS_LOAD * 100:.0f} %)"),
        (m.read.p99 <= read_limit,
         f"a tick's position{' and torque' if rates.torque_each_tick else ''} read p99 {m.read.p99:.2f} ms "
         f"of the {deadline_ms:g} ms command deadline "
         f"(limit {read_limit:g} ms: the rest is perception's, the controller's and the filter's)"),
        (held_back <= ahead_ms,
         f"a point held back by one call reaches the arm {held_back:.2f} ms after it falls due "
         f"(p99s; within send_ahead {ahead_ms:g} ms)"),
        (m.point_rate_hz >= point_limit,
         f"the arm received {m.point_rate_hz:.1f} points/s in the held-still loop (limit "
         f"{point_limit:g})"),
    ]
    return Verdict(tuple(f"  {'fits' if ok else 'DOES NOT FIT'}: {text}" for ok, text in rules),
                   all(ok for ok, _ in rules))


def report(m: Measurement, rates: Rates) -> tuple[list[str], bool]:
    """The lines ``--check`` prints and whether the budget fits."""
    verdict = judge(m, rates)
    lines = [f"kinova-gen2 --check on the arm with serial {m.serial} (held still: zero velocities only)",
             f"held-still loop: {m.ticks} ticks at {rates.control_hz:g} Hz, each one position read "
             f"(request -> frame) {m.read}; the arm received {m.point_rate_hz:.1f} points/s",
             "SDK calls, each timed on the USB thread:"]
    lines += [f"  {name:22s} {stats}" for name, stats in m.calls.items()]
    lines.append(f"velocity at rest: GetAngularVelocity (not used by the loop) std "
                 f"{m.raw_velocity_std:.2f} deg/s; the loop's position differences std "
                 f"{m.derived_velocity_std:.3f} deg/s")
    lines.append(f"budget at {rates.control_hz:g} Hz control, {rates.send_rate_hz:g} Hz points, "
                 f"{rates.status_rate_hz:g} Hz status:")
    lines += list(verdict.lines)
    lines.append(f"the USB budget fits at {rates.control_hz:g} Hz" if verdict.fits else
                 f"the USB budget does NOT fit at {rates.control_hz:g} Hz: see docs/hardware.md "
                 "(Kinova Gen2, the USB budget) before any motion")
    return lines, verdict.fits


def check_link(arm: "KinovaGen2Arm", rates: Rates, calls: int) -> tuple[list[str], bool]:
    """Connect ``arm`` (not connected), measure it held still, disconnect; :func:`report`'s lines
    and verdict. Connecting may raise :class:`~ahrm_stack.hardware.protocol.HardwareError` (one line, e.g.
    no arm found)."""
    arm.connect()
    try:
        measured = measure(arm, rates.control_hz, calls)
    finally:
        arm.disconnect()
    return report(measured, rates)
