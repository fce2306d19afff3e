"""The four-method experiment's registered analysis (docs/protocol.md), from its folder only.

    python studies/experiment_analysis.py OUT [--reference ahrm] [--collect DIR] [--write MD] [--curves PNG]

OUT is a ``python -m ahrm_stack.experiment`` folder: ``runs/<method>-seed<s>/eval/evaluation.csv``
(per test episode: ``success``, ``touched_steps``, ``time_to_success``; lane columns where
present), ``runs/<method>-seed<s>/events.jsonl`` (AHRM's ``order_changed`` events) and
``scripted/evaluation.csv`` (the scripted controller on the same episodes). Writes markdown with:

* every run's row (successes, touching, time, lane agreement; for AHRM whether its order ever
  changed — a run whose order never changed trained as FHRM with the initial order, and says so);
* per method, the pooled successes and touching with Clopper–Pearson 95 % intervals, and against
  the scripted controller the exact sign test on the paired episodes;
* the reference (AHRM) against each other method: the mean per-seed difference (paired by seed)
  with its 95 % t-interval and p, Holm-adjusted over the comparisons (success: H1–H3), and for
  touching the same plus the exact sign test on paired episodes (same seed, same episode); the
  same t-interval for the time to success on the episodes both runs of a seed won, and the exact
  sign test on episodes pushed out by the lane the planner did not choose;
* per run, its time to success against the scripted controller's on the episodes both won;
* each run against the scripted controller on the same episodes: exact sign tests on success,
  touching and wrong-lane episodes;
* the registered hypotheses called (:func:`call_success`, :func:`call_touching`): H1–H3
  established or not at two-sided α = 0.05 after Holm, H4 (touching) secondary and uncorrected;
  every call is "not called (partial)" while a run is missing;
* the goal: without the planner, the reference's pooled success ≥ 95 % and touching ≤ 2 % (not
  applicable to planner-assisted runs, which the report says).

Missing runs are listed and the whole output is marked PARTIAL; nothing is called on it then. An
attempt lost with its checkpoints before its test evaluation (``OUT/lost/<run>/``, see
:data:`LOST`) is listed with how far it got; the run's rows are its restart's. Where runs have
been through the deploy loop (``OUT/robustness/<run>/robustness.json``, see :data:`ROBUSTNESS`), a
secondary, descriptive section gives each run's ``ideal`` and ``all`` rows and the pooled ``all``
row per method; it reads no test episode.

``--collect DIR`` first copies what the analysis reads into ``DIR`` (``grid.json``; per run its
``config.yaml``, ``evaluations.csv``, ``batches.csv`` gzipped, ``eval/evaluation.*``, ``done.json``
or ``failed.json``, the final ``policy.pt``, and of ``events.jsonl`` only the priority-order events; the scripted
controller's ``evaluation.*``; each ``robustness.json`` gzipped), then analyses that copy, so that
the committed report can be regenerated from committed data (``tests/test_experiment_analysis.py`` does it for
``docs/experiment-42``).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import gzip
import json
import math
import os
import shutil
import sys
from pathlib import Path
from typing import Callable

import numpy as np
from scipy import stats

from ahrm_stack.log_copies import csv_rows, gzip_copy
from ahrm_stack.robustness import Row, meets_goal

GOAL_SUCCESS, GOAL_TOUCHING = 0.95, 0.02  # docs/protocol.md


@dataclasses.dataclass(frozen=True)
class Episodes:
    """One policy's evaluation episodes, in episode order: success, touched (bool) and time to
    success (s, nan without success); lane agreement per episode ('' where not pushed or absent)."""

    success: np.ndarray
    touched: np.ndarray
    time: np.ndarray
    lane_agrees: tuple[str, ...]

    @classmethod
    def read(cls, path: Path) -> "Episodes":
        with open(path) as handle:
            rows = list(csv.DictReader(handle))
        if not rows:
            raise ValueError(f"{path}: no episodes")
        return cls(np.array([row["success"] == "True" for row in rows]),
                   np.array([int(row["touched_steps"]) > 0 for row in rows]),
                   np.array([float(row["time_to_success"]) for row in rows]),
                   tuple(row.get("lane_agrees", "") for row in rows))


def clopper_pearson(k: int, n: int) -> tuple[float, float]:
    """Exact 95 % interval of a binomial share ``k`` of ``n``."""
    lo = 0.0 if k == 0 else float(stats.beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def sign_test(only_a: int, only_b: int) -> float:
    """Exact two-sided sign test (McNemar's exact form) of discordant pair counts."""
    n = only_a + only_b
    return 1.0 if n == 0 else float(stats.binomtest(only_a, n, 0.5).pvalue)


Stat = tuple[float, float, float, float]  # mean, 95 % interval low, high, two-sided p


def paired_t(differences: np.ndarray) -> Stat:
    """(mean, 95 % t-interval low, high, two-sided p) of per-seed differences (nan below 2 seeds;
    all equal: the interval is the point and p is 1 for 0 else 0)."""
    d = np.asarray(differences, dtype=float)
    mean = float(d.mean()) if d.size else math.nan
    if d.size < 2:
        return mean, math.nan, math.nan, math.nan
    se = float(d.std(ddof=1)) / math.sqrt(d.size)
    if se == 0.0:
        return mean, mean, mean, 1.0 if mean == 0.0 else 0.0
    half = float(stats.t.ppf(0.975, d.size - 1)) * se
    return mean, mean - half, mean + half, float(2 * stats.t.sf(abs(mean) / se, d.size - 1))


def holm(pvalues: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values, in the given order (nan stays nan)."""
    order = sorted((p, i) for i, p in enumerate(pvalues) if not math.isnan(p))
    adjusted = [math.nan] * len(pvalues)
    running = 0.0
    for rank, (p, i) in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * p))
        adjusted[i] = running
    return adjusted


ALPHA = 0.05  # two-sided, for H1–H3 after Holm and for H4 uncorrected (docs/protocol.md)
HYPOTHESES = {"ls": "H1", "mhrm": "H2", "fhrm": "H3"}  # AHRM against each (docs/protocol.md)


def call_success(stat: Stat, p_holm: float, partial: bool, reference: str) -> str:
    """H1–H3's call on the seed-level success difference (``stat``: reference − other, from
    :func:`paired_t`): established in the direction of its mean when the Holm-adjusted two-sided
    p is below :data:`ALPHA`, else not established; never called on a partial experiment."""
    if partial:
        return "not called (partial)"
    if math.isnan(p_holm):
        return "not tested (fewer than 2 paired seeds)"
    if p_holm < ALPHA:
        return f"**established**: {reference} {'higher' if stat[0] > 0 else 'lower'} (Holm p = {p_holm:.3g})"
    return f"not established (Holm p = {p_holm:.3g}; unadjusted 95 % interval [{stat[1]:+.3f}, {stat[2]:+.3f}])"


def call_touching(stat: Stat, only_mine: int, only_theirs: int, partial: bool, reference: str) -> str:
    """H4's call, secondary and uncorrected: the exact sign test on the paired episodes only one
    of the two touched in (the protocol's test for rare events), with whether the seed-level
    t-interval of the touching difference (``stat``) also excludes 0."""
    if partial:
        return "not called (partial)"
    p = sign_test(only_mine, only_theirs)
    sign = (f"{only_mine} only {reference} / {only_theirs} only the other, p = {p:.3g}: "
            + (f"{reference} touches {'less' if only_mine < only_theirs else 'more'}" if p < ALPHA
               else "no difference shown"))
    if math.isnan(stat[1]):
        return sign + "; seed level: fewer than 2 seeds"
    excludes = stat[1] > 0 or stat[2] < 0
    return sign + f"; seed level {stat[0]:+.3f} [{stat[1]:+.3f}, {stat[2]:+.3f}]" + (
        ", excludes 0" if excludes else ", holds 0")


def order_changed(run_dir: Path) -> bool | None:
    """Whether the run's priority order ever changed (``order_changed`` in ``events.jsonl``);
    None without the file."""
    path = run_dir / "events.jsonl"
    if not path.is_file():
        return None
    return any(json.loads(line).get("kind") == "order_changed" for line in path.read_text().splitlines() if line)


def _runs(out: Path) -> dict[str, dict[int, Path]]:
    """method -> seed -> run folder, from ``out/grid.json`` (every planned run, evaluated or not)."""
    grid = json.loads((out / "grid.json").read_text())
    runs: dict[str, dict[int, Path]] = {}
    for spec in grid["runs"]:
        runs.setdefault(spec["method"], {})[int(spec["seed"])] = out / "runs" / spec["name"]
    return runs


#: the events of a run that the analysis reads (the rest of ``events.jsonl`` is not copied)
ORDER_EVENTS = ("order_changed", "order_locked")


#: an attempt of a run that was lost with its checkpoints before its test evaluation (the machine
#: went away); the run restarted from frame 0 with the same seed (docs/protocol.md, Deviations).
#: ``OUT/lost/<run>/`` holds what had been collected of it; the report lists how far it got.
LOST = "lost"


#: each run's deploy-loop judgement (docs/protocol.md, "the experiment's policies through the deploy
#: loop"): ``OUT/robustness/<run>/robustness.json`` from ``python -m ahrm_stack.robustness RUN
#: --no-dose --out OUT/robustness/<run>`` (gzipped in a collected copy); secondary, descriptive.
ROBUSTNESS = "robustness"


def read_robustness(folder: Path) -> dict | None:
    """``folder/robustness.json`` (or its gzipped copy) as written by ``ahrm_stack.robustness``; None
    without either."""
    if (folder / "robustness.json").is_file():
        return json.loads((folder / "robustness.json").read_text())
    if (folder / "robustness.json.gz").is_file():
        with gzip.open(folder / "robustness.json.gz", "rt") as handle:
            return json.loads(handle.read())
    return None


def _copy_run(source: Path, target: Path) -> None:
    """Copy what the analysis reads of one run folder (files it does not have are skipped)."""
    for file in ("config.yaml", "evaluations.csv", "done.json", "failed.json", "policy.pt",
                 "eval/evaluation.csv", "eval/evaluation.json", "batches.csv.gz"):
        if (source / file).is_file():
            (target / file).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source / file, target / file)
    if (source / "batches.csv").is_file():
        target.mkdir(parents=True, exist_ok=True)
        gzip_copy(source / "batches.csv", target / "batches.csv.gz")
    if (source / "events.jsonl").is_file():
        target.mkdir(parents=True, exist_ok=True)
        kept = [line for line in (source / "events.jsonl").read_text().splitlines()
                if line and json.loads(line).get("kind") in ORDER_EVENTS]
        (target / "events.jsonl").write_text("".join(line + "\n" for line in kept))


def collect(out: Path, dest: Path) -> Path:
    """Copy what :func:`analyse` and :func:`plot_curves` read from the experiment folder ``out``
    into ``dest`` (same layout; ``batches.csv`` gzipped without a time stamp, ``events.jsonl``
    cut to :data:`ORDER_EVENTS`; lost attempts under :data:`LOST`); returns ``dest``. Files a run
    does not have yet are skipped."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "grid.json", dest / "grid.json")
    grid = json.loads((out / "grid.json").read_text())
    for name in [spec["name"] for spec in grid["runs"]]:
        _copy_run(out / "runs" / name, dest / "runs" / name)
        if (out / LOST / name).is_dir():
            _copy_run(out / LOST / name, dest / LOST / name)
        if (out / ROBUSTNESS / name / "robustness.json").is_file():
            (dest / ROBUSTNESS / name).mkdir(parents=True, exist_ok=True)
            gzip_copy(out / ROBUSTNESS / name / "robustness.json", dest / ROBUSTNESS / name / "robustness.json.gz")
    for file in ("evaluation.csv", "evaluation.json", "done.json"):
        if (out / "scripted" / file).is_file():
            (dest / "scripted").mkdir(parents=True, exist_ok=True)
            shutil.copyfile(out / "scripted" / file, dest / "scripted" / file)
    return dest


def progress(run_dir: Path) -> tuple[int, str, str]:
    """How far an unfinished (or finished) run is: (frames trained, its latest interim evaluation
    on validation episodes as "k/n at F frames" or "—", for AHRM whether its order has changed so
    far), read from ``batches.csv`` (or its gzipped copy; else ``episodes.csv``), ``evaluations.csv``
    and ``events.jsonl``."""
    frames = 0
    for row in csv_rows(run_dir, "batches.csv") or csv_rows(run_dir, "episodes.csv"):
        frames = int(row["frames"])
    latest = "—"
    rows = csv_rows(run_dir, "evaluations.csv")
    if rows:
        last = rows[-1]
        latest = (f"{last['successes']}/{last['episodes']} ({last['touched_episodes']} touching) "
                  f"at {int(last['frames']):,}")
    changed = order_changed(run_dir)
    return frames, latest, "—" if changed is None else "changed" if changed else "not yet"


def planner_uses(overrides: list[str]) -> list[str]:
    """What the network of a run with these training overrides takes from the scripted
    controller's lane plan ([] for a planner-free configuration), from the configuration they give."""
    from ahrm_stack.config import load_config

    config = load_config(overrides)
    return [name for name, on in (
        ("observes its lane choice", config.task.observation.lane_choice),
        ("reads the episode in that lane's frame", config.ppo.lane_frame != "none"),
        ("starts its curriculum behind the cube for that lane", config.task.arm.near_cube.bearing == "behind"))
        if on]


def planner_line(overrides: list[str]) -> str:
    """The report's first line (docs/protocol.md): whether the runs' configuration feeds the
    scripted controller's lane plan to the network, computed from the training overrides."""
    uses = planner_uses(overrides)
    if uses:
        return ("**Planner-assisted: the network runs on the scripted controller's lane plan** ("
                + "; ".join(uses) + ").")
    return "**Planner-free: no input keyed on the scripted controller's lane plan.**"


def interim_curves(out: Path) -> dict[str, dict[int, list[tuple[int, float, float]]]]:
    """method -> seed -> [(frames, success share, touching share)] of each run's interim
    evaluations (``evaluations.csv``: validation episodes), frames rounded to the grid's
    ``train.eval_every_frames`` step when the overrides give it (a batch ends a little after it)."""
    grid = json.loads((out / "grid.json").read_text())
    step = 0
    for override in grid.get("train_overrides", []):
        if override.startswith("train.eval_every_frames="):
            step = int(override.split("=", 1)[1])
    curves: dict[str, dict[int, list[tuple[int, float, float]]]] = {}
    for method, seeds in _runs(out).items():
        for seed, run_dir in sorted(seeds.items()):
            path = run_dir / "evaluations.csv"
            if not path.is_file():
                continue
            with open(path) as handle:
                rows = list(csv.DictReader(handle))
            points = []
            for row in rows:
                frames = int(row["frames"])
                if step:
                    frames = int(round(frames / step)) * step
                episodes = int(row["episodes"])
                points.append((frames, int(row["successes"]) / episodes, int(row["touched_episodes"]) / episodes))
            if points:
                curves.setdefault(method, {})[seed] = points
    return curves


def seed_band(values: list[float]) -> tuple[float, float, float]:
    """(mean, lowest, highest) over the seeds: the registered band (docs/protocol.md, Metrics: "a
    band from the lowest to the highest seed")."""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.min()), float(v.max())


def plot_curves(out: Path, path: Path) -> Path | None:
    """Success and touching shares of the interim (validation) evaluations against frames, per
    method: the mean over the seeds that reached each point, a band from the lowest to the highest
    of them (:func:`seed_band`), and each seed thin."""
    from ahrm_stack.learning.diagnostics import pyplot, save_figure

    curves = interim_curves(out)
    if not curves:
        return None
    overrides = json.loads((out / "grid.json").read_text()).get("train_overrides")
    configuration = "" if overrides is None else (
        "planner-assisted; " if planner_uses(overrides) else "planner-free; ")
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    for i, (method, by_seed) in enumerate(curves.items()):
        color = f"C{i}"
        frames = sorted({f for points in by_seed.values() for f, _, _ in points})
        for column, ax in ((1, axes[0]), (2, axes[1])):
            for points in by_seed.values():
                ax.plot([p[0] for p in points], [p[column] for p in points], color=color, alpha=0.25, lw=0.8)
            mean, low, high = [], [], []
            for f in frames:
                m, lo, hi = seed_band([p[column] for points in by_seed.values() for p in points if p[0] == f])
                mean.append(m)
                low.append(lo)
                high.append(hi)
            last = max(frames)
            complete = sum(points[-1][0] == last for points in by_seed.values())
            seeds = (f"{len(by_seed)} seeds" if complete == len(by_seed)
                     else f"{len(by_seed)} seeds, {complete} to {last / 1e6:g}M frames")
            ax.plot(frames, mean, color=color, lw=2, label=f"{method} ({seeds})")
            ax.fill_between(frames, low, high, color=color, alpha=0.2)
    fig.suptitle(f"{configuration}interim evaluations on validation episodes: mean over the seeds at each point, "
                 "band from the lowest to the highest seed, each seed thin", fontsize=10)
    axes[0].set_title("success share")
    axes[1].set_title("touching share")
    for ax in axes:
        ax.set_xlabel("training frames")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(fig, path, dpi=90)


def _share(k: int, n: int) -> str:
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} ({k / n:.1%} [{lo:.1%}, {hi:.1%}])"


