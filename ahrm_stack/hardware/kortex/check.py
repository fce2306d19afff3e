"""Does the Kortex link fit the control loop? ``python -m ahrm_stack.deploy --backend kortex --check``.

:func:`check_link` connects as a run does (the arm's model, its speed hard limits and soft limits
checked, its protection zones read), then, **with the arm held still**, runs ``kortex.check_ticks``
control ticks at ``deploy.rate_hz``, each one ``BaseCyclic.RefreshFeedback`` and one zero
``Base.SendJointSpeedsCommand`` sent the way a run sends them
(:meth:`~ahrm_stack.hardware.kortex.KortexArm.refresh_feedback`,
:meth:`~ahrm_stack.hardware.kortex.KortexArm.send_joint_speeds`: through the ``kortex_api`` process,
each with ``kortex.rpc_timeout_ms``). Each call is timed here (what the deploy loop waits for) and
in the ``kortex_api`` process (the RPC alone: :meth:`~ahrm_stack.hardware.kortex.KortexArm.link_timing`).
Then it disconnects (Stop, CloseSession) and judges (:func:`judge`):

- **the tick**: the two calls of a tick together, p99, within the send deadline
  (``watchdog.command_deadline`` control periods after the tick, by which the loop must have sent
  its command); perception, the controller and the safety filter come on top of it;
- **the timeout**: no call went unanswered within ``kortex.rpc_timeout_ms`` (a run stops on the
  first such feedback).

It also prints the arm's model, its soft limits per control mode and its protection zones. Exit
status (:func:`ahrm_stack.deploy.bring_up.check_link`): 0 fits, 1 does not, 3 the arm not reached or
refused. Nothing here moves the arm: every command is zero.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING

import numpy as np

from ahrm_stack.hardware.call_stats import CallStats
from ahrm_stack.hardware.kortex.arm_model import soft_limit_report
from ahrm_stack.hardware.protocol import FeedbackTimeoutError

if TYPE_CHECKING:
    from ahrm_stack.hardware.kortex.arm import KortexArm

#: the per-tick calls, as reported, and their link methods
CALLS = {"RefreshFeedback": "feedback", "SendJointSpeedsCommand": "joint_speeds"}


@dataclasses.dataclass(frozen=True)
class Rates:
    """What the link is judged against."""

    control_hz: float  # deploy.rate_hz
    send_deadline: float  # s after a tick its command must be sent (watchdog.command_deadline periods)
    rpc_timeout_ms: int  # kortex.rpc_timeout_ms


@dataclasses.dataclass(frozen=True)
class Measurement:
    """What :func:`measure` found on the arm."""

    address: str
    arm: str  # the arm's model and DoF
    ticks: int
    calls: dict[str, CallStats]  # by RPC, timed in this process
    vendor: dict[str, CallStats]  # by RPC, timed in the kortex_api process (the RPC alone)
    tick: CallStats  # a tick's two calls together, this process
    timeouts: int  # calls with no answer within the RPC timeout
    soft_limits: tuple[str, ...]  # lines: per control mode
    zones: str  # the protection zones, one line


@dataclasses.dataclass(frozen=True)
class Verdict:
    """A line per rule (``lines``), and whether all passed."""

    lines: tuple[str, ...]
    fits: bool


def measure(arm: KortexArm, rate_hz: float, ticks: int) -> Measurement:
    """The ticks of the module docstring on a connected ``arm``, held still."""
    period = 1.0 / rate_hz
    zero = np.zeros(arm.num_joints)
    times: dict[str, list[float]] = {name: [] for name in CALLS}
    both: list[float] = []
    timeouts = 0
    arm.link_timing(True)
    t0 = time.perf_counter()
    for k in range(ticks):
        time.sleep(max(0.0, t0 + k * period - time.perf_counter()))
        tick = 0.0
        for name, call in (("RefreshFeedback", arm.refresh_feedback),
                           ("SendJointSpeedsCommand", lambda: arm.send_joint_speeds(zero))):
            began = time.perf_counter()
            try:
                call()
            except FeedbackTimeoutError:  # no answer within the RPC timeout: counted, not fatal
                timeouts += 1
            took = time.perf_counter() - began
            times[name].append(took)
            tick += took
        both.append(tick)
    vendor = arm.link_timing(False)
    arm.stop()
    return Measurement(
        address=arm.address, arm=arm.arm_description, ticks=ticks,
        calls={name: CallStats.of(np.asarray(times[name])) for name in CALLS},
        vendor={name: CallStats.of(np.asarray(vendor.get(method, []))) for name, method in CALLS.items()},
        tick=CallStats.of(np.asarray(both)), timeouts=timeouts,
        soft_limits=tuple(soft_limit_report(arm.soft_limits)), zones=arm.zone_summary)


def judge(m: Measurement, rates: Rates) -> Verdict:
    """The two rules of the module docstring at ``rates``."""
    deadline_ms = rates.send_deadline * 1e3
    read, send = m.calls["RefreshFeedback"], m.calls["SendJointSpeedsCommand"]
    rules = [
        (m.tick.p99 <= deadline_ms,
         f"a tick's RefreshFeedback + SendJointSpeedsCommand p99 {m.tick.p99:.2f} ms of the "
         f"{deadline_ms:g} ms send deadline (watchdog.command_deadline; perception, the controller "
         "and the safety filter come on top)"),
        (m.timeouts == 0,
         f"{m.timeouts} of {2 * m.ticks} calls unanswered within kortex.rpc_timeout_ms "
         f"({rates.rpc_timeout_ms} ms; p99 RefreshFeedback {read.p99:.2f} ms, SendJointSpeedsCommand "
         f"{send.p99:.2f} ms)"),
    ]
    return Verdict(tuple(f"  {'fits' if ok else 'DOES NOT FIT'}: {text}" for ok, text in rules),
                   all(ok for ok, _ in rules))


def report(m: Measurement, rates: Rates) -> tuple[list[str], bool]:
    """The lines ``--check`` prints and whether the link fits."""
    verdict = judge(m, rates)
    lines = [f"kortex --check on the arm at {m.address}: {m.arm} (held still: zero joint speeds only)",
             f"{m.ticks} ticks at {rates.control_hz:g} Hz, each one RefreshFeedback and one zero "
             "SendJointSpeedsCommand as a run sends them; timed here (through the kortex_api process) "
             "| in the kortex_api process (the RPC alone):"]
    lines += [f"  {name:24s} {m.calls[name]} | {m.vendor[name]}" for name in CALLS]
    lines.append(f"  {'the tick (both)':24s} {m.tick}")
    lines.append("soft limits (ControlConfig.GetAllKinematicSoftLimits), per control mode:")
    lines += [f"  {line}" for line in m.soft_limits] or ["  none reported"]
    lines.append(m.zones)
    lines.append(f"budget at {rates.control_hz:g} Hz:")
    lines += list(verdict.lines)
    lines.append(f"the Kortex link fits at {rates.control_hz:g} Hz" if verdict.fits else
                 f"the Kortex link does NOT fit at {rates.control_hz:g} Hz: see docs/kortex.md "
                 "(Bring-up, --check) before any motion")
    return lines, verdict.fits


def check_link(arm: KortexArm, rates: Rates, ticks: int) -> tuple[list[str], bool]:
    """Connect ``arm`` (not connected), measure it held still, disconnect; :func:`report`'s lines
    and verdict. Connecting may raise :class:`~ahrm_stack.hardware.protocol.HardwareError` (one
    line: the arm not reached, or refused)."""
    arm.connect()
    try:
        measured = measure(arm, rates.control_hz, ticks)
    finally:
        arm.disconnect()
    return report(measured, rates)
