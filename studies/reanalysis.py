"""Re-analysis of what exists (issue 59, item 1): experiment 42 as P(a run learns) and success among
learned runs, and the default policy against its teacher with the test episode as the unit.

    python studies/reanalysis.py   # writes docs/reanalysis/data.json and the tables of docs/reanalysis.md

Reads committed data only (no episode is run, no test seed drawn):

* ``docs/experiment-42/data``: per run ``eval/evaluation.csv`` (its 200 test episodes of the
  ``random`` set; the same 200 episodes for every run and for ``scripted/evaluation.csv``);
* ``docs/policies/ahrm-default-seed{0..4}/suite-test/<family>/evaluation.csv`` and its
  ``scripted/evaluation.csv`` (the default policies' one test read of the suite, 20 families × 40
  episodes, and the scripted controller on the same episodes).

**Experiment 42.** A run *learned* when it won at least :data:`LEARNED_SHARE` of its test episodes.
The runs' shares are bimodal (the lowest learned run won 107/200, the highest other 2/200): any
threshold between 1.5 % and 53 % sorts them alike, which the tables show. Reported per method:
P(learn) with its exact 95 % interval and Fisher's exact test against the reference; success and
touching among learned runs at two levels: *seed level* (each learned run's share, mean and Welch's
t against the reference's learned runs) and *episode level* (each test episode's mean over the
method's learned runs, paired by episode against the reference's: the mean difference with a
two-way bootstrap interval that resamples both the episodes and the learned runs, and the exact
sign test on the episodes whose means differ). Pooled figures over all 200 × seeds episodes treat
episodes shared by seeds as independent draws; they are not used here.

**The default policy against its teacher.** Every test episode of the suite (800) is one unit: the
policy's mean success (and touching) over its five seeds against the scripted controller's one
outcome; the mean difference with an episode-bootstrap interval (seeds resampled too), and the
exact sign test on the episodes where they differ (the policy's mean above or below the teacher's).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "docs" / "experiment-42" / "data"
POLICIES = ROOT / "docs" / "policies"
DEFAULT_SEEDS = range(5)
LEARNED_SHARE = 0.10  # a run learned when it won >= this share of its test episodes
REFERENCE = "ahrm"
METHODS = ("ahrm", "mhrm", "fhrm", "ls")
BOOTSTRAP = 4000  # two-way bootstrap samples
BOOTSTRAP_SEED = 20261207
PAGE = ROOT / "docs" / "reanalysis.md"
BEGIN, END = "<!-- reanalysis tables begin -->", "<!-- reanalysis tables end -->"


def _columns(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(success, touched, time to success) per episode of an ``evaluation.csv``: 0/1 arrays and s
    (NaN where not won), in episode order."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    won = np.array([r["success"] == "True" for r in rows], dtype=float)
    return (won, np.array([int(r["touched_steps"]) > 0 for r in rows], dtype=float),
            np.array([float(r["time_to_success"]) if w else np.nan for r, w in zip(rows, won)]))


def _episodes(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(success, touched) per episode of an ``evaluation.csv``, as 0/1 arrays in episode order."""
    return _columns(path)[:2]


def _exact_interval(k: int, n: int) -> list[float]:
    """Clopper-Pearson 95 % interval of k successes in n."""
    ci = stats.binomtest(k, n).proportion_ci(0.95, method="exact")
    return [float(ci.low), float(ci.high)]


def _sign_test(a: np.ndarray, b: np.ndarray) -> dict:
    """Exact two-sided sign test on paired values: episodes where a > b against a < b."""
    above, below = int(np.sum(a > b)), int(np.sum(a < b))
    p = 1.0 if above + below == 0 else float(stats.binomtest(above, above + below).pvalue)
    return {"above": above, "below": below, "p": p}


def _two_way_bootstrap(a: np.ndarray, b: np.ndarray | None, rng: np.random.Generator) -> list[float]:
    """95 % interval of mean(a) - mean(b) where a (and b) are [runs, episodes] arrays on the same
    episodes: each sample resamples the episodes (shared by both) and each side's runs."""
    n = a.shape[1]
    out = np.empty(BOOTSTRAP)
    for i in range(BOOTSTRAP):
        episodes = rng.integers(0, n, n)
        ra = a[rng.integers(0, a.shape[0], a.shape[0])][:, episodes].mean()
        rb = 0.0 if b is None else b[rng.integers(0, b.shape[0], b.shape[0])][:, episodes].mean()
        out[i] = ra - rb
    return [float(np.quantile(out, 0.025)), float(np.quantile(out, 0.975))]


