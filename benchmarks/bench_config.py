"""Configuration cost: reading configs/ and validating it, writing it back, and attribute access.

* ``load_config()``: the seven YAML files read (libyaml when built), overrides applied, validated
  (pydantic, ahrm_stack/schema.py) and checked (the cross-key rules);
* ``config_from_dict(raw)``: validation and checks alone, on an already parsed mapping;
* ``config.to_dict()`` and reading it back (a run folder's config.yaml);
* ``config.ppo.learning_rate`` against the same access on a plain frozen dataclass (ratio ~1: the
  sections are plain dataclasses after loading; nothing is validated on access).

Prints medians and ratios. Usage: python benchmarks/bench_config.py [--repeats N]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

from ahrm_stack.config import config_from_dict, load_config, load_raw


def _median(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


@dataclasses.dataclass(frozen=True)
class _Plain:
    learning_rate: float


@dataclasses.dataclass(frozen=True)
class _Outer:
    ppo: _Plain


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--quick", action="store_true", help="3 repeats, 20,000 attribute reads")
    args = parser.parse_args()
    if args.quick:
        args.repeats = 3
    start = time.perf_counter()
    config = load_config()  # first call: builds the validators once, imports what checks use
    first = time.perf_counter() - start
    raw = load_raw()
    load = _median(load_config, args.repeats)
    validate = _median(lambda: config_from_dict(raw), args.repeats)
    written = config.to_dict()
    write = _median(config.to_dict, args.repeats)
    back = _median(lambda: config_from_dict(written), args.repeats)
    assert config_from_dict(written) == config
    plain = _Outer(_Plain(config.ppo.learning_rate))
    n = 20_000 if args.quick else 200_000

    def access(obj):
        def run():
            for _ in range(n):
                obj.ppo.learning_rate  # noqa: B018 - the attribute access is what is timed
        return run
    ours, theirs = _median(access(config), 5) / n, _median(access(plain), 5) / n
    print(f"first load_config: {first * 1e3:.0f} ms (once per process)")
    print(f"load_config: {load * 1e3:.2f} ms; config_from_dict: {validate * 1e3:.2f} ms; "
          f"to_dict: {write * 1e3:.3f} ms; read back: {back * 1e3:.2f} ms")
    print(f"config.ppo.learning_rate: {ours * 1e9:.0f} ns vs plain dataclass {theirs * 1e9:.0f} ns "
          f"(ratio config/plain attribute access {ours / theirs:.2f})")


if __name__ == "__main__":
    main()
