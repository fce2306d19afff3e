"""The homing step of a Kinova Gen2 arm: ``python -m ahrm_stack.deploy --backend kinova-gen2 --home``
moves the arm to the posture the policy was trained from (:class:`Homing`; the command line builds
it in :func:`ahrm_stack.deploy.bring_up.home`, which gives it the deploy settings as :class:`Limits`).

**What moves, and why so.** Kinova's SDK has ``MoveHome`` (no arguments, exported by the vendored
``USBCommandLayerUbuntu.so``; kinova-ros's ``KinovaComm::homeArm`` calls it): the firmware drives
the arm to its *factory* home at its own speed and on its own path, as the joystick's home button.
That home is not the policy's start (j2n6s300's factory home, kinova-ros's ``j2n6s300.srdf``, is
about (275, 168, 57, 241, 83, 76) deg; ``task.arm.home_deg`` is (240, 204, 55, 351, 36, 75): the
pusher vertical 0.2 m above the table), and the firmware's speed cannot be limited. So homing is
two stages:

1. ``MoveHome`` (``kinova_gen2.home.factory_home_first``): the factory procedure, the way out of
   the retracted power-up posture (kinova-ros's README: "if the robot is not able to move after
   boot, please try to home the arm"); it ends when the arm has been still for ``home.settle`` s.
   Kinova's ``MoveHome`` blocks until the arm is home, so it runs on a thread of its own, never the
   USB thread, and a stop ends it (:mod:`~ahrm_stack.hardware.kinova_gen2.moves`): the supervision
   below reads, polls and stops during it as during stage 2;
2. one ``ANGULAR_POSITION`` trajectory point to the policy's start, every joint limited to
   ``home.speed_deg_s`` (``LimitationsActive``, ``speedParameter1``/``2``, as kinova-ros's
   ``setJointAngles``); the firmware moves the joints along a straight line in joint space.

Before stage 2 the target must be inside every limited joint's range (the deploy loop e-stops
outside it) and pass the deploy loop's own start check (:func:`~ahrm_stack.deploy.start_check.
start_refusal`), and the joint-space path from where the arm then is must keep the pusher tip
``home.clearance`` m above the table (forward kinematics of the task's model,
:meth:`~ahrm_stack.deploy.WorldModel.tip_pose`, at :data:`PATH_SAMPLES` points). These moves do not
pass through the QP safety filter (the filter shapes velocity commands in a run; the scene may not
be set up yet): the checks above, the low speed, the supervision below and the person at the
e-stop stand in for it.

**Nothing moves without a confirmation.** The arm's posture now and the target are printed
(Kinova's degrees), then the user types the arm's serial number or ``home``; anything else (an
empty line, end of input) moves nothing. ``--yes`` confirms for scripted use. An arm already within
``home.tolerance_deg`` of the target is left where it is, without asking.

**Supervision.** While the arm moves, its position is read at ``home.poll_rate_hz``
(:meth:`~ahrm_stack.hardware.kinova_gen2.KinovaGen2Arm.refresh_feedback`; the USB thread polls faults and the
e-stop as in a run). A fault, a joint over its speed alarm on ``watchdog.velocity_alarm_ticks``
consecutive reads (stage 1: the arm's velocity limit; stage 2: ``home.speed_deg_s``, each times
1 + ``watchdog.velocity_tolerance``), a stage longer than ``home.timeout`` s, a lost link, Ctrl-C
or SIGTERM: the arm is stopped (zero velocity, ``EraseAllTrajectories``) at once. Every exit path,
success included, then disconnects (``StopControlAPI``, ``CloseAPI``), and the reason is printed
and logged (:class:`HomeOutcome`).
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Callable

import numpy as np

from ahrm_stack.hardware.homing import (BAD_INPUT, CONFIRM_WORD, DONE, INTERRUPTED, NOT_CONFIRMED,
                                        PATH_SAMPLES, STOPPED, HomeOutcome, HomeRefusal, Limits,
                                        TaskModel, check_target, confirmed, path_clearance,
                                        start_target, supervised)
from ahrm_stack.hardware.homing import HomeStop as _Stop
from ahrm_stack.hardware.homing import degrees_text as _degrees
from ahrm_stack.hardware.homing import wrap as _wrap
from ahrm_stack.hardware.kinova_gen2.settings import kinova_positions
from ahrm_stack.hardware.protocol import HardwareError

if TYPE_CHECKING:
    from ahrm_stack.hardware.kinova_gen2.arm import KinovaGen2Arm
    from ahrm_stack.hardware.kinova_gen2.settings import HomeSettings

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")

# The shared parts (the statuses, the target and its checks, the confirmation) live in
# ahrm_stack/hardware/homing.py; they are named here too, where the Gen2 step and its tests read them.
__all__ = ["BAD_INPUT", "CONFIRM_WORD", "DONE", "INTERRUPTED", "NOT_CONFIRMED", "PATH_SAMPLES",
           "STOPPED", "HomeOutcome", "HomeRefusal", "Homing", "Limits", "TaskModel", "check_target",
           "confirmed", "path_clearance", "start_target"]


class Homing:
    """One homing of a connected ``arm`` (see the module docstring): :meth:`run`.

    Args:
        arm: a connected :class:`~ahrm_stack.hardware.kinova_gen2.KinovaGen2Arm`.
        world: the task's model (the policy's start, the tip's forward kinematics).
        limits: the deploy settings that apply (:class:`Limits`).
        say: prints one line to the user.
        ask: asks the user (a prompt -> the answer); None with ``--yes``.
        clock, sleep: s (time.perf_counter and time.sleep; tests keep them).
    """

    def __init__(self, arm: KinovaGen2Arm, world: TaskModel, limits: Limits,
                 say: Callable[[str], None], ask: Callable[[str], str] | None,
                 clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.arm, self.world, self.limits = arm, world, limits
        self.home: HomeSettings = limits.home
        self.say, self.ask, self.clock, self.sleep = say, ask, clock, sleep
        self.outcome = HomeOutcome(STOPPED, "")

    def run(self) -> HomeOutcome:
        """Plan, confirm, move, and stop on every exit path (the outcome says why)."""
        outcome = self.outcome
        outcome.status, outcome.reason = supervised(self._run, self._stop)
        level = logging.INFO if outcome.status == DONE else logging.ERROR
        log.log(level, "kinova_gen2: homing of %s: %s", self.arm.serial, outcome.reason)
        return outcome

    def _stop(self) -> None:
        """Zero velocity and an empty FIFO now; then StopControlAPI and CloseAPI (disconnect)."""
        try:
            self.arm.stop()
        except HardwareError as error:  # lost link: disconnect closes what it can
            log.error("kinova_gen2: homing: stop failed (%s)", error)
        finally:
            self.arm.disconnect()

    def _run(self) -> tuple[int, str]:
        home, robot = self.home, self.world.robot
        q_now = self.arm.refresh_feedback().position
        target = start_target(self.world, q_now)
        check_target(self.world, target, self.limits)
        tolerance = math.radians(home.tolerance_deg)
        if np.all(np.abs(q_now - target) <= tolerance):
            return DONE, (f"already at the policy's start posture (every joint within "
                          f"{home.tolerance_deg:g} deg); nothing moved")
        if not home.factory_home_first:
            self._check_path(q_now, target)

        convention = self.arm.convention
        self.say(f"Kinova arm {self.arm.serial} ({robot.name}), Kinova joint angles in deg:")
        self.say(f"  now:    {_degrees(kinova_positions(q_now, convention))}")
        if home.factory_home_first:
            self.say("  first:  the factory home (MoveHome: the firmware's own path and speed)")
        self.say(f"  then:   {_degrees(kinova_positions(target, convention))} "
                 f"(the policy's start, task.arm.home_deg) at <= {home.speed_deg_s:g} deg/s per joint")
        self.say("  keep a hand on the e-stop; Ctrl-C stops the arm")
        if self.ask is not None:
            try:
                answer = self.ask(f"type the arm's serial ({self.arm.serial}) or '{CONFIRM_WORD}' "
                                  "to move it: ")
            except EOFError:
                answer = ""
            if not confirmed(answer, self.arm.serial):
                return NOT_CONFIRMED, "not confirmed: nothing moved"
        alarm = robot.velocity_limit * (1.0 + self.limits.velocity_tolerance)
        if home.factory_home_first:
            self.outcome.moved = True
            self.arm.move_home()
            self._watch("MoveHome", alarm, None, busy=lambda: self.arm.move_home_running)
            self.arm.end_move_home()
            q_now = self.arm.refresh_feedback().position
            target = start_target(self.world, q_now)
            self._check_path(q_now, target)
        slow = np.minimum(alarm, math.radians(home.speed_deg_s) * (1.0 + self.limits.velocity_tolerance))
        self.outcome.moved = True
        self.arm.move_to(target, home.speed_deg_s)
        q_end = self._watch("the move to the policy's start", slow, target)
        off = np.degrees(np.abs(_wrap(q_end - target)))
        return DONE, (f"at the policy's start posture (largest joint error {off.max():.2f} deg, "
                      f"tolerance {home.tolerance_deg:g})")

    def _check_path(self, q_from: np.ndarray, q_to: np.ndarray) -> None:
        lowest, where = path_clearance(self.world, q_from, q_to)
        if lowest < self.home.clearance:
            error = _Stop if self.outcome.moved else HomeRefusal  # before any motion: bad input
            raise error(f"the move from {_degrees(np.degrees(q_from))} to the policy's start would "
                        f"bring the pusher tip {lowest:.3f} m above the table at {where:.0%} of the "
                        f"way (kinova_gen2.home.clearance: {self.home.clearance:g} m); move the arm "
                        "clear of the table first (the joystick)")

    def _watch(self, stage: str, alarm: np.ndarray, target: np.ndarray | None,
               busy: Callable[[], bool] | None = None) -> np.ndarray:
        """Read the position at ``poll_rate_hz`` until the arm has been still for ``settle`` s
        (and, with a ``target``, is within ``tolerance_deg`` of it; with ``busy``, once that says
        the move is no longer running: MoveHome's own end); :class:`_Stop` on a fault, an overspeed
        (``alarm``, rad/s, on ``velocity_alarm_ticks`` reads in a row) or the timeout. Returns the
        last position (rad)."""
        home = self.home
        period = 1.0 / home.poll_rate_hz
        still = math.radians(home.still_deg_s)
        tolerance = math.radians(home.tolerance_deg)
        ticks = self.limits.alarm_ticks
        over = np.zeros(len(alarm), dtype=int)
        begun = self.clock()
        still_since: float | None = None
        while True:
            feedback = self.arm.refresh_feedback()
            now = self.clock()
            if not feedback.healthy:
                raise _Stop(f"{stage}: arm fault ({feedback.faults!r}: {self.arm.fault_reason})")
            over = np.where(np.abs(feedback.velocity) > alarm, over + 1, 0)
            fast = np.flatnonzero(over >= ticks)
            if fast.size:
                i = int(fast[0])
                raise _Stop(f"{stage}: joint {i} moving at {math.degrees(feedback.velocity[i]):.1f} "
                            f"deg/s, alarm at {math.degrees(alarm[i]):.1f} on {over[i]} reads in a row")
            there = (target is None or bool(np.all(np.abs(_wrap(feedback.position - target))
                                                   <= tolerance))) and not (busy is not None and busy())
            if there and np.all(np.abs(feedback.velocity) < still):
                still_since = now if still_since is None else still_since
                if now - still_since >= home.settle:
                    self.outcome.stages.append(f"{stage}: done in {now - begun:.1f} s")
                    return feedback.position
            else:
                still_since = None
            if now - begun > home.timeout:
                raise _Stop(f"{stage}: not done after {home.timeout:g} s (kinova_gen2.home.timeout)")
            self.sleep(max(0.0, period - (self.clock() - now)))
