"""The project's seed ranges (``configs/seeds.yaml``), named once and checked to be disjoint.

Training environment i of a run is seeded ``train.seed + i * env_stride`` (one stream per
environment); demonstration episode i uses ``start(demonstrations) + i``. Every evaluation set (the
run's own layouts, ``run``, and each family of ``configs/layouts.yaml``) has two splits:
``validation`` (interim evaluations, checkpoint choice, studies, benchmarks) and ``test``; episode
i of a split uses its start + i. No two ranges overlap, so no evaluation replays a training or
demonstration layout and no validation episode is a test episode.

The test split is sealed: :func:`evaluation_range` is the one function that returns a test range,
and it refuses unless its caller is the final evaluation of a frozen policy
(:data:`FINAL_EVALUATION`: the evaluation library :mod:`ahrm_stack.evaluation`, which
``python -m ahrm_stack.evaluate RUN --split test`` and the experiment's final table call) and no
training runs in this process (:func:`sealed`, which ``ahrm_stack.learning.training.train`` holds for
its whole run).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import sys
from pathlib import Path
from typing import Annotated, Any, Iterator, Literal

from pydantic import PlainValidator

from ahrm_stack.config import CONFIG_DIR, ConfigError
from ahrm_stack.schema import Int, Section, Str, fail, ge, load_file

SEEDS_FILE = CONFIG_DIR / "seeds.yaml"

Split = Literal["validation", "test"]
SPLITS: tuple[Split, ...] = ("validation", "test")
RUN = "run"  # the evaluation set of a run's own layouts (evaluate RUN without --layout)
FINAL_EVALUATION = "ahrm_stack.evaluation"  # the one module that may read the test split


class SealedSplitError(ConfigError):
    """The test split was asked for outside the final evaluation of a frozen policy."""


@dataclasses.dataclass(frozen=True)
class SeedRange:
    name: str
    start: int
    size: int

    @property
    def stop(self) -> int:
        return self.start + self.size

    def seed(self, index: int) -> int:
        """The seed of episode ``index`` of this range; raises ConfigError past its end."""
        if not 0 <= index < self.size:
            raise ConfigError(f"seed range '{self.name}' holds {self.size} seeds; episode {index} is past it")
        return self.start + index

    def __contains__(self, seed: object) -> bool:
        return isinstance(seed, int) and self.start <= seed < self.stop


def _seed_range(value: Any) -> SeedRange:
    """``[start, size]`` (integers, start >= 0, size >= 1) -> a SeedRange (named by the table)."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        fail(f": expected [start, size], got {value!r}")
    for what, number, least in (("start", value[0], 0), ("size", value[1], 1)):
        if isinstance(number, bool) or not isinstance(number, int) or number < least:
            fail(f" {what} must be an integer >= {least}, got {number!r}")
    return SeedRange("", value[0], value[1])


RangeField = Annotated[SeedRange, PlainValidator(_seed_range)]  # [start, size] in YAML


@dataclasses.dataclass(frozen=True)
class SplitRanges(Section):
    """One evaluation set's seeds: its validation range and its sealed test range. Read the test
    range only through :func:`evaluation_range`."""

    validation: RangeField  # [start, size]: interim evaluations, checkpoint choice, studies
    test: RangeField  # [start, size]: the final evaluation of a frozen policy only


