"""Whether an evaluation lies inside the training support, computed from two task configs.

The *training support* of a randomised quantity is the set training draws it from, read from the
run's task config; the evaluation's set is read from the evaluation's task config (the run's with
a family of ``configs/layouts.yaml`` applied, :func:`~ahrm_stack.env.layout_catalog.evaluation_task`).
Nothing is typed by hand: a family's row says what these two configs give. The quantities:

* ``cube``: the cube centre (x, y), m. Random layouts draw it in ``task.layout.cube_region``;
  fixed layouts put it at ``task.cube.position`` ± ``task.cube.jitter``.
* ``obstacles``: each obstacle's distance from the cube centre, m. Random layouts draw it in
  ``task.layout.radial_range`` at any bearing; a fixed layout's distances are those of its
  obstacles from every cube position of its jitter box. Against fixed training, only the same
  obstacles are inside.
* ``start``: the pusher tip at the episode's start (x, y, z), m: ``task.arm.start_region`` for
  random starts; the home posture (``start: home``) is inside only the same home posture.
* ``cube_mass``, ``cube_friction``: the factors on the cube's mass and sliding friction
  (``task.realism.cube_mass_scale`` / ``cube_friction_scale``; the nominal 1 where none is drawn).

Each quantity is ``inside`` (the evaluation's set lies in the training's), ``outside`` (no part of
it does: the sets share no interval of positive length) or ``partly outside``. A training
curriculum's extra starts (``train.start_curriculum``) are not counted: the support is the task's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, Sequence

import numpy as np

from ahrm_stack.config import TaskConfig

Status = Literal["inside", "partly outside", "outside"]
Interval = tuple[float, float]
TOLERANCE = 1e-9  # m or factor: bounds this close count as equal

QUANTITIES = ("cube", "obstacles", "start", "cube_mass", "cube_friction")


@dataclasses.dataclass(frozen=True)
class QuantitySupport:
    """One randomised quantity: where the evaluation draws it, where training did, and the verdict."""

    quantity: str  # one of QUANTITIES
    status: Status
    evaluation: str  # the evaluation's set, in words with units
    training: str  # the training's set, in words with units


def _interval_status(evaluation: Interval, training: Interval) -> Status:
    """``evaluation`` against ``training`` (closed intervals; a point is an interval of length 0)."""
    (a, b), (c, d) = evaluation, training
    if c - TOLERANCE <= a and b <= d + TOLERANCE:
        return "inside"
    if b - a <= TOLERANCE:  # a point outside
        return "outside"
    return "partly outside" if min(b, d) - max(a, c) > TOLERANCE else "outside"


def combine(statuses: Sequence[Status]) -> Status:
    """All inside: inside; any outside (every draw of the evaluation has it outside): outside;
    otherwise partly outside."""
    if all(s == "inside" for s in statuses):
        return "inside"
    return "outside" if "outside" in statuses else "partly outside"


def box_status(evaluation: Sequence[Interval], training: Sequence[Interval]) -> Status:
    """A box (one interval per axis) against another: per axis, then :func:`combine`."""
    return combine([_interval_status(e, t) for e, t in zip(evaluation, training)])


def _m(interval: Sequence[float]) -> str:
    """``[lo, hi]``, or the single value of a point."""
    lo, hi = (float(v) for v in interval)
    return f"{lo:.3g}" if hi - lo <= TOLERANCE else f"[{lo:.3g}, {hi:.3g}]"


def _box_words(box: Sequence[Interval], axes: str = "xyz") -> str:
    return ", ".join(f"{axis} {_m(r)}" for axis, r in zip(axes, box)) + " m"


def cube_box(task: TaskConfig) -> list[Interval]:
    """The cube centre's (x, y) ranges, m, under ``task``'s layout mode."""
    if task.layout.mode == "random":
        return [(float(lo), float(hi)) for lo, hi in task.layout.cube_region]
    jitter = float(task.cube.jitter)
    return [(float(p) - jitter, float(p) + jitter) for p in task.cube.position]


def _distance_range(point: np.ndarray, box: Sequence[Interval]) -> Interval:
    """The nearest and farthest distance (m) from ``point`` to the points of ``box`` (x, y)."""
    lo = np.array([r[0] for r in box])
    hi = np.array([r[1] for r in box])
    nearest = np.linalg.norm(np.clip(point, lo, hi) - point)
    farthest = np.linalg.norm(np.maximum(np.abs(point - lo), np.abs(point - hi)))
    return float(nearest), float(farthest)


def _cube(training: TaskConfig, evaluation: TaskConfig) -> QuantitySupport:
    e, t = cube_box(evaluation), cube_box(training)
    return QuantitySupport("cube", box_status(e, t), _box_words(e), _box_words(t))


def _obstacles(training: TaskConfig, evaluation: TaskConfig) -> QuantitySupport:
    if training.layout.mode == "fixed":
        t_words = f"the fixed layout {[list(map(float, xy)) for xy in training.obstacles.fixed_layout]} m"
        if evaluation.layout.mode == "random":
            return QuantitySupport("obstacles", "outside", f"random at {_m(evaluation.layout.radial_range)} m "
                                   "from the cube", t_words)
        same = np.allclose(np.sort(np.asarray(evaluation.obstacles.fixed_layout, float), axis=0),
                           np.sort(np.asarray(training.obstacles.fixed_layout, float), axis=0), atol=TOLERANCE)
        words = f"the fixed layout {[list(map(float, xy)) for xy in evaluation.obstacles.fixed_layout]} m"
        return QuantitySupport("obstacles", "inside" if same else "outside", words, t_words)
    radial = (float(training.layout.radial_range[0]), float(training.layout.radial_range[1]))
    t_words = f"{_m(radial)} m from the cube"
    if evaluation.layout.mode == "random":
        e_range = (float(evaluation.layout.radial_range[0]), float(evaluation.layout.radial_range[1]))
        return QuantitySupport("obstacles", _interval_status(e_range, radial), f"{_m(e_range)} m from the cube",
                               t_words)
    box = cube_box(evaluation)
    ranges = [_distance_range(np.asarray(xy, float), box) for xy in evaluation.obstacles.fixed_layout]
    words = ", ".join(_m(r) for r in ranges) + " m from the cube"
    return QuantitySupport("obstacles", combine([_interval_status(r, radial) for r in ranges]), words, t_words)


def _region(task: TaskConfig) -> list[Interval]:
    """The random start's tip region (x, y, z ranges), m."""
    return [(float(lo), float(hi)) for lo, hi in task.arm.start_region]


