"""The evaluation suite in the experiment's report: per-family tables and bootstrap intervals.

Every run of the grid is evaluated on the same episodes of every suite family (each family has its
own seed range), so two methods are compared *paired*: seed s of method A against seed s of method
B, episode i of a family against the same episode i. The 95 % interval of a difference comes from a
two-level bootstrap: resample the seeds with replacement, then within each drawn seed the
(family, episode) pairs with replacement, and take the 2.5 and 97.5 percentiles of the resampled
mean difference.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Sequence

import numpy as np

Episodes = dict[str, dict[str, np.ndarray]]  # family -> column -> per-episode values


def read_suite(suite_dir: Path) -> Episodes | None:
    """Per-episode ``success``, ``touched`` and ``time_to_success`` of each family evaluated under
    ``suite_dir`` (``<family>/evaluation.csv``); None when the folder is missing."""
    suite_dir = Path(suite_dir)
    if not suite_dir.is_dir():
        return None
    families = {path.parent.name: read_episodes(path) for path in sorted(suite_dir.glob("*/evaluation.csv"))}
    return families or None


def read_support(suite_dir: Path) -> dict[str, str]:
    """Each family's training-support verdict under ``suite_dir`` (``<family>/evaluation.json``,
    computed when it was evaluated); families evaluated before it was computed are left out."""
    support = {}
    for path in sorted(Path(suite_dir).glob("*/evaluation.json")):
        verdict = json.loads(path.read_text()).get("training_support", {}).get("verdict")
        if verdict:
            support[path.parent.name] = verdict
    return support


def read_episodes(path: Path) -> dict[str, np.ndarray]:
    """Per-episode ``success``, ``touched`` and ``time`` (to success, nan without) of one
    ``evaluation.csv``."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    return {
        "success": np.array([r["success"] == "True" for r in rows], dtype=float),
        "touched": np.array([int(r["touched_steps"]) > 0 for r in rows], dtype=float),
        "time": np.array([float(r["time_to_success"]) if r["time_to_success"] not in ("", "None")
                          else np.nan for r in rows]),
    }


def _paired_units(a: Episodes, b: Episodes, families: Sequence[str], column: str) -> np.ndarray:
    """(units, 2) values of the same (family, episode) under a and b; for ``time`` only the
    episodes both succeeded in."""
    rows = []
    for family in families:
        if family not in a or family not in b:
            continue
        x, y = a[family][column], b[family][column]
        n = min(len(x), len(y))
        pair = np.stack([x[:n], y[:n]], axis=1)
        if column == "time":
            pair = pair[np.isfinite(pair).all(axis=1)]
        rows.append(pair)
    return np.concatenate(rows) if rows else np.empty((0, 2))


def paired_difference(a_seeds: Sequence[Episodes], b_seeds: Sequence[Episodes], families: Sequence[str],
                      column: str, samples: int, rng: np.random.Generator) -> tuple[float, float, float]:
    """Mean of (a - b) over seeds and (family, episode) units, and its bootstrap 95 % interval.

    ``a_seeds[s]`` and ``b_seeds[s]`` are the same seed's suites of the two methods. Returns
    (difference, low, high); nan when no pair exists."""
    per_seed = [_paired_units(a, b, families, column) for a, b in zip(a_seeds, b_seeds)]
    per_seed = [d[:, 0] - d[:, 1] for d in per_seed if len(d)]
    if not per_seed:
        return float("nan"), float("nan"), float("nan")
    point = float(np.mean(np.concatenate(per_seed)))
    stats = np.empty(samples)
    for k in range(samples):
        drawn = [per_seed[i] for i in rng.integers(len(per_seed), size=len(per_seed))]
        stats[k] = np.mean(np.concatenate([d[rng.integers(len(d), size=len(d))] for d in drawn]))
    low, high = np.percentile(stats, [2.5, 97.5])
    return point, float(low), float(high)