@dataclasses.dataclass(frozen=True)
class SeedTable(Section):
    """``configs/seeds.yaml``: the environment stride, training's ranges and the evaluation splits."""

    env_stride: Annotated[Int, ge(1)]  # training environment i is seeded train.seed + i * this
    ranges: dict[str, RangeField]  # name: [start, size]; training, demonstrations, ...
    evaluation: dict[str, SplitRanges]  # evaluation set (run, or a family): its two splits
    test_ledger: Str  # the test split's reads (ahrm_stack.test_ledger), relative to the repository

    def derive(self) -> None:
        object.__setattr__(self, "ranges", {name: dataclasses.replace(r, name=name)
                                            for name, r in self.ranges.items()})
        object.__setattr__(self, "evaluation", {
            name: SplitRanges(*(dataclasses.replace(getattr(s, split), name=f"{name} ({split})")
                                for split in SPLITS))
            for name, s in self.evaluation.items()})

    def check(self, key: str) -> None:
        for required in ("training", "demonstrations"):
            if required not in self.ranges:
                raise ConfigError(f"missing seed range 'ranges.{required}'")
        if RUN not in self.evaluation:
            raise ConfigError(f"missing evaluation seeds 'evaluation.{RUN}' (the run's own layouts)")
        ordered = sorted(self.every_range(), key=lambda r: r.start)
        for a, b in zip(ordered, ordered[1:]):
            if b.start < a.stop:
                raise ConfigError(f"seed ranges '{a.name}' [{a.start}, {a.stop}) and '{b.name}' "
                                  f"[{b.start}, {b.stop}) overlap")
        if ordered and ordered[-1].stop > 2**32:
            raise ConfigError("seed ranges must end below 2**32 (numpy's seed range)")

    def every_range(self) -> list[SeedRange]:
        """Every range of the file, both evaluation splits included: for the disjointness checks
        (and the tests that prove the test split is never drawn). Not a way to a test seed."""
        return list(self.ranges.values()) + [getattr(s, split) for s in self.evaluation.values()
                                             for split in SPLITS]

    def to_dict(self) -> dict:
        return {"env_stride": self.env_stride,
                "ranges": {name: [r.start, r.size] for name, r in self.ranges.items()},
                "evaluation": {name: {split: [getattr(s, split).start, getattr(s, split).size]
                                      for split in SPLITS} for name, s in self.evaluation.items()},
                "test_ledger": self.test_ledger}

    def __getitem__(self, name: str) -> SeedRange:
        """A range of ``ranges`` (training, demonstrations, ...); evaluation seeds come from
        :func:`evaluation_range`."""
        if name not in self.ranges:
            raise ConfigError(f"no seed range '{name}' in {SEEDS_FILE}; known: {sorted(self.ranges)}")
        return self.ranges[name]


def load_seed_table(path: Path | str = SEEDS_FILE) -> SeedTable:
    """Read and check the seed ranges: integer [start, size] pairs that do not overlap."""
    return load_file(SeedTable, path)


@functools.lru_cache(maxsize=1)
def seed_table() -> SeedTable:
    """The project's seed table (``configs/seeds.yaml``), read once."""
    return load_seed_table()


_training_runs = 0  # trainings running in this process (:func:`sealed`)


@contextlib.contextmanager
def sealed() -> Iterator[None]:
    """Held while a training runs: meanwhile :func:`evaluation_range` refuses the test split to
    every caller, the final-evaluation module included."""
    global _training_runs
    _training_runs += 1
    try:
        yield
    finally:
        _training_runs -= 1


def evaluation_range(name: str, split: Split = "validation") -> SeedRange:
    """The seeds of evaluation set ``name`` (:data:`RUN` or a family of ``configs/layouts.yaml``)
    in ``split``. The one way to a test range: ``split="test"`` is refused
    (:class:`SealedSplitError`) unless the caller is :data:`FINAL_EVALUATION` and no training runs
    in this process. An unknown set or split is a :class:`ConfigError` naming it."""
    table = seed_table()
    if name not in table.evaluation:
        raise ConfigError(f"no evaluation seeds for '{name}' in {SEEDS_FILE}: add "
                          f"'evaluation.{name}: {{validation: [start, size], test: [start, size]}}' "
                          "(disjoint from the other ranges)")
    if split == "validation":
        return table.evaluation[name].validation
    if split != "test":
        raise ConfigError(f"split must be one of {list(SPLITS)}, got {split!r}")
    frame_globals = sys._getframe(1).f_globals
    caller = frame_globals.get("__name__")
    spec = frame_globals.get("__spec__")
    if caller == "__main__" and spec is not None:  # a module run as __main__ (python -m): its own name
        caller = getattr(spec, "name", caller)
    if caller != FINAL_EVALUATION:
        raise SealedSplitError(f"the test split is sealed: only the final evaluation of a frozen policy "
                               f"(python -m ahrm_stack.evaluate RUN --split test) reads it, not {caller}")
    if _training_runs:
        raise SealedSplitError("the test split is sealed while a training runs in this process")
    return table.evaluation[name].test


def training_seeds(seed: int, num_envs: int) -> list[int]:
    """The stream seeds of a run's environments; ConfigError when they leave the training range."""
    table = seed_table()
    training = table["training"]
    if not 0 <= seed < table.env_stride:
        raise ConfigError(f"train.seed must be in [0, {table.env_stride}) (configs/seeds.yaml env_stride), got {seed}")
    seeds = [seed + i * table.env_stride for i in range(num_envs)]
    if seeds[-1] >= training.stop:
        raise ConfigError(f"train.num_envs ({num_envs}) × env_stride ({table.env_stride}) leaves the "
                          f"training seed range [{training.start}, {training.stop})")
    return seeds
