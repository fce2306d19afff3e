"""Power analysis for the four-method comparison (issue 59, item 3), from experiment 42's variances.

    python studies/power_analysis.py   # writes docs/power-analysis/data.json and the tables of docs/power-analysis.md

Reads ``docs/reanalysis/data.json`` (studies/reanalysis.py: experiment 42's per-seed test success
shares and which runs learned). Learning is all-or-nothing in that experiment, so a run is
modelled as learning with probability q and, if it learned, winning a share with the learned
runs' spread. Three outcomes, three tests, each two-sided at alpha / 3 (Holm's first step over
the three comparisons with the reference, the worst case):

* **P(learn)**: Fisher's exact test on learned counts; power computed exactly (every pair of
  binomial outcomes weighted by its probability);
* **success among learned runs**: two-sample t on the learned runs' shares (noncentral t,
  the learned runs' pooled SD; the number of learned runs is n·q, taken at its expectation);
* **success over all runs, paired by seed** (the registered H1–H3 analysis): paired t with the
  SD of per-seed differences observed in experiment 42 (0.41–0.47, dominated by runs that did
  not learn).

Reported: seeds per method for 80 % power at the differences named in :data:`TARGETS`, and the
minimum detectable difference at 80 % power with the five seeds experiment 42 had.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs" / "reanalysis" / "data.json"
OUT = ROOT / "docs" / "power-analysis"
PAGE = ROOT / "docs" / "power-analysis.md"
BEGIN, END = "<!-- power tables begin -->", "<!-- power tables end -->"
ALPHA = 0.05 / 3  # two-sided, Holm's first step over three comparisons
POWER = 0.80
SEEDS = (5, 10, 15, 20, 25, 30, 35, 40, 50, 60, 80, 100)
# (outcome, a difference worth detecting): P(learn) 1.0 vs 0.8 and 0.9 vs 0.7; success among
# learned 5 and 10 percentage points; success over all runs 0.1 and 0.2 (paired by seed)
TARGETS = {"p_learn": [(1.0, 0.8), (0.9, 0.7)], "learned_success": [0.05, 0.10], "paired_success": [0.10, 0.20]}


def fisher_power(q1: float, q2: float, n: int, alpha: float = ALPHA) -> float:
    """Exact power of Fisher's two-sided test of k1 ~ Bin(n, q1) against k2 ~ Bin(n, q2)."""
    k = np.arange(n + 1)
    p1, p2 = stats.binom.pmf(k, n, q1), stats.binom.pmf(k, n, q2)
    power = 0.0
    for a in k:
        if p1[a] < 1e-12:
            continue
        for b in k:
            if p2[b] < 1e-12:
                continue
            if stats.fisher_exact([[a, n - a], [b, n - b]]).pvalue < alpha:
                power += p1[a] * p2[b]
    return float(power)


def t_power(delta: float, sd: float, n: int, paired: bool, alpha: float = ALPHA) -> float:
    """Power of a two-sided t test: paired (n pairs, SD of the differences) or two-sample (n per group)."""
    if n < 2:
        return 0.0
    df = n - 1 if paired else 2 * n - 2
    ncp = delta / (sd * np.sqrt(1 / n if paired else 2 / n))
    crit = stats.t.ppf(1 - alpha / 2, df)
    return float(1 - stats.nct.cdf(crit, df, ncp) + stats.nct.cdf(-crit, df, ncp))


def detectable(sd: float, n: int, paired: bool) -> float:
    """The smallest difference with 80 % power at n (bisection on t_power)."""
    low, high = 0.0, 5.0 * sd
    for _ in range(60):
        mid = (low + high) / 2
        low, high = (mid, high) if t_power(mid, sd, n, paired) < POWER else (low, mid)
    return high