def experiment(data: Path = EXPERIMENT) -> dict:
    runs = {m: [_episodes(data / "runs" / f"{m}-seed{s}" / "eval" / "evaluation.csv") for s in range(5)]
            for m in METHODS}
    shares = {m: [float(s.mean()) for s, _ in runs[m]] for m in METHODS}
    learned_runs = {m: [i for i, share in enumerate(shares[m]) if share >= LEARNED_SHARE] for m in METHODS}
    every = sorted(x for m in METHODS for x in shares[m])
    gap = [max(x for x in every if x < LEARNED_SHARE), min(x for x in every if x >= LEARNED_SHARE)]
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    ref = learned_runs[REFERENCE]
    out: dict = {"learned_share": LEARNED_SHARE, "gap": gap, "reference": REFERENCE, "methods": {}}
    for m in METHODS:
        k, n = len(learned_runs[m]), len(runs[m])
        row: dict = {"runs": n, "learned": k, "learned_seeds": learned_runs[m],
                     "p_learn_ci": _exact_interval(k, n), "success_per_seed": shares[m],
                     "touching_per_seed": [float(t.mean()) for _, t in runs[m]]}
        if m != REFERENCE:
            table = [[len(ref), 5 - len(ref)], [k, n - k]]
            row["fisher_p_learn"] = float(stats.fisher_exact(table).pvalue)
        for what, index in (("success", 0), ("touching", 1)):
            mine = np.array([runs[m][i][index] for i in learned_runs[m]])
            theirs = np.array([runs[REFERENCE][i][index] for i in ref])
            per_seed = mine.mean(axis=1)
            level = {"seed_mean": float(per_seed.mean()), "seed_values": [float(x) for x in per_seed],
                     "episode_mean": float(mine.mean())}
            if m != REFERENCE:
                welch = stats.ttest_ind(theirs.mean(axis=1), per_seed, equal_var=False)
                level["seed_reference_minus_this"] = float(theirs.mean(axis=1).mean() - per_seed.mean())
                level["seed_welch_p"] = float(welch.pvalue)
                level["episode_reference_minus_this"] = float(theirs.mean() - mine.mean())
                level["episode_interval"] = _two_way_bootstrap(theirs, mine, rng)
                level["episode_sign_test"] = _sign_test(theirs.mean(axis=0), mine.mean(axis=0))
            row[what] = level
        out["methods"][m] = row
    return out


DEFAULT_SUITES = tuple(POLICIES / f"ahrm-default-seed{seed}" / "suite-test" for seed in DEFAULT_SEEDS)


def default_policy(suites: Sequence[Path] = DEFAULT_SUITES) -> dict:
    """The policy's seeds (one suite folder each) against the scripted controller on the same
    episodes, each test episode one unit."""
    families = sorted(p.name for p in suites[0].iterdir() if p.is_dir())
    success, touched, teacher_success, teacher_touched = [], [], [], []
    for family in families:
        per_seed = [_episodes(suite / family / "evaluation.csv") for suite in suites]
        success.append(np.array([s for s, _ in per_seed]))
        touched.append(np.array([t for _, t in per_seed]))
        # the scripted controller on the same episodes: one deterministic draw (the first seed's
        # copy; the copies beside every seed are the same episodes, checked below)
        teachers = [_episodes(suite / family / "scripted" / "evaluation.csv") for suite in suites]
        same = all(np.array_equal(teachers[0][0], t[0]) for t in teachers)
        if not same:
            raise ValueError(f"{family}: the scripted controller's copies differ across seeds")
        teacher_success.append(teachers[0][0])
        teacher_touched.append(teachers[0][1])
    policy_s, policy_t = np.concatenate(success, axis=1), np.concatenate(touched, axis=1)
    teacher_s, teacher_t = np.concatenate(teacher_success), np.concatenate(teacher_touched)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    out: dict = {"families": families, "episodes": int(teacher_s.size), "seeds": len(suites)}
    for what, mine, theirs in (("success", policy_s, teacher_s), ("touching", policy_t, teacher_t)):
        out[what] = {"policy": float(mine.mean()), "teacher": float(theirs.mean()),
                     "policy_minus_teacher": float(mine.mean() - theirs.mean()),
                     "interval": _two_way_bootstrap(mine, theirs[None, :], rng),
                     "sign_test": _sign_test(mine.mean(axis=0), theirs),
                     "policy_per_seed": [float(x) for x in mine.mean(axis=1)],
                     "seeds_above_teacher": int(np.sum(mine.mean(axis=1) > theirs.mean())),
                     "teacher_events": int(theirs.sum())}
    return out


