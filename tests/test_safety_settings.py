"""Deploy's safety settings against a checkpoint's, key by key, from the schema: every key of
``SafetyConfig`` carries a ``stricter(...)`` marker, and :func:`merge_safety` follows it — a
checkpoint's stricter value wins, a weaker one is ignored with a note, a key without an order keeps
deploy's value, a vector of another length is ignored. Fast (no simulator)."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from ahrm_stack.config import SafetyConfig, load_config
from ahrm_stack.deploy import DeployConfigError, merge_safety, safety_directions
from ahrm_stack.schema import DIRECTIONS, Stricter, keys_of, markers, stricter


@pytest.fixture(scope="module")
def ours() -> SafetyConfig:
    return load_config().safety


def test_every_safety_key_has_a_direction_that_fits_its_type(ours):
    found = markers(SafetyConfig, Stricter)
    assert sorted(found) == keys_of(SafetyConfig)
    unmarked = [key for key, mark in found.items() if mark is None]
    assert not unmarked, f"safety keys without a stricter(...) marker in ahrm_stack/config/safety.py: {unmarked}"
    for key, direction in safety_directions().items():
        value = getattr(ours, key)
        assert direction in DIRECTIONS, key
        if direction == "on":
            assert isinstance(value, bool), key
        elif direction in ("higher", "lower"):
            entries = value if isinstance(value, tuple) else (value,)
            assert all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in entries), key


def test_an_unmarked_safety_key_is_refused_not_merged(monkeypatch):
    @dataclasses.dataclass(frozen=True)
    class Unmarked(SafetyConfig):
        brand_new_rows: bool = True  # a key added without its marker

    monkeypatch.setattr("ahrm_stack.deploy.safety_settings.SafetyConfig", Unmarked)
    with pytest.raises(TypeError, match=r"^safety.brand_new_rows has no stricter\(...\) marker"):
        safety_directions()
    with pytest.raises(ValueError, match="stricter"):
        stricter("tighter")  # type: ignore[arg-type]


def _step(value: Any, sign: int) -> Any:
    """``value`` moved by ``sign`` (+1 up, -1 down): 1 for an integer, 0.01 for a float, entry by
    entry for a vector."""
    if isinstance(value, tuple):
        return tuple(_step(v, sign) for v in value)
    return value + sign * (1 if isinstance(value, int) else 0.01)


def _other(value: Any) -> Any:
    """A different value of the same kind, for a key without an order."""
    if isinstance(value, str):
        return "osqp" if value != "osqp" else "daqp"
    if isinstance(value, dict):  # e.g. the self-collision pairs per arm: one pair fewer for the first arm
        first = next(iter(value))
        return {**value, first: value[first][:-1]}
    return _step(value, +1)


def _cases(ours: SafetyConfig) -> list[tuple[str, str, Any, Any]]:
    """Per key: (key, direction, the checkpoint's stricter value, its weaker value) around
    deploy's value (None: no stricter value, for a key without an order)."""
    cases = []
    for key, direction in safety_directions().items():
        value = getattr(ours, key)
        if direction == "on":
            cases.append((key, direction, True, False))
        elif direction == "higher":
            cases.append((key, direction, _step(value, +1), _step(value, -1)))
        elif direction == "lower":
            cases.append((key, direction, _step(value, -1), _step(value, +1)))
        else:
            cases.append((key, direction, None, _other(value)))
    return cases


def test_a_stricter_checkpoint_value_wins_for_every_safety_key(ours):
    for key, direction, strict, _ in _cases(ours):
        if strict is None:
            continue
        deploy = dataclasses.replace(ours, **{key: False}) if direction == "on" else ours
        if key == "enabled":  # deploy never runs without its filter, whatever the checkpoint says
            with pytest.raises(DeployConfigError, match="safety.enabled"):
                merge_safety(deploy, dataclasses.replace(deploy, enabled=True))
            continue
        merged, notes = merge_safety(deploy, dataclasses.replace(deploy, **{key: strict}))
        assert getattr(merged, key) == strict, key
        assert merged == dataclasses.replace(deploy, **{key: strict}), key  # nothing else moves
        assert [(n.key, n.kind) for n in notes] == [(key, "stricter")], key
        assert notes[0].text.startswith(f"safety.{key}: the checkpoint's ") and "stricter" in notes[0].text


def test_a_weaker_checkpoint_value_is_ignored_with_a_note_for_every_safety_key(ours):
    for key, direction, _, weak in _cases(ours):
        deploy = dataclasses.replace(ours, **{key: True}) if direction == "on" else ours
        merged, notes = merge_safety(deploy, dataclasses.replace(deploy, **{key: weak}))
        assert merged == deploy, key
        kind = "other" if direction == "none" else "weaker"
        assert [(n.key, n.kind) for n in notes] == [(key, kind)], key
        kept = getattr(deploy, key)
        shown = repr(list(kept)) if isinstance(kept, tuple) else repr(kept)
        said = "(not a safety bound): using" if kind == "other" else "ignored, using"
        assert notes[0].text.startswith(f"safety.{key}: the checkpoint's "), key
        assert notes[0].text.endswith(f"{said} {shown}"), (key, notes[0].text)


def test_a_checkpoint_with_self_collision_rows_turns_them_on(ours):
    """The issue's case: rows on in training, off in deploy's settings -> on (the stricter)."""
    deploy = dataclasses.replace(ours, self_collision_rows=False)
    merged, notes = merge_safety(deploy, dataclasses.replace(deploy, self_collision_rows=True))
    assert merged.self_collision_rows is True
    assert [(n.key, n.kind) for n in notes] == [("self_collision_rows", "stricter")]
    assert notes[0].text == ("safety.self_collision_rows: the checkpoint's True is stricter than "
                             "deploy's False: using True")


@pytest.mark.parametrize("key", ["acceleration_limit", "workspace_lower", "workspace_upper"])
@pytest.mark.parametrize("change", [+1, -1])
def test_a_checkpoint_vector_of_another_length_is_ignored(ours, key, change):
    value = getattr(ours, key)
    direction = safety_directions()[key]
    strict = _step(value, +1 if direction == "higher" else -1)  # stricter in every entry ...
    theirs = strict + (strict[-1],) if change > 0 else strict[:-1]  # ... but another length
    merged, notes = merge_safety(ours, dataclasses.replace(ours, **{key: theirs}))
    assert merged == ours
    assert [(n.key, n.kind) for n in notes] == [(key, "weaker")]
    assert f"has {len(theirs)} entries, deploy's {len(value)}: ignored" in notes[0].text


def test_a_vector_stricter_in_some_entries_and_weaker_in_others_takes_the_stricter_per_entry(ours):
    """acceleration_limit is 'lower': entry 0 lowered (stricter, taken), entry 1 raised (weaker,
    ignored), the rest equal."""
    theirs = (ours.acceleration_limit[0] - 1.0, ours.acceleration_limit[1] + 1.0) + ours.acceleration_limit[2:]
    merged, notes = merge_safety(ours, dataclasses.replace(ours, acceleration_limit=theirs))
    expected = (theirs[0],) + ours.acceleration_limit[1:]
    assert merged == dataclasses.replace(ours, acceleration_limit=expected)
    assert [(n.key, n.kind) for n in notes] == [("acceleration_limit", "weaker")]
    assert notes[0].text == (f"safety.acceleration_limit: the checkpoint's {list(theirs)} is weaker than "
                             f"deploy's {list(ours.acceleration_limit)} in entries [1] (ignored there) and "
                             f"stricter in entries [0]: using {list(expected)}")


@pytest.mark.parametrize("where", [0, -1])
def test_a_checkpoint_vector_with_a_non_finite_entry_is_ignored_whole(ours, where):
    strict = [v - 1.0 for v in ours.acceleration_limit]  # stricter in every finite entry ...
    strict[where] = float("nan")  # ... but one entry is not a number
    merged, notes = merge_safety(ours, dataclasses.replace(ours, acceleration_limit=tuple(strict)))
    assert merged == ours
    assert [(n.key, n.kind) for n in notes] == [("acceleration_limit", "weaker")]
    assert notes[0].text.endswith(f"is not finite: ignored, using {list(ours.acceleration_limit)}")


def test_a_safety_note_cannot_be_changed():
    _, [note] = merge_safety(load_config().safety, dataclasses.replace(load_config().safety, table_margin=1.0))
    with pytest.raises(dataclasses.FrozenInstanceError):
        note.kind = "stricter"  # type: ignore[misc]


def test_tightened_workspace_boxes_must_still_overlap(ours):
    """Deploy's box x in [-0.8, 0.8]; a checkpoint box whose x range ends at -0.8 (an empty
    overlap, lo == hi) or before it is refused; one that ends just after -0.8 is kept."""
    for end in (-0.8, -0.9):
        upper = (end,) + ours.workspace_upper[1:]
        with pytest.raises(DeployConfigError, match=rf"do not overlap on axis 0 \(\[-0\.8, {end}\] after"):
            merge_safety(ours, dataclasses.replace(ours, workspace_upper=upper))
    upper = (-0.79,) + ours.workspace_upper[1:]
    merged, _ = merge_safety(ours, dataclasses.replace(ours, workspace_upper=upper))
    assert merged.workspace_upper == upper


def test_the_activation_distance_must_stay_above_the_safe_distance_after_tightening(ours):
    """obstacle_safe_distance is 'higher' (a larger distance is stricter): a checkpoint's safe
    distance equal to deploy's activation distance is refused, just below it is kept."""
    activation = ours.obstacle_activation_distance
    with pytest.raises(DeployConfigError, match=r"^safety\.obstacle_activation_distance .* must exceed"):
        merge_safety(ours, dataclasses.replace(ours, obstacle_safe_distance=activation))
    merged, _ = merge_safety(ours, dataclasses.replace(ours, obstacle_safe_distance=activation - 1e-3))
    assert merged.obstacle_safe_distance == activation - 1e-3
