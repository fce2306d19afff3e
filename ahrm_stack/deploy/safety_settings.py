"""The safety filter's settings in deployment: deploy's own (``configs/safety.yaml``); a
checkpoint's ``safety`` section may only tighten them (:func:`merge_safety`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from ahrm_stack.deploy.settings import DeployConfigError

#: Safety settings with a stricter direction, and which direction that is. A checkpoint's value
#: is used where it is stricter (per entry for vectors); where it is weaker it is ignored.
HIGHER_IS_STRICTER = ("position_margin", "velocity_margin", "table_margin", "wrist_table_margin",
                      "obstacle_safe_distance", "obstacle_activation_distance",
                      "max_obstacle_rows", "workspace_lower")
LOWER_IS_STRICTER = ("acceleration_limit", "workspace_upper")
ON_IS_STRICTER = ("enabled", "braking_horizon", "table_rows", "workspace_rows",
                  "table_distance_rows", "obstacle_rows")
# Every other key (solver, osqp_eps, osqp_max_iter, cartesian_regularization,
# cartesian_orientation_weight, and any key added later) is no bound: deploy's value is used.


@dataclasses.dataclass(frozen=True)
class SafetyNote:
    """One difference between deploy's and a checkpoint's safety setting ``key``: ``kind`` is
    ``stricter`` (the checkpoint's value, or its stricter entries, used), ``weaker`` (ignored)
    or ``other`` (no stricter direction: deploy's value used); ``text`` is the printed line."""

    key: str
    kind: str
    text: str


def _show(value: Any) -> str:
    return repr(list(value)) if isinstance(value, tuple) else repr(value)


def require_filter(safety) -> None:
    """:class:`DeployConfigError` unless ``safety`` (a SafetyConfig) turns the filter on."""
    if not safety.enabled:
        raise DeployConfigError("safety.enabled is false: the deploy loop never runs without the "
                                "safety filter")


def merge_safety(deploy, checkpoint) -> tuple[Any, list[SafetyNote]]:
    """The safety settings a checkpoint run is deployed with: ``deploy``'s (configs/safety.yaml as
    deploy reads it), tightened wherever ``checkpoint`` (the run's ``config.yaml``) is stricter;
    a weaker checkpoint value is ignored. Both are :class:`~ahrm_stack.config.SafetyConfig`.

    Returns the merged settings and one :class:`SafetyNote` per differing key. Raises
    :class:`DeployConfigError` when deploy's own settings turn the filter off, or when the
    tightened settings contradict each other (an empty workspace box, an activation distance not
    above the safe distance)."""
    require_filter(deploy)
    merged, notes = {}, []
    for field in dataclasses.fields(deploy):
        key, ours, theirs = field.name, getattr(deploy, field.name), getattr(checkpoint, field.name)
        if ours == theirs:
            continue
        name = f"safety.{key}"
        said = f"{name}: the checkpoint's {_show(theirs)}"
        if key in ON_IS_STRICTER:
            if theirs:
                merged[key] = True
                notes.append(SafetyNote(key, "stricter", f"{said} is stricter than deploy's "
                                        f"{_show(ours)}: using {_show(theirs)}"))
            else:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)}: ignored, using {_show(ours)}"))
        elif key in HIGHER_IS_STRICTER or key in LOWER_IS_STRICTER:
            pick = max if key in HIGHER_IS_STRICTER else min
            vector = isinstance(ours, tuple)
            a, b = (ours, theirs) if vector else ((ours,), (theirs,))
            if len(a) != len(b):
                notes.append(SafetyNote(key, "weaker", f"{said} has {len(b)} entries, deploy's "
                                        f"{len(a)}: ignored, using {_show(ours)}"))
                continue
            if not all(math.isfinite(y) for y in b):
                notes.append(SafetyNote(key, "weaker", f"{said} is not finite: ignored, using "
                                        f"{_show(ours)}"))
                continue
            best = tuple(pick(x, y) for x, y in zip(a, b))
            value = best if vector else best[0]
            weaker = [i for i, (x, y) in enumerate(zip(a, b)) if pick(x, y) == x != y]
            stricter = [i for i, (x, y) in enumerate(zip(a, b)) if pick(x, y) == y != x]
            if value != ours:
                merged[key] = value
            if weaker and stricter:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)} in entries {weaker} (ignored there) and "
                                        f"stricter in entries {stricter}: using {_show(value)}"))
            elif weaker:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)}: ignored, using {_show(ours)}"))
            else:
                notes.append(SafetyNote(key, "stricter", f"{said} is stricter than deploy's "
                                        f"{_show(ours)}: using {_show(value)}"))
        else:
            notes.append(SafetyNote(key, "other", f"{said} differs from deploy's {_show(ours)} "
                                    f"(not a safety bound): using {_show(ours)}"))
    result = dataclasses.replace(deploy, **merged)
    for i, (lo, hi) in enumerate(zip(result.workspace_lower, result.workspace_upper)):
        if not lo < hi:
            raise DeployConfigError(f"safety.workspace_lower/workspace_upper: deploy's workspace "
                                    f"box and the checkpoint's do not overlap on axis {i} "
                                    f"([{lo}, {hi}] after tightening)")
    if result.obstacle_activation_distance <= result.obstacle_safe_distance:
        raise DeployConfigError(
            f"safety.obstacle_activation_distance {result.obstacle_activation_distance} must "
            f"exceed safety.obstacle_safe_distance {result.obstacle_safe_distance} after taking "
            "the checkpoint's stricter values")
    return result, notes
