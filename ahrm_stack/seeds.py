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

from ahrm_stack.config import CONFIG_DIR, ConfigError, _read_yaml

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


@dataclasses.dataclass(frozen=True)
class SeedTable:
    env_stride: int
    ranges: dict[str, SeedRange]

    def __getitem__(self, name: str) -> SeedRange:
        if name not in self.ranges:
            raise ConfigError(f"no seed range '{name}' in {SEEDS_FILE}; known: {sorted(self.ranges)}")
        return self.ranges[name]


def _int(value, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where} must be an integer >= {minimum}, got {value!r}")
    return value


def load_seed_table(path: Path | str = SEEDS_FILE) -> SeedTable:
    """Read and check the seed ranges: integer [start, size] pairs that do not overlap."""
    path = Path(path)
    data = _read_yaml(path)
    unknown = sorted(set(data) - {"env_stride", "ranges"})
    if unknown:
        raise ConfigError(f"{path}: unknown key '{unknown[0]}'; allowed: ['env_stride', 'ranges']")
    stride = _int(data.get("env_stride"), f"{path}: env_stride", 1)
    ranges = {}
    for name, pair in (data.get("ranges") or {}).items():
        where = f"{path}: ranges.{name}"
        if not isinstance(pair, list) or len(pair) != 2:
            raise ConfigError(f"{where}: expected [start, size], got {pair!r}")
        ranges[name] = SeedRange(name, _int(pair[0], f"{where} start", 0), _int(pair[1], f"{where} size", 1))
    ordered = sorted(ranges.values(), key=lambda r: r.start)
    for a, b in zip(ordered, ordered[1:]):
        if b.start < a.stop:
            raise ConfigError(f"{path}: seed ranges '{a.name}' [{a.start}, {a.stop}) and '{b.name}' "
                              f"[{b.start}, {b.stop}) overlap")
    for required in ("training", "demonstrations", "evaluation"):
        if required not in ranges:
            raise ConfigError(f"{path}: missing seed range '{required}'")
    if ordered and ordered[-1].stop > 2**32:
        raise ConfigError(f"{path}: seed ranges must end below 2**32 (numpy's seed range)")
    return SeedTable(stride, ranges)


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
