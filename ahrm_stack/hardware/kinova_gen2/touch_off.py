"""The tool's touch-off on a Kinova Gen2 arm: ``python -m ahrm_stack.deploy --backend kinova-gen2
--touch-off`` checks that the tool, the mount and the table are where the policy's model has them.

The policy and the safety filter assume the hand removed and a 15 cm x 4 cm rod at the wrist, the
arm's base at table height (docs/hardware.md, "The tool"). A different tool, a base on a spacer or a
table of another height puts the real tip centimetres from where forward kinematics says it is; the
filter's 1 cm table margin would then be fiction. So, for each of ``kinova_gen2.touch_off.points``
(three points of the table top, world frame, m):

1. the arm moves (one supervised ``ANGULAR_POSITION`` point, as ``--home``'s second stage:
   :class:`~ahrm_stack.hardware.kinova_gen2.home.Homing`'s supervision, speed limit and path check)
   to the posture with the pusher tip ``lift`` m above the point, pointing down (IK of the task's
   model), then ``approach`` m above it;
2. it is jogged down ``step`` m at a time (each step one such move), the user answering each time:
   Enter one step down, ``u`` one step up, ``t`` the tip touches the table (a sheet of paper under it
   is pinched), ``q`` stop; never more than ``below`` m below the model's table top;
3. at ``t`` the joint angles are read and forward kinematics gives the tip's height above the
   model's table top: that point's error (positive: the real tip met the table above the model's
   table top, e.g. a longer rod or a lower base; negative: below it).

Then the arm goes back up to ``lift``. The touch-off passes when every error is within
``max_error`` (3 mm). Its record (``touch_off.record``, JSON: the arm's serial, the time, each
point's angles and error, passed or not) is written either way; with ``touch_off.required`` a deploy
run on this backend refuses in one line unless the arm's latest record passed
(:func:`touch_off_refusal`). Every exit path stops the arm and disconnects, as ``--home``'s do.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ahrm_stack.hardware.kinova_gen2.home import (BAD_INPUT, DONE, NOT_CONFIRMED, STOPPED, HomeRefusal, Homing,
                                                  _Stop, path_clearance)

FAILED = 1  # exit status: the touch-off ran and an error exceeded max_error (as "not confirmed")
TOUCH_WORD = "touch"


def tip_target(world: Any, xy: tuple[float, float], height: float) -> np.ndarray:
    """The point ``height`` m above the task's table top at ``xy`` (m, world frame)."""
    return np.array([float(xy[0]), float(xy[1]), float(world.task.config.table.height) + height])


def solve_tip(world: Any, target: np.ndarray, q_init: np.ndarray, tolerance: float) -> np.ndarray:
    """Joint angles (rad) putting the pusher tip at ``target`` (m, world) pointing down, by the
    task model's IK (``world.tip_ik``: :meth:`~ahrm_stack.deploy.WorldModel.tip_ik`) from
    ``q_init``; :class:`HomeRefusal` when the tip misses by more than ``tolerance`` m or tilts more
    than the IK's tolerance (a point out of reach)."""
    q, miss, tilt = world.tip_ik(np.asarray(target, float), np.asarray(q_init, float))
    if miss > tolerance or tilt > world.task.config.arm.start_ik.tilt_tolerance:
        raise HomeRefusal(f"the touch-off point {np.round(target, 3).tolist()} m is out of the arm's "
                          f"reach pointing down (IK misses it by {miss * 1e3:.1f} mm, "
                          f"tilt {math.degrees(tilt):.1f} deg): choose kinova_gen2.touch_off.points "
                          "nearer the arm")
    return q


@dataclasses.dataclass
class PointResult:
    """One point: where (m, world), the angles read at the touch (rad) and the error (m)."""

    point: tuple[float, float]
    q: list[float]
    error: float


