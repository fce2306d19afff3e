"""What every backend's ``--home`` shares (the Gen2's :mod:`ahrm_stack.hardware.kinova_gen2.home`,
the Kortex's :mod:`ahrm_stack.hardware.kortex.home`): the exit statuses, the outcome, the policy's
start posture as the target, the checks on it (joint ranges, the deploy loop's start check) and on
the joint-space path to it (the pusher tip's clearance above the table), and the typed
confirmation. The moves and their supervision are each backend's own."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Protocol

import numpy as np

from ahrm_stack.hardware.protocol import HardwareError

PATH_SAMPLES = 50  # points of the final move's joint-space path checked for clearance
CONFIRM_WORD = "home"

#: exit statuses of ``--home``
DONE, NOT_CONFIRMED, BAD_INPUT, STOPPED, INTERRUPTED = 0, 1, 2, 3, 130


class HomeRefusal(ValueError):
    """The homing target or its path is not acceptable; one line, nothing moved."""


class HomeStop(Exception):
    """A supervised stage ended badly; the arm is stopped (the message is why)."""


@dataclasses.dataclass
class HomeOutcome:
    """How a homing ended: ``status`` (:data:`DONE`, ...), ``reason`` (one line), ``moved``
    (a motion was commanded) and ``stages`` (what happened, in order)."""

    status: int
    reason: str
    moved: bool = False
    stages: list[str] = dataclasses.field(default_factory=list)


class TaskModel(Protocol):
    """What homing and the touch-off need of the task the policy was trained on (the deploy loop's
    :class:`~ahrm_stack.deploy.WorldModel`): its task (``task.config.arm.home``,
    ``task.config.table.height``), its robot description, the tip's forward kinematics and its IK."""

    task: Any

    @property
    def robot(self) -> Any: ...

    def tip_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def tip_ik(self, target: np.ndarray, q_init: np.ndarray) -> tuple[np.ndarray, float, float]: ...


@dataclasses.dataclass(frozen=True)
class Limits:
    """The deploy settings homing applies: ``home`` (the backend's home section:
    ``kinova_gen2.home``, ``kortex.home``), the velocity alarm (``watchdog.velocity_tolerance``,
    ``watchdog.velocity_alarm_ticks``) and the deploy loop's start check on a posture (rad -> why it
    is refused, or None: ``deploy.start_check.start_refusal`` with ``deploy.start_posture``'s
    tolerances)."""

    home: Any
    velocity_tolerance: float
    alarm_ticks: int
    start_refusal: Callable[[np.ndarray], "str | None"]


def wrap(delta: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped into [-pi, pi)."""
    return (np.asarray(delta, dtype=float) + math.pi) % (2 * math.pi) - math.pi


def start_target(world: TaskModel, q_now: np.ndarray) -> np.ndarray:
    """The policy's start posture (rad): ``task.arm.home_deg`` of the task the policy was trained
    on, each continuous joint the short way round from ``q_now`` (rad). Both start modes begin
    there: ``home`` jitters it, ``random`` runs its IK from it (it lies in ``task.arm.start_region``
    pointing down)."""
    home = np.asarray(world.task.config.arm.home, dtype=float)
    continuous = ~world.robot.limited
    return np.where(continuous, q_now + wrap(home - q_now), home)


def check_target(world: TaskModel, target: np.ndarray, limits: Limits) -> None:
    """:class:`HomeRefusal` (one line) unless ``target`` (rad) is inside every limited joint's range
    and passes the deploy loop's start check."""
    robot = world.robot
    outside = np.flatnonzero(robot.limited & ((target < robot.position_lower)
                                              | (target > robot.position_upper)))
    if outside.size:
        i = int(outside[0])
        raise HomeRefusal(f"task.arm.home_deg puts joint {i} ({robot.joint_names[i]}) at "
                          f"{math.degrees(target[i]):.1f} deg, outside its range "
                          f"[{math.degrees(robot.position_lower[i]):.1f}, "
                          f"{math.degrees(robot.position_upper[i]):.1f}]")
    refusal = limits.start_refusal(target)
    if refusal is not None:
        raise HomeRefusal(f"the homing target fails the deploy loop's start check: {refusal}")


def path_clearance(world: TaskModel, q_from: np.ndarray, q_to: np.ndarray,
                   samples: int = PATH_SAMPLES) -> tuple[float, float]:
    """The pusher tip's lowest height above the table top (m) along the straight joint-space line
    from ``q_from`` to ``q_to`` (rad), and where (0 start .. 1 end), at ``samples`` + 1 points."""
    top = float(world.task.config.table.height)
    lowest, where = math.inf, 0.0
    for s in np.linspace(0.0, 1.0, samples + 1):
        tip, _ = world.tip_pose(q_from + (q_to - q_from) * s)
        if tip[2] - top < lowest:
            lowest, where = float(tip[2] - top), float(s)
    return lowest, where


def path_deviation(q: np.ndarray, q_from: np.ndarray, q_to: np.ndarray) -> float:
    """How far (rad, the largest joint's) the posture ``q`` lies from the straight joint-space
    segment from ``q_from`` to ``q_to`` (all rad; the differences wrapped, so a continuous joint's
    reading a turn away counts as the same angle)."""
    step = np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float)
    offset = wrap(np.asarray(q, dtype=float) - q_from)
    length = float(step @ step)
    s = 0.0 if length == 0.0 else min(1.0, max(0.0, float(offset @ step) / length))
    return float(np.max(np.abs(wrap(offset - s * step))))


def confirmed(answer: str, serial: str) -> bool:
    """The user typed the arm's serial number (or name) or ``home`` (surrounding spaces ignored)."""
    return answer.strip() in (serial, CONFIRM_WORD)


def degrees_text(values: np.ndarray) -> str:
    """``(a, b, ...)`` with one decimal."""
    return "(" + ", ".join(f"{v:.1f}" for v in values) + ")"


def supervised(run: Callable[[], tuple[int, str]], stop: Callable[[], None]) -> tuple[int, str]:
    """``run()``'s (status, reason), or the status and reason of how it ended: a :class:`HomeStop`
    (stopped), a :class:`HomeRefusal` (bad input, nothing moved), a :class:`HardwareError` (a lost
    link, a timed-out or refused call: stopped) or a Ctrl-C / SIGTERM (interrupted). ``stop()`` runs
    on every exit path, success included (both backends' homing: Stop, then disconnect)."""
    try:
        return run()
    except HomeStop as reason:
        return STOPPED, f"stopped: {reason}"
    except HomeRefusal as refusal:
        return BAD_INPUT, f"refused: {refusal}"
    except HardwareError as error:
        return STOPPED, f"stopped: {(str(error).splitlines() or [''])[0]}"
    except KeyboardInterrupt:
        return INTERRUPTED, "stopped: interrupted (Ctrl-C or SIGTERM)"
    finally:
        stop()