def _interval(stat: Stat, p_adjusted: float | None = None) -> str:
    mean, lo, hi, p = stat
    if math.isnan(lo):  # fewer than 2 seeds so far
        return f"{mean:+.3f} (one seed: no interval, no test)"
    text = f"{mean:+.3f} [{lo:+.3f}, {hi:+.3f}], p = {p:.3g}"
    return text + (f", Holm p = {p_adjusted:.3g}" if p_adjusted is not None else "")


def _per_seed(mine: dict[int, Episodes], theirs: dict[int, Episodes], seeds: list[int], name: str) -> Stat:
    """:func:`paired_t` of the per-seed differences of the share of episodes with ``name`` true."""
    return paired_t(np.array([getattr(mine[s], name).mean() - getattr(theirs[s], name).mean() for s in seeds]))


def deploy_loop_section(out: Path, runs: dict[str, dict[int, Path]]) -> list[str]:
    """The secondary, descriptive section on the runs that have been through the deploy loop
    (:data:`ROBUSTNESS`): per run its ``ideal`` and ``all`` conditions against the scripted
    controller on the same episodes and how many conditions meet the robustness goal
    (:func:`ahrm_stack.robustness.meets_goal`); per method the ``all`` condition pooled over its
    seeds (Clopper–Pearson 95 %) with the exact sign test against the scripted controller on the
    paired episodes. [] when no run has been through it."""
    judged = {(method, seed): data for method, seeds in runs.items() for seed in sorted(seeds)
              if (data := read_robustness(out / ROBUSTNESS / f"{method}-seed{seed}")) is not None}
    if not judged:
        return []
    unjudged = [(f"{m}-seed{s}", path) for m, seeds in runs.items() for s, path in sorted(seeds.items())
                if (m, s) not in judged]
    lost = [name for name, path in unjudged if (path / "done.json").is_file() and not (path / "policy.pt").is_file()]
    waiting = [name for name, _ in unjudged if name not in lost]
    lines = ["## Through the deploy loop (secondary, descriptive; docs/protocol.md)", "",
             "Each run's final policy and the scripted controller through the deploy loop on the sim backend "
             "with a real arm's imperfections (`python -m ahrm_stack.robustness RUN --no-dose`; episodes of the "
             "`robustness` seed range, **not** the test split; counted in the simulator). Cells: policy wins / "
             "scripted wins of the episodes (touching episodes in brackets)."
             + (f" Not yet through it: {', '.join(waiting)}." if waiting else "")
             + (f" Finished, but its final policy is lost (not in the run folder): {', '.join(lost)}." if lost else ""),
             "",
             "| run | profile | ideal | all imperfections | conditions meeting the goal |", "|---|---|---|---|---|"]
    pooled: dict[str, list[tuple[bool, bool, bool, bool]]] = {}
    for (method, seed), data in judged.items():
        def records(condition: str, controller: str, data: dict = data) -> list[dict]:
            return [r for r in data["records"] if r["condition"] == condition and r["controller"] == controller]

        everything = next(c for c in data["conditions"] if c.startswith("all ("))
        cells = []
        for condition in ("ideal", everything):
            mine, theirs = Row.of(records(condition, "policy")), Row.of(records(condition, "scripted"))
            cells.append(f"{mine.successes}/{theirs.successes} of {mine.episodes} ({mine.touching}/{theirs.touching})")
        met = sum(meets_goal(records(c, "policy"), records(c, "scripted")) for c in data["conditions"])
        lines.append(f"| {method}-seed{seed} | {data['profile']} | {cells[0]} | {cells[1]} | "
                     f"{met} of {len(data['conditions'])} |")
        theirs_by_seed = {r["seed"]: r for r in records(everything, "scripted")}
        pooled.setdefault(method, []).extend(
            (r["success"], r["touched"], theirs_by_seed[r["seed"]]["success"], theirs_by_seed[r["seed"]]["touched"])
            for r in records(everything, "policy") if r["seed"] in theirs_by_seed)
    lines += ["", "Pooled over each method's judged seeds, all imperfections together (Clopper–Pearson 95 %; "
              "exact sign test against the scripted controller on the same episodes: episodes only the policy / "
              "only the scripted controller won or touched in):", "",
              "| method | seeds | wins | touching | wins vs scripted | touching vs scripted |",
              "|---|---|---|---|---|---|"]
    for method, rows in pooled.items():
        table = np.array(rows, dtype=bool).reshape(-1, 4)
        seeds = sum(1 for m, _ in judged if m == method)
        versus = []
        for policy, scripted in ((table[:, 0], table[:, 2]), (table[:, 1], table[:, 3])):
            a, b = _only(policy, scripted)
            versus.append(f"{a} / {b}, p = {sign_test(a, b):.3g}")
        lines.append(f"| {method} | {seeds} | {_share(int(table[:, 0].sum()), len(table))} | "
                     f"{_share(int(table[:, 1].sum()), len(table))} | {versus[0]} | {versus[1]} |")
    return lines + [""]


