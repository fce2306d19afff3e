"""The safety filter's settings in deployment: deploy's own (``configs/safety.yaml``); a
checkpoint's ``safety`` section may only tighten them (:func:`merge_safety`).

Which value of a key is the stricter is not kept here: it is the ``stricter(...)`` marker on the
key's field of :class:`~ahrm_stack.config.SafetyConfig` (``on``, ``higher``, ``lower`` or ``none``),
read by :func:`safety_directions`; a key without one is refused, so a key added later cannot
silently become "not a safety bound"."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from ahrm_stack.config import SafetyConfig
from ahrm_stack.deploy.settings import DeployConfigError
from ahrm_stack.schema import Stricter, markers


def safety_directions() -> dict[str, str]:
    """Each key of :class:`~ahrm_stack.config.SafetyConfig` -> its stricter direction (``on``,
    ``higher``, ``lower``, ``none``), from the fields' :func:`~ahrm_stack.schema.stricter`
    markers. Raises ``TypeError`` naming a key that has none (a programming error)."""
    found = markers(SafetyConfig, Stricter)
    for key, mark in found.items():
        if mark is None:
            raise TypeError(f"safety.{key} has no stricter(...) marker in ahrm_stack/config/safety.py "
                            "(SafetyConfig): say which of two values is the stricter")
    return {key: mark.direction for key, mark in found.items()}


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


def merge_safety(deploy: SafetyConfig, checkpoint: SafetyConfig) -> tuple[SafetyConfig, list[SafetyNote]]:
    """The safety settings a checkpoint run is deployed with: ``deploy``'s (configs/safety.yaml as
    deploy reads it), tightened wherever ``checkpoint`` (the run's ``config.yaml``) is stricter in
    its key's direction (:func:`safety_directions`; per entry for a vector); a weaker checkpoint
    value, a non-finite one or a vector of another length is ignored; a key without an order
    (``none``) takes deploy's value.

    Returns the merged settings and one :class:`SafetyNote` per differing key. Raises
    :class:`DeployConfigError` when deploy's own settings turn the filter off, or when the
    tightened settings contradict each other (an empty workspace box, an activation distance not
    above the safe distance)."""
    require_filter(deploy)
    merged, notes = {}, []
    for key, direction in safety_directions().items():
        ours, theirs = getattr(deploy, key), getattr(checkpoint, key)
        if isinstance(ours, dict) and isinstance(theirs, dict):  # per arm (self_collision_pairs): an
            theirs = type(ours)({**ours, **theirs})  # arm registered after the checkpoint is no difference
        if ours == theirs:
            continue
        name = f"safety.{key}"
        said = f"{name}: the checkpoint's {_show(theirs)}"
        if direction == "on":
            if theirs:
                merged[key] = True
                notes.append(SafetyNote(key, "stricter", f"{said} is stricter than deploy's "
                                        f"{_show(ours)}: using {_show(theirs)}"))
            else:
                notes.append(SafetyNote(key, "weaker", f"{said} is weaker than deploy's "
                                        f"{_show(ours)}: ignored, using {_show(ours)}"))
        elif direction in ("higher", "lower"):
            pick = max if direction == "higher" else min
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
        else:  # "none": no order between two values
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
