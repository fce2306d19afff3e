"""The homing step of a Kortex (Gen3) arm: ``python -m ahrm_stack.deploy --backend kortex --home``
moves the arm to the posture the policy was trained from (:class:`KortexHoming`; the command line
builds it in :func:`ahrm_stack.deploy.bring_up.home`).

**What moves.** One ``ReachJointAngles`` action (``Base.ExecuteAction``, as Kinova's
api_python/examples/102-Movement_high_level/01-move_angular_and_cartesian.py sends it) to the
policy's start, ``task.arm.home_deg``, every joint limited to ``kortex.home.speed_deg_s``
(``JointTrajectoryConstraint`` ``JOINT_CONSTRAINT_SPEED``, deg/s for joints: Kinova's user guide,
quoted in Kinovarobotics/Kinova-kortex2_Gen3_G3L issue 190; ros_kortex's simulated arm reads it so).
Kinova's predefined "Home" action is not used: it is the factory home, not the policy's start.

**Before it** (shared with the Gen2 step, :mod:`ahrm_stack.hardware.homing`): the target must be
inside every limited joint's range and pass the deploy loop's start check, and the straight
joint-space path from where the arm is must keep the pusher tip ``kortex.home.clearance`` m above
the table. Nothing moves without a confirmation: the arm's posture and the target are printed (the
arm's degrees), then the user types the arm's address or ``home`` (``--yes`` confirms for scripted
use). An arm already within ``tolerance_deg`` of the target is left where it is, without asking.
This move does not pass through the QP safety filter; the checks, the low speed, the supervision
and the person at the e-stop stand in for it.

**Supervision: nothing waits on the action.** Kinova's example blocks on a ``threading.Event``
until ``ACTION_END`` or ``ACTION_ABORT``. Here the notifications are queued by the link and read
at every poll, ``kortex.home.poll_periods`` control periods apart (at most half a period), with the
feedback (:meth:`~ahrm_stack.hardware.kortex.KortexArm.refresh_feedback`). ``Base.Stop`` is sent at
once, and why recorded (:class:`~ahrm_stack.hardware.homing.HomeOutcome`, the log), on: Ctrl-C or
SIGTERM (a ``KeyboardInterrupt`` wherever it lands); the move taking longer than
``kortex.home.timeout`` (the wait for the next poll ends at the deadline); a fault or the e-stop in
the feedback; a lost link (the adapter sends its best-effort Stop and closes, as in a run); an
RPC that times out; ``ACTION_ABORT`` from the arm; a joint over its speed alarm on
``watchdog.velocity_alarm_ticks`` reads in a row (``speed_deg_s`` times 1 +
``watchdog.velocity_tolerance``); or a joint more than ``kortex.home.path_tolerance_deg`` off the
planned path (the one the clearance was checked on). So the arm is stopped within one poll (plus
one feedback read) of any event it can see, inside one control period. The homing is done at
``ACTION_END`` with every joint within ``tolerance_deg`` of the target and slower than
``still_deg_s``. Every exit path, success included, then unsubscribes and disconnects (Stop,
CloseSession).
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Callable

import numpy as np

from ahrm_stack.hardware.homing import (BAD_INPUT, CONFIRM_WORD, DONE, INTERRUPTED, NOT_CONFIRMED,
                                        STOPPED, HomeOutcome, HomeRefusal, HomeStop, Limits, TaskModel,
                                        check_target, confirmed, degrees_text, path_clearance,
                                        path_deviation, start_target, supervised, wrap)
from ahrm_stack.hardware.kortex.moves import ACTION_ABORT, ACTION_END, kortex_degrees
from ahrm_stack.hardware.protocol import HardwareError

if TYPE_CHECKING:
    from ahrm_stack.hardware.kortex.arm import KortexArm

log = logging.getLogger("ahrm_stack.hardware.kortex")

__all__ = ["BAD_INPUT", "DONE", "INTERRUPTED", "NOT_CONFIRMED", "STOPPED", "KortexHoming"]


class KortexHoming:
    """One homing of a connected Kortex ``arm`` (see the module docstring): :meth:`run`.

    Args:
        arm: a connected :class:`~ahrm_stack.hardware.kortex.KortexArm`.
        world: the task's model (the policy's start, the tip's forward kinematics).
        limits: the deploy settings that apply (``limits.home``: ``kortex.home``).
        period: s, the control period (``1 / deploy.rate_hz``): the poll is
            ``kortex.home.poll_periods`` of it.
        say: prints one line to the user.
        ask: asks the user (a prompt -> the answer); None with ``--yes``.
        clock, sleep: s (time.perf_counter and time.sleep; tests keep them).
    """

    def __init__(self, arm: KortexArm, world: TaskModel, limits: Limits, period: float,
                 say: Callable[[str], None], ask: Callable[[str], str] | None,
                 clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.arm, self.world, self.limits = arm, world, limits
        self.home = limits.home
        self.poll = self.home.poll_periods * period
        self.say, self.ask, self.clock, self.sleep = say, ask, clock, sleep
        self.outcome = HomeOutcome(STOPPED, "")
        self.move_began: float | None = None  # clock() when ExecuteAction was sent

    def run(self) -> HomeOutcome:
        """Plan, confirm, move, and stop on every exit path (the outcome says why)."""
        outcome = self.outcome
        outcome.status, outcome.reason = supervised(self._run, self._stop)
        level = logging.INFO if outcome.status == DONE else logging.ERROR
        log.log(level, "kortex: homing of %s: %s", self.arm.address, outcome.reason)
        return outcome

    def _stop(self) -> None:
        """Base.Stop now; then Unsubscribe, and disconnect (Stop, CloseSession)."""
        try:
            if self.arm.is_connected:
                self.arm.stop()
        except HardwareError as error:  # lost link: the adapter sent its own Stop and closed
            log.error("kortex: homing: Stop failed (%s)", error)
        finally:
            try:
                if self.arm.is_connected:
                    self.arm.unsubscribe_actions()
            finally:
                self.arm.disconnect()

    def _run(self) -> tuple[int, str]:
        home, robot = self.home, self.world.robot
        q_now = self.arm.refresh_feedback().position
        target = start_target(self.world, q_now)
        check_target(self.world, target, self.limits)
        tolerance = math.radians(home.tolerance_deg)
        if np.all(np.abs(wrap(q_now - target)) <= tolerance):
            return DONE, (f"already at the policy's start posture (every joint within "
                          f"{home.tolerance_deg:g} deg); nothing moved")
        lowest, where = path_clearance(self.world, q_now, target)
        if lowest < home.clearance:
            raise HomeRefusal(f"the move from {degrees_text(np.degrees(q_now))} to the policy's start "
                              f"would bring the pusher tip {lowest:.3f} m above the table at "
                              f"{where:.0%} of the way (kortex.home.clearance: {home.clearance:g} m); "
                              "move the arm clear of the table first (the joystick or the Web App)")
        continuous = ~robot.limited
        address = self.arm.address
        self.say(f"Kortex arm at {address} ({self.arm.arm_description}; {robot.name}), joint angles "
                 "in deg as the arm reports them:")
        self.say(f"  now:    {degrees_text(kortex_degrees(q_now, continuous))}")
        self.say(f"  target: {degrees_text(kortex_degrees(target, continuous))} (the policy's start, "
                 f"task.arm.home_deg) at <= {home.speed_deg_s:g} deg/s per joint (one ReachJointAngles "
                 "action)")
        self.say("  keep a hand on the e-stop; Ctrl-C stops the arm")
        if self.ask is not None:
            try:
                answer = self.ask(f"type the arm's address ({address}) or '{CONFIRM_WORD}' to move it: ")
            except EOFError:
                answer = ""
            if not confirmed(answer, address):
                return NOT_CONFIRMED, "not confirmed: nothing moved"
        alarm = np.minimum(robot.velocity_limit, math.radians(home.speed_deg_s)) * (
            1.0 + self.limits.velocity_tolerance)
        q_from = self.arm.refresh_feedback().position  # where the action starts
        self.arm.subscribe_actions()
        self.outcome.moved = True
        self.move_began = self.clock()
        self.arm.move_to(target, home.speed_deg_s)
        q_end = self._watch(q_from, target, alarm)
        off = np.degrees(np.abs(wrap(q_end - target)))
        return DONE, (f"at the policy's start posture (largest joint error {off.max():.2f} deg, "
                      f"tolerance {home.tolerance_deg:g})")

    def _watch(self, q_from: np.ndarray, target: np.ndarray, alarm: np.ndarray) -> np.ndarray:
        """Poll feedback and the action's events until ``ACTION_END`` at the target (returns the
        position, rad); :class:`HomeStop` on anything in the module docstring's list."""
        home = self.home
        stage = "the move to the policy's start"
        still = math.radians(home.still_deg_s)
        tolerance = math.radians(home.tolerance_deg)
        off_path = math.radians(home.path_tolerance_deg)
        ticks = self.limits.alarm_ticks
        over = np.zeros(len(alarm), dtype=int)
        assert self.move_began is not None
        deadline = self.move_began + home.timeout
        ended = False
        while True:
            if self.clock() > deadline:
                raise HomeStop(f"{stage}: not done after {home.timeout:g} s (kortex.home.timeout)")
            events = self.arm.action_events()  # before the feedback: an abort's cause (a fault,
            feedback = self.arm.refresh_feedback()  # the e-stop) is then in this frame already
            now = self.clock()
            if not feedback.healthy:
                raise HomeStop(f"{stage}: arm fault ({feedback.faults!r}: {self.arm.fault_reason})")
            over = np.where(np.abs(feedback.velocity) > alarm, over + 1, 0)
            fast = np.flatnonzero(over >= ticks)
            if fast.size:
                i = int(fast[0])
                raise HomeStop(f"{stage}: joint {i} moving at {math.degrees(feedback.velocity[i]):.1f} "
                               f"deg/s, alarm at {math.degrees(alarm[i]):.1f} on {over[i]} reads in a row")
            deviation = path_deviation(feedback.position, q_from, target)
            if deviation > off_path:
                raise HomeStop(f"{stage}: the arm is {math.degrees(deviation):.1f} deg off the planned "
                               f"joint-space path (kortex.home.path_tolerance_deg "
                               f"{home.path_tolerance_deg:g})")
            for event in events:
                if event["event"] == ACTION_ABORT:
                    raise HomeStop(f"{stage}: the arm aborted the action (ACTION_ABORT, abort_details "
                                   f"{event.get('abort_details', 0)})")
                ended = ended or event["event"] == ACTION_END
            error = np.abs(wrap(feedback.position - target))
            if ended and np.all(np.abs(feedback.velocity) < still):
                if np.all(error <= tolerance):
                    self.outcome.stages.append(f"{stage}: done in {now - self.move_began:.1f} s")
                    return feedback.position
                raise HomeStop(f"{stage}: the arm reported ACTION_END {math.degrees(error.max()):.2f} deg "
                               f"from the target (kortex.home.tolerance_deg {home.tolerance_deg:g})")
            self.sleep(max(0.0, min(now + self.poll, deadline) - self.clock()))