class TouchOff(Homing):
    """One touch-off of a connected arm (see the module docstring): :meth:`run`, whose outcome's
    status is :data:`DONE` (passed), :data:`FAILED` (an error above ``max_error``),
    :data:`NOT_CONFIRMED`, :data:`BAD_INPUT` (a point out of reach, a path through the table:
    nothing moved), :data:`STOPPED` or ``INTERRUPTED``. ``touch`` is ``kinova_gen2.touch_off``."""

    def __init__(self, arm, world, limits, touch, say, ask, **clock: Any) -> None:
        super().__init__(arm, world, limits, say, ask, **clock)
        self.touch = touch
        self.results: list[PointResult] = []
        self.passed = False

    def _move(self, stage: str, q: np.ndarray, clearance: float) -> np.ndarray:
        """One supervised position move to ``q`` at ``touch.speed_deg_s``, its joint-space path
        keeping the tip ``clearance`` m above the table top; the position reached (rad)."""
        q_now = self.arm.refresh_feedback().position
        lowest, where = path_clearance(self.world, q_now, q)
        if lowest < clearance - 1e-4:
            error = _Stop if self.outcome.moved else HomeRefusal
            raise error(f"{stage}: the path would bring the tip {lowest * 1e3:.1f} mm above the table at "
                        f"{where:.0%} of the way (at least {clearance * 1e3:.1f} mm here)")
        speed = self.touch.speed_deg_s
        alarm = np.minimum(self.world.robot.velocity_limit,
                           math.radians(speed)) * (1.0 + self.limits.velocity_tolerance)
        self.outcome.moved = True
        self.arm.move_to(q, speed)
        return self._watch(stage, alarm, q)

    def _run(self) -> tuple[int, str]:
        touch, world = self.touch, self.world
        q_now = self.arm.refresh_feedback().position
        # every posture planned (and refused if out of reach) before anything moves
        plans = []
        q_seed = q_now
        for xy in touch.points:
            above = solve_tip(world, tip_target(world, xy, touch.lift), q_seed, touch.step / 2)
            approach = solve_tip(world, tip_target(world, xy, touch.approach), above, touch.step / 2)
            plans.append((xy, above, approach))
            q_seed = above
        points = [list(map(float, xy)) for xy in touch.points]
        self.say(f"touch-off of Kinova arm {self.arm.serial}: the pusher tip to {len(plans)} table points "
                 f"(world m) {points}, at <= {touch.speed_deg_s:g} deg/s")
        self.say("  at each point, answer: Enter = one step down "
                 f"({touch.step * 1e3:g} mm), u = up, t = the tip touches the table, q = stop")
        self.say("  keep a hand on the e-stop; Ctrl-C stops the arm")
        if self.ask is not None:
            try:
                answer = self.ask(f"type the arm's serial ({self.arm.serial}) or '{TOUCH_WORD}' to start: ")
            except EOFError:
                answer = ""
            if answer.strip() not in (self.arm.serial, TOUCH_WORD):
                return NOT_CONFIRMED, "not confirmed: nothing moved"
        top = float(world.task.config.table.height)
        for i, (xy, above, approach) in enumerate(plans, start=1):
            start_height = world.tip_pose(self.arm.refresh_feedback().position)[0][2] - top
            self._move(f"point {i}: above", above, min(touch.lift, start_height) - 0.005)
            self._move(f"point {i}: approach", approach, touch.approach - touch.step)
            height, q = touch.approach, approach
            while True:
                prompt = (f"point {i}: the model's tip {height * 1e3:+.1f} mm above the table "
                          "[Enter down / u up / t touching / q stop]: ")
                try:
                    answer = "q" if self.ask is None else self.ask(prompt).strip().lower()
                except EOFError:
                    answer = "q"
                if answer == "t":
                    q_read = self.arm.refresh_feedback().position
                    error = float(world.tip_pose(q_read)[0][2] - top)
                    self.results.append(PointResult((float(xy[0]), float(xy[1])), q_read.tolist(), error))
                    self.say(f"  point {i}: touching, the model's tip {error * 1e3:+.2f} mm above its table")
                    break
                if answer == "q":
                    raise _Stop(f"point {i}: stopped by the user")
                if answer not in ("", "u"):
                    continue
                new = height + (touch.step if answer == "u" else -touch.step)
                if new < -touch.below - 1e-9:
                    raise _Stop(f"point {i}: {touch.below * 1e3:g} mm below the model's table top and "
                                "not touching: the tool, the mount or the table differ from the model "
                                "by more than that (docs/hardware.md, the tool)")
                q = solve_tip(world, tip_target(world, xy, new), q, touch.step / 2)
                self.outcome.moved = True
                speed = self.touch.speed_deg_s
                self.arm.move_to(q, speed)
                alarm = np.minimum(world.robot.velocity_limit, math.radians(speed)) * (
                    1.0 + self.limits.velocity_tolerance)
                self._watch(f"point {i}: jog", alarm, q)
                height = new
            self._move(f"point {i}: up", above, height - touch.step)
        errors = [r.error for r in self.results]
        worst = max(abs(e) for e in errors)
        self.passed = worst <= touch.max_error
        shown = ", ".join(f"{e * 1e3:+.2f}" for e in errors)
        if self.passed:
            return DONE, (f"passed: the tip's height above the model's table at the {len(errors)} points "
                          f"{shown} mm (max_error {touch.max_error * 1e3:g} mm)")
        return FAILED, (f"FAILED: the tip's height above the model's table at the {len(errors)} points "
                        f"{shown} mm, beyond max_error {touch.max_error * 1e3:g} mm: the tool, its mount "
                        "or the table is not where the policy's model has it (docs/hardware.md, the tool)")

    def record(self, path: Path) -> dict:
        """Write this touch-off's record to ``path`` (JSON; the folder made); returns it."""
        data = {"serial": self.arm.serial, "time": datetime.datetime.now(datetime.timezone.utc).isoformat(),
                "passed": self.passed, "status": self.outcome.status, "reason": self.outcome.reason,
                "max_error": self.touch.max_error,
                "points": [dataclasses.asdict(r) for r in self.results]}
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=1) + "\n")
        return data


def touch_off_refusal(record: Path, serial: str | None) -> str | None:
    """Why a deploy run on the arm ``serial`` is refused for want of a passing touch-off (one
    line), or None: the record at ``record`` must exist, name this arm and have passed."""
    if not record.is_file():
        return (f"no touch-off record at {record} (kinova_gen2.touch_off.record): run "
                "python -m ahrm_stack.deploy --backend kinova-gen2 --touch-off first (docs/hardware.md)")
    try:
        data = json.loads(record.read_text())
    except (OSError, ValueError) as error:
        return f"the touch-off record {record} cannot be read ({error}): run --touch-off again"
    if data.get("serial") != serial:
        return (f"the touch-off record {record} is of arm {data.get('serial')!r}, not {serial!r}: run "
                "--touch-off on this arm")
    if not data.get("passed"):
        return (f"the last touch-off of arm {serial} failed ({data.get('reason', '')}): fix the tool or "
                "the table, then --touch-off")
    return None


__all__ = ["BAD_INPUT", "DONE", "FAILED", "NOT_CONFIRMED", "STOPPED", "TouchOff", "solve_tip", "tip_target",
           "touch_off_refusal"]
