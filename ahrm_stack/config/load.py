"""From the YAML files to a validated :class:`~ahrm_stack.config.root.Config`: the sections read,
profiles and ``key=value`` overrides applied, a run folder's older ``config.yaml`` brought to this
schema (:func:`fill_missing`), and messages that name where each value came from."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import yaml

from ahrm_stack.config.files import CONFIG_DIR, PROFILE_DIR, SECTIONS
from ahrm_stack.config.robots import compose_task
from ahrm_stack.config.root import Config
from ahrm_stack.realism import resolve_realism
from ahrm_stack.schema import (ConfigError, Source, apply_override, fill_legacy, override_keys, read_yaml, show_path,
                               source_note, validate)


def _flatten(mapping: dict, prefix: str = "") -> list[str]:
    """``{"ppo": {"epochs": 3}}`` -> ``["ppo.epochs=3"]`` (values written back as YAML)."""
    items = []
    for key, value in mapping.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            items += _flatten(value, f"{dotted}.")
        else:
            items.append(f"{dotted}={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}")
    return items


def profile_overrides(name: str, config_dir: Path | str = CONFIG_DIR, _seen: tuple[str, ...] = ()) -> list[str]:
    """The overrides of profile ``name`` (``configs/profiles/<name>.yaml``), as ``key=value``. A
    top-level ``profile: BASE`` in the file puts BASE's overrides first (the file's own win)."""
    folder = Path(config_dir) / PROFILE_DIR
    path = folder / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []
        raise ConfigError(f"profile={name}: no file {path}; known profiles: {known}")
    if name in _seen:
        raise ConfigError(f"profile={name}: its 'profile' key comes back to itself ({' -> '.join([*_seen, name])})")
    data = read_yaml(path)
    base = data.pop("profile", None)
    if base is None:
        return _flatten(data)
    if not isinstance(base, str):
        raise ConfigError(f"profile: must name a profile in {show_path(path)}, got {base!r}")
    return profile_overrides(base, config_dir, (*_seen, name)) + _flatten(data)


def apply_overrides(data: dict, overrides: Sequence[str], config_dir: Path | str = CONFIG_DIR) -> None:
    """Apply ``key=value`` overrides in order; ``profile=NAME`` applies that profile's overrides at
    its place in the list (so later overrides win over it)."""
    _resolve_realism(data)
    for override in overrides:
        if override.strip().startswith("profile="):
            name = override.split("=", 1)[1].strip()
            for item in profile_overrides(name, config_dir):
                try:
                    apply_override(data, item)
                except ConfigError as error:
                    path = show_path(Path(config_dir) / PROFILE_DIR / f"{name}.yaml")
                    raise ConfigError(f"{error} ({path})") from None
        else:
            apply_override(data, override)
        _resolve_realism(data)


def _resolve_realism(data: dict) -> None:
    """``task.realism`` given as a profile name (``configs/realism.yaml``) becomes its values, in
    place (so that the values are what a run folder records, and overrides of single values apply)."""
    task = data.get("task")
    if isinstance(task, dict) and isinstance(task.get("realism"), str):
        task["realism"] = resolve_realism(task["realism"], "task.realism")


def load_raw(config_dir: Path | str = CONFIG_DIR) -> dict:
    """The sections of ``config_dir`` as parsed, with the per-arm values composed from its arm
    registry (``robots/<name>.yaml``; :func:`~ahrm_stack.config.robots.compose_task`)."""
    config_dir = Path(config_dir)
    data = {section: read_yaml(config_dir / name) for section, name in SECTIONS.items()}
    compose_task(data, config_dir / "robots")
    return data


def config_source(config_dir: Path | str = CONFIG_DIR, overrides: Sequence[str] = (),
                  path: Path | str | None = None) -> Source:
    """Where a key's value came from, for messages: "override" for a key that ``overrides`` set
    (a profile's keys count as the profile's file), else ``path`` (a run's config.yaml) or the
    section's file under ``config_dir``."""
    changed, profiles = [], []
    for item in overrides:
        if item.strip().startswith("profile="):
            profiles.append(item.split("=", 1)[1].strip())
        else:
            changed += override_keys([item])

    def at(key: str, keys: list[str]) -> bool:  # key is one of keys or lies below one
        return any(key == k or key.startswith((f"{k}.", f"{k}[")) for k in keys)

    def note(key: str) -> str | None:
        if at(key, changed):
            return "override"
        for name in profiles:
            try:
                keys = override_keys(profile_overrides(name, config_dir))
            except ConfigError:
                continue
            if at(key, keys):
                return show_path(Path(config_dir) / PROFILE_DIR / f"{name}.yaml")
        section = key.split(".")[0].split("[")[0]
        if path is not None:
            where = show_path(path)
        elif section in SECTIONS:
            where = show_path(Path(config_dir) / SECTIONS[section])
        else:
            return None
        # a rule over several keys of a section (key: the section) that an override took part in
        return f"{where} with overrides" if any(at(k, [key]) for k in changed) else where
    return note


def load_config(overrides: Sequence[str] = (), config_dir: Path | str = CONFIG_DIR) -> Config:
    """Read ``configs/*.yaml``, apply ``overrides`` (``profile=NAME`` among them) and validate."""
    data = load_raw(config_dir)
    apply_overrides(data, overrides, config_dir)
    return config_from_dict(data, source=config_source(config_dir, overrides))


#: The version of the run-folder layout of ``config.yaml`` that this code writes (the file's
#: top-level ``schema_version``; a file without one is version 0, written before it was recorded).
#: Adding a key does not change it (a file that lacks the key takes the field's legacy marker);
#: renaming or removing one does, with a step in :func:`fill_missing` that converts older files.
SCHEMA_VERSION = 1


def fill_missing(data: Any) -> Any:
    """A run folder's parsed ``config.yaml`` brought to this schema: its ``schema_version`` checked
    and dropped, every missing key with a :func:`~ahrm_stack.schema.legacy` marker filled with the
    value that run had before the key existed (so it keeps its behaviour, and overrides of the new
    keys apply to it), and a ``task.realism`` profile name resolved. ``data`` itself is not changed;
    anything but a dict is returned as it is, for the schema to name. Raises :class:`ConfigError`
    for a ``schema_version`` this code does not know."""
    if not isinstance(data, dict):
        return data
    if "schema_version" in data:
        version = data["schema_version"]
        if isinstance(version, bool) or not isinstance(version, int) or not 0 <= version <= SCHEMA_VERSION:
            raise ConfigError(f"schema_version: {version!r} is not a version this code reads (0 to "
                              f"{SCHEMA_VERSION}; a newer ahrm_stack wrote it?)")
        data = {key: value for key, value in data.items() if key != "schema_version"}
    data = fill_legacy(Config, data)
    task = data.get("task")
    if isinstance(task, dict) and isinstance(task.get("realism"), str):
        data = {**data, "task": {**task, "realism": resolve_realism(task["realism"], "task.realism")}}
    return data


def config_from_dict(data: dict, runnable: bool = True, source: Source | None = None) -> Config:
    """Validate a parsed configuration (the sections of ``configs/`` or a run folder's
    ``config.yaml``: its ``schema_version`` read, keys added since it was written filled by
    :func:`fill_missing`) into a :class:`Config`.

    ``runnable``: also refuse combinations that cannot run (deploy reads a checkpoint's config,
    whose safety settings it replaces, with False). ``source`` (see :func:`config_source`) names
    the file in messages. ``config_from_dict(config.to_dict()) == config``.
    """
    try:
        data = fill_missing(data)
    except ConfigError as error:
        raise ConfigError(f"{error}{source_note(source, 'schema_version')}") from None
    config = validate(Config, data, "", source)
    if runnable and config.task.action.smoothing > 0 and (
            config.train.warm_start != "none" or config.ppo.bc_coeff > 0 or config.train.dagger_rounds > 0):
        raise ConfigError(f"task.action.smoothing: {config.task.action.smoothing} needs train.warm_start: "
                          "none, ppo.bc_coeff: 0 and train.dagger_rounds: 0 (the scripted "
                          "demonstrations' labels are unsmoothed actions)")
    if runnable and config.task.action.mode == "cartesian" and not config.safety.enabled:
        # a rule for running the task, not for reading a run's file: deploy reads a checkpoint's
        # config (and replaces its safety settings with its own) with runnable=False
        raise ConfigError("safety.enabled: false needs task.action.mode: joint (cartesian "
                          "actions are turned into joint velocities by the safety filter)")
    return config