def analyse(data: dict) -> dict:
    methods = data["methods"]
    learned = [s for m in methods.values() for i, s in enumerate(m["success_per_seed"]) if i in m["learned_seeds"]]
    learned_sd = float(np.std(learned, ddof=1))  # pooled over methods (their means differ by < 0.12)
    ref = np.array(methods[data["reference"]]["success_per_seed"])
    paired_sd = {m: float(np.std(ref - np.array(r["success_per_seed"]), ddof=1))
                 for m, r in methods.items() if m != data["reference"]}
    paired = max(paired_sd.values())
    q = sum(r["learned"] for r in methods.values()) / sum(r["runs"] for r in methods.values())
    out: dict = {"alpha": ALPHA, "power": POWER, "learned_sd": learned_sd, "paired_sd": paired_sd,
                 "p_learn_pooled": q, "rows": []}
    for q1, q2 in TARGETS["p_learn"]:
        curve = {n: fisher_power(q1, q2, n) for n in SEEDS}
        out["rows"].append({"outcome": f"P(learn) {q1:.1f} vs {q2:.1f}", "statistic": "Fisher exact",
                            "power_at": curve, "seeds": next((n for n in SEEDS if curve[n] >= POWER), None)})
    for delta in TARGETS["learned_success"]:
        # the learned runs per method: n * q at the pooled P(learn)
        curve = {n: t_power(delta, learned_sd, max(2, int(round(n * q))), False) for n in SEEDS}
        out["rows"].append({"outcome": f"success among learned runs, {100 * delta:.0f} pp", "statistic": "two-sample t",
                            "power_at": curve, "seeds": next((n for n in SEEDS if curve[n] >= POWER), None)})
    for delta in TARGETS["paired_success"]:
        curve = {n: t_power(delta, paired, n, True) for n in SEEDS}
        out["rows"].append({"outcome": f"success over all runs, {100 * delta:.0f} pp", "statistic": "paired t (H1–H3)",
                            "power_at": curve, "seeds": next((n for n in SEEDS if curve[n] >= POWER), None)})
    out["detectable_at_5"] = {"paired_success": detectable(paired, 5, True),
                              "learned_success": detectable(learned_sd, max(2, int(round(5 * q))), False)}
    return out


def tables(result: dict) -> str:
    lines = ["<!-- generated by studies/power_analysis.py; do not edit -->",
             f"Two-sided α = {result['alpha']:.4f} per comparison (0.05 / 3), power {result['power']:.0%}. "
             f"Experiment 42: SD of learned runs' success {result['learned_sd']:.3f}; SD of the per-seed "
             "differences from AHRM " + ", ".join(f"{m} {sd:.3f}" for m, sd in result["paired_sd"].items())
             + f" (the largest is used); pooled P(learn) {result['p_learn_pooled']:.2f}.",
             "",
             "| outcome, difference | statistic | " + " | ".join(f"n = {n}" for n in SEEDS)
             + " | seeds per method for 80 % |",
             "|---|---|" + "---|" * len(SEEDS) + "---|"]
    for row in result["rows"]:
        powers = " | ".join(f"{row['power_at'][n]:.2f}" for n in SEEDS)
        lines.append(f"| {row['outcome']} | {row['statistic']} | {powers} | {row['seeds'] or f'> {SEEDS[-1]}'} |")
    d = result["detectable_at_5"]
    lines += ["", f"With five seeds per method (experiment 42), the smallest difference with 80 % power: "
              f"success over all runs, paired by seed, {100 * d['paired_success']:.0f} percentage points; "
              f"success among learned runs {100 * d['learned_success']:.0f} percentage points."]
    return "\n".join(lines) + "\n"


def render(text: str, result: dict) -> str:
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[:start] + BEGIN + "\n" + tables(result) + END + text[end:]


def main() -> int:
    result = analyse(json.loads(DATA.read_text())["experiment"])
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "data.json").write_text(json.dumps(result, indent=1) + "\n")
    PAGE.write_text(render(PAGE.read_text(), result))
    print(tables(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
