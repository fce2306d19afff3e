"""The project's seed ranges (``configs/seeds.yaml``), named once and checked to be disjoint.

Training environment i of a run is seeded ``train.seed + i * env_stride`` (one stream per
environment); demonstration episode i uses ``start(demonstrations) + i``; evaluation episode i of a
family F of ``configs/layouts.yaml`` uses ``start(F) + i``, and the run's own final and interim
evaluations ``start(evaluation) + i``. No two ranges overlap, so no evaluation replays a training
or demonstration layout.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Annotated, Any

from pydantic import PlainValidator

from ahrm_stack.config import CONFIG_DIR, ConfigError
from ahrm_stack.schema import Int, Section, fail, ge, load_file

SEEDS_FILE = CONFIG_DIR / "seeds.yaml"


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


def _seed_range(value: Any) -> SeedRange:
    """``[start, size]`` (integers, start >= 0, size >= 1) -> a SeedRange (named by the table)."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        fail(f": expected [start, size], got {value!r}")
    for what, number, least in (("start", value[0], 0), ("size", value[1], 1)):
        if isinstance(number, bool) or not isinstance(number, int) or number < least:
            fail(f" {what} must be an integer >= {least}, got {number!r}")
    return SeedRange("", value[0], value[1])


@dataclasses.dataclass(frozen=True)
class SeedTable(Section):
    """``configs/seeds.yaml``: the environment stride and the named, disjoint ranges."""

    env_stride: Annotated[Int, ge(1)]  # training environment i is seeded train.seed + i * this
    ranges: dict[str, Annotated[SeedRange, PlainValidator(_seed_range)]]  # name: [start, size]

    def derive(self) -> None:
        object.__setattr__(self, "ranges", {name: dataclasses.replace(r, name=name)
                                            for name, r in self.ranges.items()})

    def check(self, key: str) -> None:
        ordered = sorted(self.ranges.values(), key=lambda r: r.start)
        for a, b in zip(ordered, ordered[1:]):
            if b.start < a.stop:
                raise ConfigError(f"seed ranges '{a.name}' [{a.start}, {a.stop}) and '{b.name}' "
                                  f"[{b.start}, {b.stop}) overlap")
        for required in ("training", "demonstrations", "evaluation"):
            if required not in self.ranges:
                raise ConfigError(f"missing seed range 'ranges.{required}'")
        if ordered and ordered[-1].stop > 2**32:
            raise ConfigError("seed ranges must end below 2**32 (numpy's seed range)")

    def to_dict(self) -> dict:
        return {"env_stride": self.env_stride,
                "ranges": {name: [r.start, r.size] for name, r in self.ranges.items()}}

    def __getitem__(self, name: str) -> SeedRange:
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