def seed_level(shares: list[float]) -> str:
    """Per-seed shares (one per seed, 0–1) as ``mean [95 % t-interval over seeds]`` (percent, the
    interval clipped to 0–100 %), with the lowest and highest seed; one seed: no interval."""
    mean, lo, hi, _ = paired_t(np.array(shares))
    if math.isnan(lo):
        return f"{mean:.1%} (one seed: no interval)"
    return f"{mean:.1%} [{max(lo, 0.0):.1%}, {min(hi, 1.0):.1%}]; seeds {min(shares):.1%}–{max(shares):.1%}"


def seed_level_ranking(episodes: dict[str, dict[int, Episodes]]) -> list[str]:
    """The methods ranked by their mean per-seed success share, each with a 95 % t-interval over its
    seeds (seeds are the units; descriptive: the registered tests are the paired comparisons); the
    same for touching."""
    shares = {method: ([float(e.success.mean()) for e in by_seed.values()],
                       [float(e.touched.mean()) for e in by_seed.values()])
              for method, by_seed in episodes.items() if by_seed}
    ranked = sorted(shares, key=lambda method: -float(np.mean(shares[method][0])))
    lines = ["", "## The methods ranked, seed level (per-seed shares of the test episodes: mean and 95 % t-interval "
             "over seeds, clipped to 0–100 %; seeds are the units here; descriptive: the paired comparisons and "
             "the hypotheses below say which differences are established)", "",
             "| rank | method | seeds | success | touching |", "|---|---|---|---|---|"]
    for rank, method in enumerate(ranked, start=1):
        success, touched = shares[method]
        lines.append(f"| {rank} | {method} | {len(success)} | {seed_level(success)} | {seed_level(touched)} |")
    return lines


