"""Named evaluation layouts (``configs/layouts.yaml``): fixed layouts and held-out random families.

A named layout turns into config overrides of ``task`` (mode, fixed layout, cube position, cube
region, radial range); its evaluation episodes use its own seed range of ``configs/seeds.yaml``
(episode i: the range's start + i). The evaluation suite is every entry with ``suite: true``. Fixed layouts are checked with the task's
own placement rules (:func:`validate_layout`) when they are applied, so a bad entry fails with the
file, the name and the broken rule before any episode runs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ahrm_stack.config import CONFIG_DIR, ConfigError, _read_yaml, config_from_dict
from ahrm_stack.env.layout import Layout, LayoutError, validate_layout
from ahrm_stack.seeds import SEEDS_FILE, seed_table

LAYOUTS_FILE = CONFIG_DIR / "layouts.yaml"
_KEYS = {"mode", "cube", "obstacles", "radial_range", "cube_region", "suite"}


@dataclasses.dataclass(frozen=True)
class NamedLayout:
    name: str
    mode: str  # fixed | random
    cube: tuple[float, float] | None  # nominal cube (x, y), m; None: the run's own
    obstacles: tuple[tuple[float, float], ...] | None  # obstacle (x, y) centres, m; None: the run's
    radial_range: tuple[float, float] | None  # random mode, m; None: the run's own
    cube_region: tuple[tuple[float, float], tuple[float, float]] | None  # random mode: cube x, y
    # ranges, m; None: the run's own
    suite: bool  # part of the evaluation suite (evaluate --suite)

    @property
    def seed_offset(self) -> int:
        """Episode i of this family uses seed ``seed_offset + i`` (its range in seeds.yaml)."""
        table = seed_table()
        if self.name not in table.ranges:
            raise ConfigError(f"layout '{self.name}' has no seed range in {SEEDS_FILE}; add one "
                              "(disjoint from the others)")
        return table.ranges[self.name].start


def _pairs(value, where: str, count: int | None = None) -> tuple:
    array = np.asarray(value, dtype=float) if isinstance(value, list) else None
    if array is None or array.ndim != 2 or array.shape[1] != 2 or not np.isfinite(array).all():
        raise ConfigError(f"{where}: expected a list of [x, y] pairs in m, got {value!r}")
    return tuple(tuple(map(float, row)) for row in array)


def _pair(value, where: str) -> tuple[float, float]:
    return _pairs([value] if isinstance(value, list) else value, where)[0]


def load_layouts(path: Path | str = LAYOUTS_FILE) -> dict[str, NamedLayout]:
    """Every entry of the layouts file, shape-checked (placement is checked by :func:`apply_layout`)."""
    path = Path(path)
    layouts = {}
    for name, entry in _read_yaml(path).items():
        where = f"{path}: layout '{name}'"
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: expected a mapping with keys {sorted(_KEYS)}")
        unknown = sorted(set(entry) - _KEYS)
        if unknown:
            raise ConfigError(f"{where}: unknown key '{unknown[0]}'; allowed keys: {sorted(_KEYS)}")
        mode = entry.get("mode")
        if mode not in ("fixed", "random"):
            raise ConfigError(f"{where}: mode must be fixed or random, got {mode!r}")
        if mode == "random" and ("cube" in entry or "obstacles" in entry):
            raise ConfigError(f"{where}: cube/obstacles belong to fixed layouts only")
        for key in ("radial_range", "cube_region"):
            if mode == "fixed" and key in entry:
                raise ConfigError(f"{where}: {key} belongs to random layouts only")
        suite = entry.get("suite", True)
        if not isinstance(suite, bool):
            raise ConfigError(f"{where}.suite: expected true/false, got {suite!r}")
        region = None
        if "cube_region" in entry:
            region = _pairs(entry["cube_region"], f"{where}.cube_region")
            if len(region) != 2 or any(lo > hi for lo, hi in region):
                raise ConfigError(f"{where}.cube_region: expected [[x_lo, x_hi], [y_lo, y_hi]] with "
                                  f"lo <= hi, got {entry['cube_region']!r}")
        layouts[name] = NamedLayout(
            name=name, mode=mode,
            cube=_pair(entry["cube"], f"{where}.cube") if "cube" in entry else None,
            obstacles=_pairs(entry["obstacles"], f"{where}.obstacles") if "obstacles" in entry else None,
            radial_range=_pair(entry["radial_range"], f"{where}.radial_range") if "radial_range" in entry else None,
            cube_region=region, suite=suite)
    return layouts


def apply_layout(raw: dict, name: str, path: Path | str = LAYOUTS_FILE) -> NamedLayout:
    """Apply the named layout to a raw config dict in place (``task`` section) and check it.

    Raises :class:`ConfigError` naming the file and the layout: an unknown name (with the known
    ones), a different number of obstacles than the run's, or a fixed layout that breaks the
    placement rules of ``task.layout``.
    """
    layouts = load_layouts(path)
    if name not in layouts:
        raise ConfigError(f"--layout {name!r} is not in {path}; known layouts: {sorted(layouts)}")
    entry = layouts[name]
    task = raw["task"]
    task["layout"]["mode"] = entry.mode
    if entry.obstacles is not None:
        count = len(task["obstacles"]["fixed_layout"])
        if len(entry.obstacles) != count:
            raise ConfigError(f"{path}: layout '{name}' has {len(entry.obstacles)} obstacles; the run "
                              f"has {count} (the observation depends on the number)")
        task["obstacles"]["fixed_layout"] = [list(xy) for xy in entry.obstacles]
    if entry.cube is not None:
        task["cube"]["position"] = list(entry.cube)
    if entry.radial_range is not None:
        task["layout"]["radial_range"] = list(entry.radial_range)
    if entry.cube_region is not None:
        task["layout"]["cube_region"] = [list(r) for r in entry.cube_region]
    try:
        config = config_from_dict(raw).task
    except ConfigError as error:
        raise ConfigError(f"{path}: layout '{name}': {error}") from None
    try:
        if entry.mode == "fixed":
            fixed = Layout(np.asarray(config.cube.position, float),
                           np.asarray(config.obstacles.fixed_layout, float))
            validate_layout(fixed, config.table, config.cube, config.obstacles, config.layout)
        else:
            from ahrm_stack.env.layout import LayoutSampler
            LayoutSampler(config.table, config.cube, config.obstacles, config.layout)
    except LayoutError as error:
        raise ConfigError(f"{path}: layout '{name}': {error}") from None
    entry.seed_offset  # a family without a seed range fails here, before any episode
    return entry


def suite_names(path: Path | str = LAYOUTS_FILE) -> list[str]:
    """The evaluation suite: the families of the layouts file with ``suite: true``, in file order."""
    return [name for name, entry in load_layouts(path).items() if entry.suite]