CLONES = ROOT / "docs" / "reanalysis"  # clone-seed<N>/suite-clone-test/<family>/evaluation.csv


def ppo_over_clone(clones: Path = CLONES, policies: Path = POLICIES) -> dict:
    """Each default seed whose clone has been read on the test suite: the policy (after PPO) against
    its own clone (before any PPO update) on the same 800 episodes, the test episode as the unit:
    success and touching differences with the exact sign test, and the mean time ratio on episodes
    both won; then pooled over those seeds (each episode's mean over seeds, two-way bootstrap)."""
    seeds = [s for s in DEFAULT_SEEDS if (clones / f"clone-seed{s}" / "suite-clone-test" / "suite.json").is_file()]
    out: dict = {"seeds": seeds, "per_seed": {}}
    if not seeds:
        return out
    families = sorted(p.name for p in (policies / "ahrm-default-seed0" / "suite-test").iterdir() if p.is_dir())
    stacks: dict[str, list[np.ndarray]] = {"policy_s": [], "clone_s": [], "policy_t": [], "clone_t": []}
    for seed in seeds:
        mine = [policies / f"ahrm-default-seed{seed}" / "suite-test" / f / "evaluation.csv" for f in families]
        theirs = [clones / f"clone-seed{seed}" / "suite-clone-test" / f / "evaluation.csv" for f in families]
        ps, pt, ptime = (np.concatenate(x) for x in zip(*[_columns(p) for p in mine]))
        cs, ct, ctime = (np.concatenate(x) for x in zip(*[_columns(p) for p in theirs]))
        both = ~np.isnan(ptime) & ~np.isnan(ctime)
        out["per_seed"][seed] = {
            "policy_successes": int(ps.sum()), "clone_successes": int(cs.sum()),
            "policy_touching": int(pt.sum()), "clone_touching": int(ct.sum()), "episodes": int(ps.size),
            "success_sign": _sign_test(ps, cs), "touching_sign": _sign_test(pt, ct),
            "time_ratio": float(np.mean(ptime[both] / ctime[both])), "both_won": int(both.sum())}
        for key, value in (("policy_s", ps), ("clone_s", cs), ("policy_t", pt), ("clone_t", ct)):
            stacks[key].append(value)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    arrays = {k: np.array(v) for k, v in stacks.items()}
    for what, a, b in (("success", arrays["policy_s"], arrays["clone_s"]),
                       ("touching", arrays["policy_t"], arrays["clone_t"])):
        # paired by seed: resample seeds jointly for both sides, and the episodes
        diffs = a - b
        out[what] = {"policy_minus_clone": float(diffs.mean()),
                     "interval": _two_way_bootstrap(diffs, None, rng),
                     "sign_test": _sign_test(a.mean(axis=0), b.mean(axis=0))}
    return out


TEACHER_AT_CAP = CLONES / "scripted-at-policy-cap"  # <family>/evaluation.csv: the same test episodes


def _suite_columns(folder: Path, families: Sequence[str], sub: str = "") -> tuple[np.ndarray, ...]:
    """:func:`_columns` of ``folder/<family>[/sub]/evaluation.csv``, concatenated in family order."""
    parts = [_columns(folder / f / sub / "evaluation.csv") for f in families]
    return tuple(np.concatenate(x) for x in zip(*parts))