def both_won_times(mine: Episodes, theirs: Episodes) -> tuple[float, float, int]:
    """(``mine``'s, ``theirs``' mean s to success, episodes) over the episodes both won, the same
    episodes in the same order (nan, nan, 0 without one)."""
    if mine.success.size != theirs.success.size:
        raise ValueError(f"paired evaluations differ in length: {mine.success.size} and {theirs.success.size} episodes")
    both = mine.success & theirs.success
    if not both.any():
        return math.nan, math.nan, 0
    return float(mine.time[both].mean()), float(theirs.time[both].mean()), int(both.sum())


def _wrong_lane(e: Episodes) -> np.ndarray:
    """Per episode: the cube left by the lane the planner did not choose."""
    return np.array([a == "False" for a in e.lane_agrees])


def _only(mine: np.ndarray, theirs: np.ndarray) -> tuple[int, int]:
    """Paired boolean outcomes: (true only in ``mine``, true only in ``theirs``), the sign test's counts."""
    return int((mine & ~theirs).sum()), int((~mine & theirs).sum())


def _discordant(mine: dict[int, Episodes], theirs: dict[int, Episodes], seeds: list[int],
                event: Callable[[Episodes], np.ndarray]) -> tuple[int, int]:
    """Paired episodes (same seed, same episode) with ``event`` only in ``mine`` / only in ``theirs``."""
    if any(mine[s].success.size != theirs[s].success.size for s in seeds):
        raise ValueError("paired evaluations differ in length")
    counts = [_only(event(mine[s]), event(theirs[s])) for s in seeds]
    return sum(a for a, _ in counts), sum(b for _, b in counts)


