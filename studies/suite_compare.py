"""Paired comparison of two policies on the evaluation suite's episodes, over seeds.

    python studies/suite_compare.py A_SEED0 A_SEED1 ... -- B_SEED0 B_SEED1 ...

Each argument is a suite folder written by ``python -m ahrm_stack.evaluate RUN --suite --out DIR``
(one ``<family>/evaluation.csv`` per family of ``configs/layouts.yaml``'s suite). The i-th folder of
A is paired with the i-th of B (same seed), and within a pair episode j of a family with episode j
(the suite's episodes are the same layouts and starts for every policy). Prints B − A per seed
pair, summed over the suite: successes, episodes touching an obstacle, and the mean time to success
over the episodes both won (s), each with a bootstrap 95 % interval that resamples seeds, then
episodes within each seed (``--samples``, seeded).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np


def load_suite(folder: Path, families: list[str]) -> np.ndarray:
    """Rows (success, touched, time to success) of every episode, families in ``families`` order."""
    rows = []
    for family in families:
        path = folder / family / "evaluation.csv"
        if not path.is_file():
            raise SystemExit(f"error: {path} not found: not a suite folder of the same families")
        with path.open() as handle:
            for row in csv.DictReader(handle):
                rows.append((row["success"] == "True", int(row["touched_steps"]) > 0,
                             float(row["time_to_success"])))
    return np.array(rows, dtype=float)


def differences(pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float, float]:
    """B − A per seed pair: successes and touching episodes (summed over a suite, averaged over the
    pairs) and the mean time to success over the episodes both won."""
    a = np.concatenate([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    per_pair = len(a) / len(pairs)
    both = (a[:, 0] > 0) & (b[:, 0] > 0)
    time = float((b[both, 2] - a[both, 2]).mean()) if both.any() else float("nan")
    return (float((b[:, 0] - a[:, 0]).mean() * per_pair), float((b[:, 1] - a[:, 1]).mean() * per_pair), time)


def bootstrap(a: list[np.ndarray], b: list[np.ndarray], samples: int, seed: int = 0) -> np.ndarray:
    """``samples`` resampled :func:`differences` (seeds, then episodes within each seed)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(samples):
        pairs = []
        for s in rng.integers(0, len(a), len(a)):
            index = rng.integers(0, len(a[s]), len(a[s]))
            pairs.append((a[s][index], b[s][index]))
        out.append(differences(pairs))
    return np.array(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        raise SystemExit("usage: suite_compare.py A... -- B... [--samples N]")
    split = argv.index("--")
    parser = argparse.ArgumentParser()
    parser.add_argument("b", nargs="+")
    parser.add_argument("--samples", type=int, default=2000)
    rest = parser.parse_args(argv[split + 1:])
    a_dirs, b_dirs = [Path(p) for p in argv[:split]], [Path(p) for p in rest.b]
    if len(a_dirs) != len(b_dirs) or not a_dirs:
        raise SystemExit(f"error: {len(a_dirs)} A folders against {len(b_dirs)} B folders: pair them by seed")
    families = sorted(p.name for p in a_dirs[0].iterdir() if (p / "evaluation.csv").is_file())
    a = [load_suite(d, families) for d in a_dirs]
    b = [load_suite(d, families) for d in b_dirs]
    for x, y, name in zip(a, b, b_dirs):
        if x.shape != y.shape:
            raise SystemExit(f"error: {name} has {len(y)} episodes, its pair {len(x)}")
    point = differences(list(zip(a, b)))
    low, high = np.percentile(bootstrap(a, b, rest.samples), [2.5, 97.5], axis=0)
    names = ("successes per suite", "touching episodes per suite", "time to success (s, both won)")
    for name, p, lo, hi in zip(names, point, low, high):
        print(f"B - A {name}: {p:+.2f} [{lo:+.2f}, {hi:+.2f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