def teacher_at_cap(teacher: Path = TEACHER_AT_CAP, policies: Path = POLICIES, clones: Path = CLONES) -> dict:
    """The scripted controller with its travel and push speeds at the policy's Cartesian cap
    (``task.action.cartesian_max_speed``) on the same 800 test episodes: its success and touching,
    and each default seed's (and each clone's) mean time ratio to it on the episodes both won, beside
    the same ratio against the teacher at its own speeds (the copies beside each seed's suite)."""
    if not (teacher / "suite.json").is_file():
        return {}
    families = sorted(p.name for p in (policies / "ahrm-default-seed0" / "suite-test").iterdir() if p.is_dir())
    ts, tt, ttime = _suite_columns(teacher, families)
    out: dict = {"episodes": int(ts.size), "successes": int(ts.sum()), "touching": int(tt.sum()), "per_seed": {}}

    def ratio(mine: np.ndarray, theirs: np.ndarray) -> tuple[float, int]:
        both = ~np.isnan(mine) & ~np.isnan(theirs)
        return float(np.mean(mine[both] / theirs[both])), int(both.sum())

    for seed in DEFAULT_SEEDS:
        suite = policies / f"ahrm-default-seed{seed}" / "suite-test"
        ptime = _suite_columns(suite, families)[2]
        row: dict = {}
        row["policy_over_teacher_at_cap"], row["policy_both_won"] = ratio(ptime, ttime)
        row["policy_over_teacher_own_speed"] = ratio(ptime, _suite_columns(suite, families, "scripted")[2])[0]
        clone = clones / f"clone-seed{seed}" / "suite-clone-test"
        if (clone / "suite.json").is_file():
            row["clone_over_teacher_at_cap"], row["clone_both_won"] = ratio(_suite_columns(clone, families)[2], ttime)
        out["per_seed"][seed] = row
    for key in ("policy_over_teacher_at_cap", "clone_over_teacher_at_cap", "policy_over_teacher_own_speed"):
        values = [r[key] for r in out["per_seed"].values() if key in r]
        out[key] = {"mean": float(np.mean(values)), "min": float(np.min(values)), "max": float(np.max(values)),
                    "seeds": len(values)}
    return out


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def tables(data: dict) -> str:
    e, d = data["experiment"], data["default_policy"]
    lines = [
        "<!-- generated by studies/reanalysis.py; do not edit -->",
        "## Experiment 42: did a run learn, and how well did the learned runs do",
        "",
        f"A run learned when it won ≥ {_pct(e['learned_share'])} of its 200 test episodes; the largest "
        f"share below that is {_pct(e['gap'][0])} and the smallest at or above it {_pct(e['gap'][1])}, so "
        "any threshold in between sorts the runs alike. Fisher: P(learn) against "
        f"{e['reference']} (exact, two-sided). Among learned runs every run has 200 episodes, so the mean "
        "over runs and over their episodes coincide; the levels differ in their unit of inference (below).",
        "",
        "| method | learned runs | P(learn), exact 95 % | Fisher p vs reference | success among learned | "
        "touching among learned | success, every run |",
        "|---|---|---|---|---|---|---|",
    ]
    for m, row in e["methods"].items():
        ci = row["p_learn_ci"]
        lines.append(
            f"| {m} | {row['learned']}/{row['runs']} (seeds {', '.join(map(str, row['learned_seeds']))}) | "
            f"{ci[0]:.2f}–{ci[1]:.2f} | {row.get('fisher_p_learn', float('nan')):.3g} | "
            f"{_pct(row['success']['seed_mean'])} | {_pct(row['touching']['seed_mean'])} | "
            f"{_pct(sum(row['success_per_seed']) / row['runs'])} |".replace("| nan |", "| — |"))
    lines += ["", f"### {e['reference']} − each method, among learned runs",
              "",
              "Seed level: difference of the learned runs' mean shares, Welch's t. Episode level: each test "
              "episode's mean over the method's learned runs, paired by episode; the difference with a two-way "
              "bootstrap 95 % interval (episodes and runs resampled) and the exact sign test on the episodes "
              "whose means differ (reference above / below).",
              "",
              "| method | measure | seed level: difference, Welch p | episode level: difference, 95 % interval |"
              " sign test: above / below, p |",
              "|---|---|---|---|---|"]
    for m, row in e["methods"].items():
        if m == e["reference"]:
            continue
        for what in ("success", "touching"):
            x = row[what]
            iv, sign = x["episode_interval"], x["episode_sign_test"]
            seed = f"{100 * x['seed_reference_minus_this']:+.1f} pp, p = {x['seed_welch_p']:.2g}"
            episode = f"{100 * x['episode_reference_minus_this']:+.1f} pp ({100 * iv[0]:+.1f}, {100 * iv[1]:+.1f})"
            signs = f"{sign['above']} / {sign['below']}, p = {sign['p']:.2g}"
            lines.append(f"| {m} | {what} | {seed} | {episode} | {signs} |")
    c = data.get("ppo_over_clone", {"seeds": []})
    if c["seeds"]:
        lines += ["", "## PPO's part: each default seed against its own clone (the policy before any PPO update)",
                  "", f"Seeds whose clone has been read on the test suite: {', '.join(map(str, c['seeds']))} "
                  "(tools/reanalysis_rows.sh; the clone retrained by this code from the seed's committed config). "
                  "Sign tests: episodes the policy won (touched) and its clone did not / the reverse.", "",
                  "| seed | policy successes | clone successes | sign test (p) | policy touching | clone touching | "
                  "sign test (p) | time policy / clone (both won) |", "|---|---|---|---|---|---|---|---|"]
        for seed, r in c["per_seed"].items():
            ss, ts = r["success_sign"], r["touching_sign"]
            n = r["episodes"]
            lines.append(f"| {seed} | {r['policy_successes']}/{n} | {r['clone_successes']}/{n} | "
                         f"{ss['above']} / {ss['below']} ({ss['p']:.2g}) | {r['policy_touching']} | "
                         f"{r['clone_touching']} | {ts['above']} / {ts['below']} ({ts['p']:.2g}) | "
                         f"{r['time_ratio']:.3f} ({r['both_won']}) |")
        for what in ("success", "touching"):
            x = c[what]
            iv = x["interval"]
            lines.append(f"\nPooled over those seeds, {what}: policy − clone {100 * x['policy_minus_clone']:+.2f} pp "
                         f"[{100 * iv[0]:+.2f}, {100 * iv[1]:+.2f}] (two-way bootstrap, seeds and episodes).")
    a = data.get("teacher_at_cap", {})
    if a:
        lines += ["", "## Time at equal speed caps: the teacher at the policy's cap",
                  "", f"The scripted controller with `scripted.travel_speed` and `scripted.push_speed` at the "
                  f"policy's Cartesian cap (1.0 m/s) on the same {a['episodes']} test episodes wins "
                  f"{a['successes']} and touches in {a['touching']}. Time ratios: the mean over episodes both won "
                  "of each seed's time over the teacher's.", "",
                  "| seed | policy / teacher at its own speeds | policy / teacher at the policy's cap (both won) | "
                  "clone / teacher at the policy's cap (both won) |", "|---|---|---|---|"]
        for seed, r in a["per_seed"].items():
            clone = (f"{r['clone_over_teacher_at_cap']:.3f} ({r['clone_both_won']})"
                     if "clone_over_teacher_at_cap" in r else "—")
            lines.append(f"| {seed} | {r['policy_over_teacher_own_speed']:.3f} | "
                         f"{r['policy_over_teacher_at_cap']:.3f} ({r['policy_both_won']}) | {clone} |")
        lines.append("| mean over seeds | " + " | ".join(
            f"{a[k]['mean']:.3f}" for k in ("policy_over_teacher_own_speed", "policy_over_teacher_at_cap",
                                            "clone_over_teacher_at_cap")) + " |")
    s, t = d["success"], d["touching"]
    lines += ["", "## The default policy against its teacher, the test episode as the unit",
              "",
              f"{d['episodes']} test episodes of the suite ({len(d['families'])} families), each one unit: the "
              f"policy's mean over its {d['seeds']} seeds against the scripted controller's one outcome on the same "
              "episode. Interval: two-way bootstrap (episodes and seeds). Sign test: episodes where the policy's "
              "mean is above / below the teacher's.",
              "",
              "| measure | policy | scripted controller | policy − scripted (95 % interval) "
              "| sign test: above / below, p | seeds above the teacher |",
              "|---|---|---|---|---|---|"]
    for what, x in (("success", s), ("touching", t)):
        iv, sign = x["interval"], x["sign_test"]
        difference = f"{100 * x['policy_minus_teacher']:+.2f} pp ({100 * iv[0]:+.2f}, {100 * iv[1]:+.2f})"
        lines.append(f"| {what} | {_pct(x['policy'])} | {_pct(x['teacher'])} ({x['teacher_events']} episodes) | "
                     f"{difference} | {sign['above']} / {sign['below']}, p = {sign['p']:.2g} | "
                     f"{x['seeds_above_teacher']}/{d['seeds']} |")
    return "\n".join(lines) + "\n"


def collect() -> dict:
    """Every analysis of this page, from the committed files (what ``data.json`` holds)."""
    return {"experiment": experiment(), "default_policy": default_policy(), "ppo_over_clone": ppo_over_clone(),
            "teacher_at_cap": teacher_at_cap()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "reanalysis"), help="folder of data.json")
    parser.add_argument("--page", default=str(PAGE), help="the page whose marked block gets the tables")
    args = parser.parse_args(argv)
    out, page = Path(args.out), Path(args.page)
    data = collect()
    out.mkdir(parents=True, exist_ok=True)
    (out / "data.json").write_text(json.dumps(data, indent=1) + "\n")
    page.write_text(render(page.read_text(), data))
    print(tables(data))
    return 0


def render(text: str, data: dict) -> str:
    """``text`` with the tables of ``data`` between its markers."""
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[:start] + BEGIN + "\n" + tables(data) + END + text[end:]


if __name__ == "__main__":
    sys.exit(main())
