"""Experiment 42 as a reviewer reads an RL comparison (issue 59, item 4): learning curves with seed
bands, interquartile means, performance profiles and the probability of improvement, each with
stratified bootstrap intervals from the ``rliable`` library (Agarwal et al., NeurIPS 2021).

    python studies/rliable_report.py   # docs/reanalysis/rliable.json, the figures, docs/rliable.md's tables

Reads committed data only (``docs/experiment-42/data/runs/<method>-seed<k>``): each run's interim
evaluations (``evaluations.csv``: 40 validation episodes at every 200k frames) and its one test
evaluation (``eval/evaluation.csv``: 200 test episodes, the same for every run). A run's score is its
share of episodes won (or touched); rliable resamples the runs of each method (its stratified
bootstrap over runs, one task; :data:`REPS` samples, seeded). With five runs per method these
intervals are wide and the percentile bootstrap is optimistic at this size (rliable's own caveat is
for fewer than ~5 runs): read them as the spread of five runs, not a test. The exact tests for the
rare events (a run that never learned, touching episodes) are docs/reanalysis.md's.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "docs" / "experiment-42" / "data" / "runs"
OUT = ROOT / "docs" / "reanalysis"
PAGE = ROOT / "docs" / "rliable.md"
METHODS = ("ahrm", "mhrm", "fhrm", "ls")
REFERENCE = "ahrm"
SEEDS = range(5)
REPS = 2000  # bootstrap samples per estimate
SEED = 20261207
TAUS = np.linspace(0.0, 1.0, 41)  # performance profile thresholds (test success share)
BEGIN, END = "<!-- rliable tables begin -->", "<!-- rliable tables end -->"


def _read(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def load(runs: Path = RUNS) -> dict:
    """Per method: ``curve`` (runs × interim evaluations, success share), ``frames`` (the mean
    frames of each evaluation), ``success`` and ``touching`` (runs, test shares)."""
    out: dict = {}
    for method in METHODS:
        curves, frames, success, touching = [], [], [], []
        for seed in SEEDS:
            run = runs / f"{method}-seed{seed}"
            rows = _read(run / "evaluations.csv")
            curves.append([int(r["successes"]) / int(r["episodes"]) for r in rows])
            frames.append([int(r["frames"]) for r in rows])
            test = _read(run / "eval" / "evaluation.csv")
            success.append(np.mean([r["success"] == "True" for r in test]))
            touching.append(np.mean([int(r["touched_steps"]) > 0 for r in test]))
        length = min(len(c) for c in curves)
        out[method] = {"curve": np.array([c[:length] for c in curves]),
                       "frames": np.array([f[:length] for f in frames]).mean(axis=0),
                       "success": np.array(success), "touching": np.array(touching)}
    return out


def _interval(scores: dict[str, np.ndarray], func, reps: int = REPS) -> tuple[dict, dict]:
    import warnings

    from rliable import library as rly

    # rliable 1.2 passes random_state to arch, which warns that it will take a generator instead;
    # and its StratifiedBootstrap draws the runs from NumPy's global generator (update_indices), not
    # from random_state: so that one is seeded here too, and restored afterwards
    state = np.random.get_state()
    np.random.seed(SEED)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
            return rly.get_interval_estimates(scores, func, reps=reps,
                                              random_state=np.random.RandomState(SEED))
    finally:
        np.random.set_state(state)


def analyse(data: dict) -> dict:
    """The estimates (point and 95 % interval), as plain lists for the JSON file."""
    from rliable import metrics

    def aggregates(x: np.ndarray) -> np.ndarray:  # (rliable's median is across tasks: one task here)
        return np.array([metrics.aggregate_iqm(x), metrics.aggregate_mean(x)])

    result: dict = {"reps": REPS, "seed": SEED, "methods": list(METHODS)}
    for key in ("success", "touching"):
        point, ci = _interval({m: data[m][key][:, None] for m in METHODS}, aggregates)
        result[key] = {m: {"runs": data[m][key].round(4).tolist(),
                           "iqm": float(point[m][0]), "iqm_ci": ci[m][:, 0].tolist(),
                           "mean": float(point[m][1]), "mean_ci": ci[m][:, 1].tolist()}
                       for m in METHODS}
    pairs = {f"{REFERENCE}>{m}": (data[REFERENCE]["success"][:, None], data[m]["success"][:, None])
             for m in METHODS if m != REFERENCE}
    point, ci = _interval(pairs, metrics.probability_of_improvement)
    result["improvement"] = {k: {"p": float(point[k]), "ci": np.ravel(ci[k]).tolist()} for k in pairs}
    curves = {}
    for m in METHODS:
        curve = data[m]["curve"]
        iqm, low, high = [], [], []
        for t in range(curve.shape[1]):
            p, c = _interval({m: curve[:, t:t + 1]}, metrics.aggregate_iqm, reps=REPS // 4)
            iqm.append(float(p[m]))
            low.append(float(np.ravel(c[m])[0]))
            high.append(float(np.ravel(c[m])[1]))
        curves[m] = {"frames": data[m]["frames"].tolist(), "iqm": iqm, "low": low, "high": high,
                     "runs": curve.round(4).tolist()}
    result["curves"] = curves
    from rliable import library as rly

    state = np.random.get_state()
    np.random.seed(SEED)  # (its bootstrap draws from the global generator, as above)
    try:
        profiles, profile_ci = rly.create_performance_profile(
            {m: data[m]["success"][:, None] for m in METHODS}, TAUS, reps=REPS)
    finally:
        np.random.set_state(state)
    result["profile"] = {m: {"taus": TAUS.tolist(), "share": profiles[m].tolist(),
                             "low": profile_ci[m][0].tolist(), "high": profile_ci[m][1].tolist()}
                         for m in METHODS}
    return result


def figures(result: dict, out: Path = OUT) -> None:
    """Learning curves (IQM of the interim validation success, bootstrap band, and every run thin)
    and the test performance profile, as PNG under ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    colours = dict(zip(METHODS, ("C0", "C1", "C2", "C3")))
    fig, ax = plt.subplots(figsize=(7, 4))
    for m in METHODS:
        c = result["curves"][m]
        frames = np.array(c["frames"]) / 1e6
        ax.plot(frames, c["iqm"], color=colours[m], label=m.upper())
        ax.fill_between(frames, c["low"], c["high"], color=colours[m], alpha=0.15)
        for run in c["runs"]:
            ax.plot(frames, run, color=colours[m], alpha=0.25, linewidth=0.6)
    ax.set_xlabel("frames (millions)")
    ax.set_ylabel("validation success (IQM over 5 runs)")
    ax.set_ylim(-0.02, 1.02)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "learning-curves.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    for m in METHODS:
        p = result["profile"][m]
        ax.plot(p["taus"], p["share"], color=colours[m], label=m.upper())
        ax.fill_between(p["taus"], p["low"], p["high"], color=colours[m], alpha=0.15)
    ax.set_xlabel("test success share τ")
    ax.set_ylabel("share of runs with success > τ")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "performance-profile.png", dpi=110)
    plt.close(fig)