def family_means(seeds: Sequence[Episodes], family: str) -> dict[str, float]:
    """Mean over seeds of the family's successes and touching episodes (counts per evaluation) and
    of the mean time to success (over the successful episodes of each seed)."""
    present = [s[family] for s in seeds if s is not None and family in s]
    if not present:
        return {"successes": np.nan, "touched": np.nan, "time": np.nan, "episodes": 0}
    times = [np.nanmean(p["time"]) for p in present if np.isfinite(p["time"]).any()]
    return {"successes": float(np.mean([p["success"].sum() for p in present])),
            "touched": float(np.mean([p["touched"].sum() for p in present])),
            "time": float(np.mean(times)) if times else np.nan,
            "episodes": int(len(present[0]["success"]))}


def _fmt(value: float, digits: int = 1) -> str:
    return "–" if not np.isfinite(value) else f"{value:.{digits}f}"


def suite_section(columns: dict[str, list[Episodes]], families: Sequence[str], methods: Sequence[str],
                  samples: int, seed: int = 0, support: dict[str, str] | None = None) -> list[str]:
    """Markdown lines of the report's suite section.

    ``columns``: name -> per-seed suites, for every method and, when present, ``clone`` (the
    first method's warm start, before PPO) and ``scripted`` (one entry). ``methods`` are the
    compared ones (the first is the reference of the differences). ``support``: family -> its
    training-support verdict (:func:`read_support`), a column of the successes table."""
    names = [m for m in columns]
    shown = [n.upper() if n in methods else n for n in names]  # methods in capitals, as elsewhere
    lines = []
    for title, key, digits in (("Successes", "successes", 1), ("Episodes touching an obstacle", "touched", 1),
                               ("Time to success (s)", "time", 2)):
        with_support = support is not None and key == "successes"
        lines += [f"### {title} per family (mean over seeds)", "",
                  "| family | " + ("training support | " if with_support else "") + " | ".join(shown) + " |",
                  "|---|" + ("---|" if with_support else "") + "---|" * len(names)]
        total: dict[str, list] = {n: [] for n in names}
        for family in families:
            row = [family] + ([(support or {}).get(family, "–")] if with_support else [])
            for name in names:
                value = family_means(columns[name], family)[key]
                total[name].append(value)
                row.append(_fmt(value, digits))
            lines.append("| " + " | ".join(row) + " |")
        agg = [("sum" if key != "time" else "mean")] + [
            _fmt(np.nansum(total[n]) if key != "time" else np.nanmean(total[n]) if np.isfinite(total[n]).any()
                 else np.nan, digits) for n in names]
        lines += ["| **" + agg[0] + "** | " + ("| " if with_support else "") + " | ".join(agg[1:]) + " |", ""]
    rng = np.random.default_rng(seed)
    reference = methods[0]
    lines += [f"### Differences {reference.upper()} − other (paired, bootstrap 95 % interval over seeds "
              f"and episodes, {samples} resamples)", "",
              "| other | Δ success rate | Δ touching rate | Δ time to success (s, both succeeded) |",
              "|---|---|---|---|"]
    for other in [m for m in methods[1:]] + [n for n in ("clone", "scripted") if n in columns]:
        b = columns[other]
        if len(b) == 1 and len(columns[reference]) > 1:  # the scripted row pairs with every seed
            b = b * len(columns[reference])
        cells = []
        for column, scale, digits in (("success", 100, 1), ("touched", 100, 1), ("time", 1, 2)):
            d, lo, hi = paired_difference(columns[reference], b, families, column, samples, rng)
            unit = " pp" if scale == 100 else ""
            cells.append(f"{_fmt(d * scale, digits)}{unit} [{_fmt(lo * scale, digits)}, {_fmt(hi * scale, digits)}]")
        lines.append(f"| {other.upper() if other in methods else other} | " + " | ".join(cells) + " |")
    return lines + [""]


def rank(columns: dict[str, list[Episodes]], families: Sequence[str], methods: Sequence[str]) -> list[str]:
    """Methods ordered by mean suite success rate, then fewer touching episodes."""
    def key(method: str) -> tuple[float, float]:
        means = [family_means(columns[method], f) for f in families]
        return (-np.nansum([m["successes"] for m in means]), np.nansum([m["touched"] for m in means]))
    return sorted(methods, key=key)