def analyse(out: Path, reference: str = "ahrm") -> str:
    """The markdown of the registered analysis of the experiment folder ``out``."""
    runs = _runs(out)
    episodes: dict[str, dict[int, Episodes]] = {}
    missing = []
    for method, seeds in runs.items():
        for seed, run_dir in sorted(seeds.items()):
            path = run_dir / "eval" / "evaluation.csv"
            if path.is_file():
                episodes.setdefault(method, {})[seed] = Episodes.read(path)
            else:
                missing.append(run_dir.name)
    scripted_path = out / "scripted" / "evaluation.csv"
    scripted = Episodes.read(scripted_path) if scripted_path.is_file() else None
    partial = bool(missing) or scripted is None
    grid = json.loads((out / "grid.json").read_text())
    lines = [f"# Analysis of {Path(grid.get('out', out)).name} (docs/protocol.md)", ""]
    if "train_overrides" in grid:
        lines += [planner_line(grid["train_overrides"]),
                  "", f"Training overrides: `{' '.join(grid['train_overrides'])}`; final evaluation on the "
                  f"**{grid.get('split', 'validation')} split**.", ""]
    if partial:
        lines += [f"**PARTIAL**: missing {', '.join(missing) or 'no run'}"
                  + ("" if scripted is not None else " and the scripted controller's evaluation")
                  + ". No hypothesis is called on these numbers.", "",
                  "## Progress (frames trained of each run's budget; its latest interim evaluation, on "
                  "**validation** episodes, never a test result)", "",
                  "| run | frames | latest interim evaluation (validation) | AHRM order |", "|---|---|---|---|"]
        budget = int(grid.get("frames") or 0)
        for method, seeds in runs.items():
            for seed, run_dir in sorted(seeds.items()):
                frames, latest, changed = progress(run_dir)
                share = f" ({frames / budget:.0%})" if budget else ""
                lines.append(f"| {method}-seed{seed} | {frames:,}{share} | {latest} | "
                             f"{changed if method == 'ahrm' else '—'} |")
        lines.append("")
    lost = [(method, seed) for method, seeds in runs.items() for seed in sorted(seeds)
            if (out / LOST / f"{method}-seed{seed}").is_dir()]
    if lost:
        lines += ["## Attempts lost with their checkpoints, before any test evaluation (docs/protocol.md, "
                  "Deviations)", "", "Each run below restarted from frame 0 with the same seed and configuration "
                  "(a new realisation: training is not bit-reproducible across machines); every other row of this "
                  "report is the restarted run's. The lost attempt never read the test split; how far it got:", "",
                  "| run | frames the lost attempt reached | its latest interim evaluation (validation) | AHRM order |",
                  "|---|---|---|---|"]
        for method, seed in lost:
            reached, last_eval, order = progress(out / LOST / f"{method}-seed{seed}")
            lines.append(f"| {method}-seed{seed} | {reached:,} | {last_eval} | {order if method == 'ahrm' else '—'} |")
        lines.append("")
    lines += ["## Every run", "", "Time vs scripted: the run's and the scripted controller's mean s to success on the "
              "test episodes both won (their number). Lanes: episodes whose cube left by the planner's lane, of those "
              "pushed off; after a wrong lane, how many of those episodes touched an obstacle.", "",
              "| run | successes | touching | time (s, won episodes) | time vs scripted (s) | lanes | order |",
              "|---|---|---|---|---|---|---|"]
    for method, by_seed in episodes.items():
        for seed, e in sorted(by_seed.items()):
            ever = order_changed(runs[method][seed]) if method == "ahrm" else None
            order = ("changed" if ever else "order never changed (FHRM)" if ever is False else "—")
            pushed = [a for a in e.lane_agrees if a]
            lanes = f"{sum(a == 'True' for a in pushed)}/{len(pushed)}" if pushed else "—"
            wrong = _wrong_lane(e)
            if wrong.any():
                lanes += f"; {int((wrong & e.touched).sum())} of {int(wrong.sum())} wrong-lane touching"
            times = e.time[e.success]
            time = f"{float(times.mean()):.2f}" if times.size else "— (no win)"
            versus_time = "—"
            if scripted is not None and scripted.success.size == e.success.size:
                t_mine, t_scripted, both = both_won_times(e, scripted)
                versus_time = f"{t_mine:.2f} / {t_scripted:.2f} ({both})" if both else "— (none both won)"
            lines.append(f"| {method}-seed{seed} | {int(e.success.sum())}/{e.success.size} | "
                         f"{int(e.touched.sum())} | {time} | {versus_time} | {lanes} | {order} |")
    if scripted is not None:
        lines += ["", "## Each run against the scripted controller on the same test episodes (exact sign test; "
                  "a / b: episodes only the run / only the scripted controller won, touched, left by a wrong lane)",
                  "", "| run | success | touching | wrong lane |", "|---|---|---|---|"]
        for method, by_seed in episodes.items():
            for seed, e in sorted(by_seed.items()):
                if e.success.size != scripted.success.size:
                    lines.append(f"| {method}-seed{seed} | — (other episodes) | | |")
                    continue
                cells = []
                for event in (lambda x: x.success, lambda x: x.touched, _wrong_lane):
                    a, b = _discordant({0: e}, {0: scripted}, [0], event)
                    cells.append(f"{a} / {b}, p = {sign_test(a, b):.3g}")
                lines.append(f"| {method}-seed{seed} | " + " | ".join(cells) + " |")
    lines += ["", "## Pooled over seeds (Clopper–Pearson 95 % over the episodes of these seeds: episodes are its "
              "units, not seeds; the seed-level comparisons follow); against the scripted controller on the same "
              "episodes, once per seed (descriptive: the scripted episodes recur for every seed; a / b: episodes only "
              "the method / only the scripted controller won or touched in)", "",
              "| method | seeds | successes | touching | success vs scripted | touching vs scripted |",
              "|---|---|---|---|---|---|"]
    for method, by_seed in episodes.items():
        success = np.concatenate([e.success for e in by_seed.values()])
        touched = np.concatenate([e.touched for e in by_seed.values()])
        versus = ["—", "—"]
        if scripted is not None:
            pairs = [(e, scripted) for e in by_seed.values() if e.success.size == scripted.success.size]
            for column, name in enumerate(("success", "touched")):
                mine = np.concatenate([getattr(e, name) for e, _ in pairs]) if pairs else np.array([], bool)
                theirs = np.concatenate([getattr(s, name) for _, s in pairs]) if pairs else np.array([], bool)
                a, b = _only(mine, theirs)
                versus[column] = f"{a} / {b}, p = {sign_test(a, b):.3g}"
        lines.append(f"| {method} | {len(by_seed)} | {_share(int(success.sum()), success.size)} | "
                     f"{_share(int(touched.sum()), touched.size)} | {versus[0]} | {versus[1]} |")
    if scripted is not None:
        lines.append(f"| scripted | – | {_share(int(scripted.success.sum()), scripted.success.size)} | "
                     f"{_share(int(scripted.touched.sum()), scripted.touched.size)} | | |")
    lines += seed_level_ranking(episodes)
    others = [m for m in episodes if m != reference]
    mine_by_seed = episodes.get(reference, {})
    comparisons = []
    for other in others:
        theirs_by_seed = episodes[other]
        common = sorted(set(mine_by_seed) & set(theirs_by_seed))
        joint = {s: both_won_times(mine_by_seed[s], theirs_by_seed[s]) for s in common}
        timed = {s: joint[s] for s in common if joint[s][2]}  # seed -> (mine, theirs, episodes both won)
        on_time = paired_t(np.array([mine - theirs for mine, theirs, _ in timed.values()]))
        comparisons.append((other, common, _per_seed(mine_by_seed, theirs_by_seed, common, "success"),
                            _per_seed(mine_by_seed, theirs_by_seed, common, "touched"),
                            _discordant(mine_by_seed, theirs_by_seed, common, lambda e: e.touched),
                            (timed, on_time), _discordant(mine_by_seed, theirs_by_seed, common, _wrong_lane)))
    adjusted = holm([c[2][3] for c in comparisons])
    lines += ["", f"## {reference} − each method, paired by seed (95 % t-interval over seeds; success: "
              "H1–H3 with Holm; touching, time and lanes: secondary, uncorrected; exact sign tests on paired episodes)",
              "", "Time: per seed, the difference of the mean s to success over the test episodes both runs of that "
              "seed won (seeds without such an episode are left out). Wrong lane: the cube left by the lane the "
              "planner did not choose.", "",
              "| comparison | paired seeds | success | touching | touching: discordant episodes | time (s, both won) "
              "| wrong lane: discordant episodes |", "|---|---|---|---|---|---|---|"]
    for comparison, p_holm in zip(comparisons, adjusted):
        other, common, on_success, on_touching, (a, b), (timed, on_time), (c, d) = comparison
        counts = ", ".join(f"{s}: {n}" for s, (_, _, n) in timed.items())
        time_cell = "— (no seed with a joint win)" if not timed else (
            f"{_interval(on_time)} (episodes both won, by seed: {counts})")
        lines.append(f"| {reference} − {other} | {', '.join(map(str, common))} | {_interval(on_success, p_holm)} | "
                     f"{_interval(on_touching)} | {a} only {reference} / {b} only {other}, p = {sign_test(a, b):.3g} | "
                     f"{time_cell} | {c} only {reference} / {d} only {other}, p = {sign_test(c, d):.3g} |")
    if comparisons:
        lines += ["", f"## The registered hypotheses (docs/protocol.md: H1–H3 two-sided at α = {ALPHA:g} with Holm "
                  "over the three; H4 secondary, uncorrected)", "",
                  "| hypothesis | comparison | call |", "|---|---|---|"]
        calls = []  # (hypothesis, its success row, its touching row), in the protocol's order
        for comparison, p_holm in zip(comparisons, adjusted):
            other, _, on_success, on_touching, (a, b), _, _ = comparison
            name = HYPOTHESES.get(other, "—") if reference == "ahrm" else "—"
            calls.append((name, f"| {name} | {reference} wins more episodes than {other} | "
                                f"{call_success(on_success, p_holm, partial, reference)} |",
                          f"| H4 (secondary) | {reference} touches in fewer episodes than {other} | "
                          f"{call_touching(on_touching, a, b, partial, reference)} |"))
        calls.sort()
        lines += [row for _, row, _ in calls] + [row for _, _, row in calls]
    deploy = deploy_loop_section(out, runs)
    if mine_by_seed:
        won = np.concatenate([e.success for e in mine_by_seed.values()])
        hit = np.concatenate([e.touched for e in mine_by_seed.values()])
        met = won.mean() >= GOAL_SUCCESS and hit.mean() <= GOAL_TOUCHING
        assisted = "train_overrides" in grid and bool(planner_uses(grid["train_overrides"]))
        verdict = ("not applicable: the goal is for a policy without the planner and these runs are "
                   "planner-assisted (the figures are for reference)" if assisted
                   else "not called (partial)" if partial else "met" if met else "not met")
        lines += ["", f"## Goal (without the planner, {reference} pooled: success ≥ {GOAL_SUCCESS:.0%}, touching ≤ "
                  f"{GOAL_TOUCHING:.0%})", "", f"success {_share(int(won.sum()), won.size)}, touching "
                  f"{_share(int(hit.sum()), hit.size)}: {verdict}"]
    if deploy:
        lines += [""] + deploy
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the experiment folder (with grid.json)")
    parser.add_argument("--reference", default="ahrm")
    parser.add_argument("--write", type=Path, default=None, help="also write the markdown here")
    parser.add_argument("--curves", type=Path, default=None,
                        help="write the interim evaluations' success/touching vs frames curves (PNG) here")
    parser.add_argument("--collect", type=Path, default=None,
                        help="first copy the data the analysis reads into this folder, then analyse the copy")
    args = parser.parse_args(argv)
    if not (args.out / "grid.json").is_file():
        print(f"error: {args.out / 'grid.json'} not found: OUT must be an experiment folder", file=sys.stderr)
        return 2
    if args.collect:
        args.out = collect(args.out, args.collect)
    text = analyse(args.out, args.reference)
    if args.curves:
        args.curves.parent.mkdir(parents=True, exist_ok=True)
        if plot_curves(args.out, args.curves) is not None:
            link = os.path.relpath(args.curves, args.write.parent if args.write else Path.cwd())
            text += f"\n![interim evaluations against frames]({link})\n"
    if args.write:
        args.write.write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