def _ci(low_high: list[float]) -> str:
    return f"[{low_high[0]:.3f}, {low_high[1]:.3f}]"


def tables(result: dict) -> str:
    """The markdown tables of ``result``."""
    lines = [f"Stratified bootstrap over runs (rliable `get_interval_estimates`, {result['reps']} samples, "
             f"seed {result['seed']}); 95 % percentile intervals. Test split: 200 episodes per run.", ""]
    for key, title in (("success", "test success share"), ("touching", "test touching share (lower is better)")):
        lines += [f"**{title}**", "", "| method | runs (seeds 0–4) | IQM | mean |", "|---|---|---|---|"]
        for m in result["methods"]:
            r = result[key][m]
            runs = ", ".join(f"{v:.3f}" for v in r["runs"])
            lines.append(f"| {m.upper()} | {runs} | {r['iqm']:.3f} {_ci(r['iqm_ci'])} | "
                         f"{r['mean']:.3f} {_ci(r['mean_ci'])} |")
        lines.append("")
    lines += ["**Probability of improvement** (test success; P(a run of the first method beats a run of "
              "the second), ties counted half)", "", "| pair | P | 95 % interval |", "|---|---|---|"]
    for pair, value in result["improvement"].items():
        first, second = pair.split(">")
        lines.append(f"| {first.upper()} > {second.upper()} | {value['p']:.3f} | {_ci(value['ci'])} |")
    lines += ["", "**Validation learning curves** (IQM of the five runs' success share at each interim "
              "evaluation, 95 % interval; figure below)", "",
              "| frames (M) | " + " | ".join(m.upper() for m in result["methods"]) + " |",
              "|---|" + "---|" * len(result["methods"])]
    first = result["curves"][result["methods"][0]]
    for t, frames in enumerate(first["frames"]):
        cells = []
        for m in result["methods"]:
            c = result["curves"][m]
            cells.append(f"{c['iqm'][t]:.2f} [{c['low'][t]:.2f}, {c['high'][t]:.2f}]" if t < len(c["iqm"]) else "—")
        lines.append(f"| {frames / 1e6:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def render(text: str, result: dict) -> str:
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[:start] + BEGIN + "\n" + tables(result) + END + text[end:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python studies/rliable_report.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-figures", action="store_true", help="the tables and the JSON only")
    args = parser.parse_args(argv)
    result = analyse(load())
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "rliable.json").write_text(json.dumps(result, indent=1) + "\n")
    if not args.no_figures:
        figures(result)
    PAGE.write_text(render(PAGE.read_text(), result))
    print(f"wrote {OUT / 'rliable.json'} and the tables of {PAGE}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