def _start(training: TaskConfig, evaluation: TaskConfig) -> QuantitySupport:
    def words(task: TaskConfig) -> str:
        if task.arm.start == "random":
            return "tip at " + _box_words(_region(task))
        return f"home posture {[round(math.degrees(q), 1) for q in task.arm.home]} deg ± {task.arm.joint_jitter} rad"
    if training.arm.start == "random" and evaluation.arm.start == "random":
        status = box_status(_region(evaluation), _region(training))
    elif training.arm.start == evaluation.arm.start == "home":
        same = np.allclose(training.arm.home, evaluation.arm.home) and \
            evaluation.arm.joint_jitter <= training.arm.joint_jitter + TOLERANCE
        status = "inside" if same else "outside"
    else:
        status = "outside"
    return QuantitySupport("start", status, words(evaluation), words(training))


def _scale(name: str, training: TaskConfig, evaluation: TaskConfig) -> QuantitySupport:
    field = f"{name}_scale"
    (e_lo, e_hi), (t_lo, t_hi) = getattr(evaluation.realism, field), getattr(training.realism, field)
    e, t = (float(e_lo), float(e_hi)), (float(t_lo), float(t_hi))
    return QuantitySupport(name, _interval_status(e, t), f"× {_m(e)}", f"× {_m(t)}")


def training_support(training: TaskConfig, evaluation: TaskConfig) -> list[QuantitySupport]:
    """Every quantity of :data:`QUANTITIES`: the evaluation's set against the training's."""
    return [_cube(training, evaluation), _obstacles(training, evaluation), _start(training, evaluation),
            _scale("cube_mass", training, evaluation), _scale("cube_friction", training, evaluation)]


def verdict(rows: Sequence[QuantitySupport]) -> str:
    """One cell: ``inside``, or the combined status and the quantities not inside, e.g.
    ``outside: cube`` or ``partly outside: obstacles``."""
    status = combine([r.status for r in rows])
    if status == "inside":
        return "inside"
    return f"{status}: " + ", ".join(r.quantity for r in rows if r.status != "inside")


def as_dict(rows: Sequence[QuantitySupport]) -> dict:
    """For JSON: ``{"verdict": ..., "inside": bool, "quantities": {name: {status, evaluation, training}}}``."""
    return {"verdict": verdict(rows), "inside": all(r.status == "inside" for r in rows),
            "quantities": {r.quantity: {"status": r.status, "evaluation": r.evaluation, "training": r.training}
                           for r in rows}}
