"""Named evaluation layouts (``configs/layouts.yaml``): fixed layouts and held-out random families.

A named layout turns into config overrides of ``task`` (mode, fixed layout, cube position, cube
region, radial range, start region) and, for the evaluation only, the cube's mass and friction
factors (:func:`evaluation_task`); its evaluation episodes use its own seed ranges of
``configs/seeds.yaml`` (a validation and a sealed test range; episode i: the range's start + i).
The evaluation suite is every entry with ``suite: true``. Fixed layouts are checked with the task's
own placement rules (:func:`validate_layout`) when they are applied, so a bad entry fails with the
file, the name and the broken rule before any episode runs. Whether a family lies inside the
training support is computed (:mod:`ahrm_stack.env.support`), not written here.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal, Optional, Sequence

import numpy as np

from ahrm_stack.config import CONFIG_DIR, Config, ConfigError, Pair, TaskConfig, config_from_dict
from ahrm_stack.env.layout import Layout, LayoutError, validate_layout
from ahrm_stack.realism.config import Scale, nominal
from ahrm_stack.schema import Bool, Section, derived, ordered, read_yaml, validate
from ahrm_stack.seeds import evaluation_range

LAYOUTS_FILE = CONFIG_DIR / "layouts.yaml"


@dataclasses.dataclass(frozen=True)
class NamedLayout(Section):
    """One entry of ``configs/layouts.yaml`` (its name is the entry's key)."""

    mode: Literal["fixed", "random"]
    cube: Optional[Pair] = None  # fixed mode: nominal cube (x, y), m; None: the run's own
    obstacles: Optional[tuple[Pair, ...]] = None  # fixed mode: obstacle (x, y) centres, m; None: the run's
    radial_range: Annotated[Optional[Pair], ordered()] = None  # random mode, m; None: the run's own
    # random mode: cube x, y ranges, m; None: the run's own
    cube_region: Annotated[Optional[tuple[Pair, Pair]], ordered()] = None
    # the pusher tip's start (x, y, z ranges, m; task.arm.start becomes random); None: the run's own
    start_region: Annotated[Optional[tuple[Pair, Pair, Pair]], ordered()] = None
    # factor ranges on the cube's mass and sliding friction, drawn per episode (the evaluation is
    # otherwise the nominal task); None: the nominal cube (factor 1)
    cube_mass_scale: Annotated[Optional[Scale], ordered()] = None
    cube_friction_scale: Annotated[Optional[Scale], ordered()] = None
    suite: Bool = True  # part of the evaluation suite (evaluate --suite)
    name: str = derived()  # the entry's key

    def check(self, key: str) -> None:
        if self.mode == "random" and (self.cube is not None or self.obstacles is not None):
            raise ConfigError(f"{key}: cube/obstacles belong to fixed layouts only")
        for field in ("radial_range", "cube_region"):
            if self.mode == "fixed" and getattr(self, field) is not None:
                raise ConfigError(f"{key}: {field} belongs to random layouts only")

    @property
    def seed_offset(self) -> int:
        """Episode i of this family's validation split uses seed ``seed_offset + i`` (seeds.yaml);
        the test split only through ``python -m ahrm_stack.evaluate --split test``."""
        return evaluation_range(self.name, "validation").start


def load_layouts(path: Path | str = LAYOUTS_FILE) -> dict[str, NamedLayout]:
    """Every entry of the layouts file, shape-checked (placement is checked by :func:`apply_layout`);
    messages name the entry and key, e.g. ``unknown config key 'typo.cubes'``."""
    layouts = validate(dict[str, NamedLayout], read_yaml(path), "", path)
    return {name: dataclasses.replace(entry, name=name) for name, entry in layouts.items()}


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
    if entry.start_region is not None:
        task["arm"]["start"] = "random"
        task["arm"]["start_region"] = [list(r) for r in entry.start_region]
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
    entry.seed_offset  # a family without seed ranges fails here, before any episode
    return entry


def run_config_in_layout(run_dir: Path | str, name: str, overrides: Sequence[str] = (),
                         runnable: bool = True) -> tuple[Config, NamedLayout]:
    """The config of the run in ``run_dir`` (:func:`~ahrm_stack.run_config.load_run_config`, with
    ``overrides``) with the named layout applied (:func:`apply_layout`), and the layout's entry
    (its ``seed_offset``: the family's first evaluation seed)."""
    from ahrm_stack.run_config import load_run_config  # imports ahrm_stack.config, as this module does

    placed: list[NamedLayout] = []
    config = load_run_config(run_dir, overrides, runnable=runnable,
                             edit=lambda raw: placed.append(apply_layout(raw, name)))
    return config, placed[0]


def evaluation_task(task: TaskConfig, entry: NamedLayout | None = None) -> TaskConfig:
    """The task an evaluation runs: ``task`` (a layout already applied) without a real arm's
    imperfections (:func:`~ahrm_stack.realism.nominal`), but for the family ``entry``'s cube
    mass and friction factors when it sets them. The same for a policy and the scripted controller."""
    evaluated = nominal(task)
    changes = {name: getattr(entry, name) for name in ("cube_mass_scale", "cube_friction_scale")
               if entry is not None and getattr(entry, name) is not None}
    if not changes:
        return evaluated
    return dataclasses.replace(evaluated, realism=dataclasses.replace(evaluated.realism, **changes))


def suite_names(path: Path | str = LAYOUTS_FILE) -> list[str]:
    """The evaluation suite: the families of the layouts file with ``suite: true``, in file order."""
    return [name for name, entry in load_layouts(path).items() if entry.suite]
