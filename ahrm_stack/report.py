"""The experiment report: ``report.md`` and its figures, generated from an experiment folder.

    python -m ahrm_stack.report OUT_DIR

Everything in the report is computed from the files the runs wrote (``grid.json``,
``runs/*/done.json`` / ``failed.json``, ``episodes.csv``, ``events.jsonl``,
``scripted/done.json``) and from ``configs/experiment.yaml`` (thresholds, the paper's Table II);
no number is typed in by hand. Across seeds, "mean ± std" uses the population std (ddof 0), as
the per-run Table II metrics do across episodes.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ahrm_stack.cli import quiet_argv
from ahrm_stack.config import ConfigError, ExperimentConfig, PaperRow, load_extra
from ahrm_stack.learning.mechanisms import MECHANISMS, label
from ahrm_stack.names import OBJECTIVE_NAMES, PHASE_NAMES

OBJECTIVE_LETTERS = {name[0].upper(): name for name in OBJECTIVE_NAMES}  # A: avoid, M: manipulate, T: time


@dataclasses.dataclass
class RunRecord:
    """One (method, seed) run as the report sees it."""

    name: str
    method: str
    seed: int
    status: str  # done | failed | missing
    evaluation: dict | None = None  # evaluation.json of a finished run
    error: str | None = None
    seconds: float = float("nan")  # wall time of the task (train + evaluate), s
    episodes: dict | None = None  # columns of episodes.csv
    events: list = dataclasses.field(default_factory=list)  # events.jsonl


# ------------------------------------------------------------------ pure statistics


def mean_std(values: Sequence[float]) -> tuple[float, float, int]:
    """Mean, population std and count of the finite values (nan, nan, 0 when there are none)."""
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not finite:
        return float("nan"), float("nan"), 0
    return float(np.mean(finite)), float(np.std(finite)), len(finite)


def budget(grid: dict) -> str:
    """A grid's training budget per run, in words: its frames when set, else its episodes (grids
    written before ``experiment.frames`` existed have episodes only)."""
    frames = grid.get("frames", 0)
    return f"{frames:,} frames" if frames else f"{grid['episodes']} episodes"


def _window_fractions(success: Sequence[bool], window: int) -> np.ndarray:
    """Success fraction of every full window of ``window`` consecutive training episodes; entry k
    is the window that starts after k episodes (episodes k+1 .. k+window, 1-based)."""
    success = np.asarray(success, dtype=float)
    if len(success) < window:
        return np.empty(0)
    return np.convolve(success, np.ones(window), mode="valid") / window


def episodes_to_threshold(success: Sequence[bool], threshold: float, window: int) -> int | None:
    """Training episodes played before the policy first reached ``threshold``: the number of
    episodes before the first window of ``window`` consecutive episodes whose success fraction
    reaches ``threshold``. 0 when the first ``window`` episodes already do (the warm start met it:
    no training was needed); None when no window does (or none is full). Counting the window's own
    episodes as needed (this function used to return the window's last episode) made every run
    that met the threshold from the start read ``window``, its floor, whatever it learned."""
    hits = np.flatnonzero(_window_fractions(success, window) >= threshold - 1e-12)
    return int(hits[0]) if hits.size else None


def episodes_to_hold_threshold(success: Sequence[bool], threshold: float, window: int) -> int | None:
    """Training episodes played before the policy reached ``threshold`` for good: the start of the
    first window from which every later window reaches ``threshold`` up to the end of training
    (0: it never fell below). None when the last window is below ``threshold``: a run that met it
    and then lost it has not reached it."""
    fractions = _window_fractions(success, window)
    below = np.flatnonzero(fractions < threshold - 1e-12)
    if not fractions.size or (below.size and below[-1] == len(fractions) - 1):
        return None
    return int(below[-1] + 1) if below.size else 0


def orders_by_phase(orders: str) -> list[str]:
    """``"AMT AMT MAT"`` -> ``["avoid > manipulate > time", ..., "manipulate > avoid > time"]``."""
    phases = orders.split()
    try:
        return [" > ".join(OBJECTIVE_LETTERS[c] for c in phase) for phase in phases]
    except KeyError:
        raise ValueError(f"priority orders {orders!r}: expected letters A, M, T per phase") from None


def method_summary(runs: list[RunRecord]) -> dict:
    """Table II over the finished runs of one method: each metric's mean ± std over seeds."""
    evaluations = [r.evaluation for r in runs if r.status == "done" and r.evaluation]
    keys = ("successes", "success_rate", "touched_episodes", "time_mean", "travel_mean",
            "interventions_per_episode", "joint_limit_violations", "episodes")
    summary = {key: mean_std([e[key] for e in evaluations]) for key in keys}
    summary["seeds_done"] = len(evaluations)
    summary["seeds"] = len(runs)
    return summary


def rank_methods(summaries: dict[str, dict]) -> list[str]:
    """Methods with finished runs, best mean evaluation success rate first (ties: fewer touches)."""
    done = [m for m, s in summaries.items() if s["seeds_done"]]
    return sorted(done, key=lambda m: (-summaries[m]["success_rate"][0], summaries[m]["touched_episodes"][0]))


def findings(summaries: dict[str, dict], paper: dict[str, PaperRow], runs: list[RunRecord],
             reference: str = "ahrm") -> list[str]:
    """Plain statements about the outcome, the ``reference`` method's rank (``experiment.reference``,
    the paper's AHRM) and its distance to the paper first."""
    lines = []
    ranking = rank_methods(summaries)
    ref = label(reference)
    if reference not in summaries or not summaries[reference]["seeds_done"]:
        lines.append(f"{ref} has no finished run in this grid, so the paper's main claim is not tested here.")
    else:
        rate = summaries[reference]["success_rate"][0]
        position = ranking.index(reference) + 1
        top_rate = summaries[ranking[0]]["success_rate"][0]
        tied = [m for m in ranking if m != reference and summaries[m]["success_rate"][0] == rate]
        if top_rate == 0:
            lines.append("**No method succeeded in any evaluation episode**: the ranking below rests on "
                         "the tiebreak (fewer episodes touching an obstacle) alone.")
        if tied and rate == top_rate:
            touches = ", ".join(f"{label(m)} {summaries[m]['touched_episodes'][0]:.1f}"
                                for m in ranking if m == reference or m in tied)
            touched = summaries[reference]["touched_episodes"][0]
            if all(summaries[m]["touched_episodes"][0] == touched for m in tied):
                ahead, place = "it is not ahead of them", "they tie on it too"
            else:
                ahead = "it is not ahead of them" if position == 1 else "**it is not the best method here**"
                place = f"it ranks {position} of {len(ranking)}"
            lines.append(f"{ref} ties with {', '.join(label(m) for m in tied)} on mean "
                         f"evaluation success rate ({rate:.1%}): {ahead}. On the tiebreak (mean episodes "
                         f"touching an obstacle: {touches}) {place}.")
        elif position == 1:
            lines.append(f"{ref} ranks first of {len(ranking)} methods by mean evaluation success rate "
                         f"({rate:.1%}).")
        else:
            best = ranking[0]
            lines.append(f"**{ref} is not the best method here**: it ranks {position} of {len(ranking)} by "
                         f"mean evaluation success rate ({rate:.1%}); {label(best)} ranks "
                         f"first ({summaries[best]['success_rate'][0]:.1%}).")
        if reference in paper:
            target = paper[reference].successes / paper[reference].episodes
            if rate < target:
                lines.append(f"**{ref}'s mean success rate ({rate:.1%}) is below the paper's "
                             f"{target:.1%}.** The paper's result is not reproduced by this run.")
            else:
                lines.append(f"{ref}'s mean success rate ({rate:.1%}) reaches the paper's {target:.1%}.")
    for method in ranking:
        if method in paper:
            ours = summaries[method]["success_rate"][0]
            theirs = paper[method].successes / paper[method].episodes
            lines.append(f"{label(method)}: {ours:.1%} here vs {theirs:.1%} in the paper.")
    failed = [r.name for r in runs if r.status == "failed"]
    missing = [r.name for r in runs if r.status == "missing"]
    if failed:
        lines.append(f"**{len(failed)} run(s) failed** ({', '.join(failed)}); see 'Failed runs'. "
                     "The means above leave them out.")
    if missing:
        lines.append(f"{len(missing)} run(s) have not finished yet ({', '.join(missing)}).")
    return lines


# ------------------------------------------------------------------ loading


def _read_events(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def load_runs(out: Path, grid: dict) -> list[RunRecord]:
    from ahrm_stack.learning.diagnostics import read_episodes

    records = []
    for spec in grid["runs"]:
        run_dir = Path(spec["run_dir"])
        record = RunRecord(spec["name"], spec["method"], spec["seed"], "missing")
        if (run_dir / "done.json").is_file():
            done = json.loads((run_dir / "done.json").read_text())
            record.status, record.evaluation, record.seconds = "done", done["evaluation"], done["seconds"]
        elif (run_dir / "failed.json").is_file():
            failed = json.loads((run_dir / "failed.json").read_text())
            record.status, record.error = "failed", failed["error"]
        try:
            record.episodes = read_episodes(run_dir)
        except (FileNotFoundError, ValueError):
            record.episodes = None
        record.events = _read_events(run_dir / "events.jsonl")
        records.append(record)
    return records


# ------------------------------------------------------------------ formatting


def _pm(stat: tuple[float, float, int], digits: int, percent: bool = False) -> str:
    mean, std, n = stat
    if n == 0:
        return "—"
    if percent:
        return f"{100 * mean:.{digits}f} ± {100 * std:.{digits}f} %"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _time(evaluation: dict) -> str:
    """Time to success of one evaluation, '—' without successes."""
    if not evaluation["successes"]:
        return "— (no success)"
    return f"{evaluation['time_mean']:.2f} ± {evaluation['time_std']:.2f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _table2_rows(methods: list[str], summaries: dict, paper: dict[str, PaperRow], scripted: dict | None) -> list[list[str]]:
    rows = []
    for method in methods:
        s = summaries[method]
        name = label(method)
        rows.append([f"{name} (here, {s['seeds_done']}/{s['seeds']} seeds)", _pm(s["successes"], 1),
                     _pm(s["success_rate"], 1, percent=True), _pm(s["touched_episodes"], 1),
                     _pm(s["time_mean"], 2), _pm(s["travel_mean"], 4)])
        if method in paper:
            p = paper[method]
            rows.append([f"{name} (paper)", str(p.successes), f"{100 * p.successes / p.episodes:.1f} %",
                         str(p.touched), f"{p.time[0]} ± {p.time[1]}", f"{p.travel[0]} ± {p.travel[1]}"])
    if scripted is not None:
        e = scripted
        rows.append(["scripted controller (mink)", str(e["successes"]), f"{100 * e['success_rate']:.1f} %",
                     str(e["touched_episodes"]), _time(e),
                     f"{e['travel_mean']:.4f} ± {e['travel_std']:.4f}"])
    return rows


def _run_rows(runs: list[RunRecord]) -> list[list[str]]:
    rows = []
    for r in runs:
        e = r.evaluation
        if e is None:
            rows.append([r.name, r.status] + ["—"] * 7)
            continue
        rows.append([r.name, r.status, f"{e['successes']}/{e['episodes']}", str(e["touched_episodes"]),
                     _time(e), f"{e['travel_mean']:.4f} ± {e['travel_std']:.4f}",
                     f"{e['interventions_per_episode']:.1f}", str(e["joint_limit_violations"]),
                     f"{r.seconds / 60:.1f}"])
    return rows


def _order_rows(runs: list[RunRecord]) -> list[list[str]]:
    rows = []
    for r in runs:
        if r.episodes is None:
            continue
        final = orders_by_phase(str(r.episodes["orders"][-1]))
        changes = [e for e in r.events if e["kind"] == "order_changed"]
        locks = {e["phase"]: e["episode"] for e in r.events if e["kind"] == "order_locked"}
        lock_text = ", ".join(f"phase {k} at {v}" for k, v in sorted(locks.items())) or "none"
        rows.append([r.name] + final + [str(len(changes)), lock_text])
    return rows


def _threshold_rows(runs: list[RunRecord], methods: list[str], threshold: float, window: int) -> list[list[str]]:
    def mean_of(values: list[int], seeds: int) -> str:
        return f"{np.mean(values):.0f} ({len(values)}/{seeds} seeds)" if values else f"never (0/{seeds} seeds)"

    rows = []
    for method in methods:
        per_seed, reached, held = [], [], []
        for r in runs:
            if r.method != method or r.episodes is None:
                continue
            success = r.episodes["success"]
            first = episodes_to_threshold(success, threshold, window)
            kept = episodes_to_hold_threshold(success, threshold, window)
            last = _window_fractions(success, window)
            end = f"last {window}: {last[-1]:.0%}" if last.size else f"{len(success)} episodes"
            per_seed.append(f"seed {r.seed}: " + (f"reached after {first}" if first is not None else
                                                  f"not reached in {len(success)}")
                            + (f", held from {kept}" if kept is not None else
                               f", not held ({end})" if first is not None else ""))
            reached += [first] if first is not None else []
            held += [kept] if kept is not None else []
        seeds = len(per_seed)
        rows.append([label(method), mean_of(reached, seeds), mean_of(held, seeds),
                     "; ".join(per_seed) or "—"])
    return rows


def _safety_rows(runs: list[RunRecord], methods: list[str], summaries: dict, scripted: dict | None) -> list[list[str]]:
    rows = []
    for method in methods:
        s = summaries[method]
        train_interventions = [np.mean(r.episodes["interventions"]) for r in runs
                               if r.method == method and r.episodes is not None]
        terminations = [np.mean(r.episodes["constraint_terminated"]) for r in runs
                        if r.method == method and r.episodes is not None]
        rows.append([label(method), _pm(s["interventions_per_episode"], 1),
                     _pm(s["touched_episodes"], 1), _pm(s["joint_limit_violations"], 1),
                     _pm(mean_std(train_interventions), 1), _pm(mean_std(terminations), 2)])
    if scripted is not None:
        rows.append(["scripted controller", f"{scripted['interventions_per_episode']:.1f}",
                     str(scripted["touched_episodes"]), str(scripted["joint_limit_violations"]), "—", "—"])
    return rows


def _suite_lines(out: Path, grid: dict, runs: list[RunRecord], methods: list[str],
                 experiment: ExperimentConfig, split: str) -> list[str]:
    """The evaluation-suite section (when the grid evaluated the suite): per-family tables for
    every method, the clone and the scripted controller, paired bootstrap differences, ranking."""
    from ahrm_stack.suite_report import rank, read_suite, read_support, suite_section

    columns: dict[str, list] = {}
    for method in methods:
        seeds = [read_suite(Path(grid["out"]) / "runs" / r.name / "suite")
                 for r in sorted(runs, key=lambda r: r.seed) if r.method == method and r.status == "done"]
        if any(s is not None for s in seeds):
            columns[method] = [s for s in seeds if s is not None]
    if not columns:
        return []
    clone = [read_suite(Path(grid["out"]) / "runs" / r.name / "suite-clone")
             for r in sorted(runs, key=lambda r: r.seed) if r.method == methods[0] and r.status == "done"]
    if any(c is not None for c in clone):
        columns["clone"] = [c for c in clone if c is not None]
    scripted = read_suite(out / "scripted" / "suite")
    if scripted is not None:
        columns["scripted"] = [scripted]
    families = sorted({f for seeds in columns.values() for s in seeds for f in s},
                      key=lambda f: next((i for i, s in enumerate(_suite_order()) if s == f), 99))
    compared = [m for m in methods if m in columns]
    order = rank(columns, families, compared)
    reference = experiment.reference
    baselines = [m for m in compared if m in MECHANISMS and not MECHANISMS[m].hierarchical]  # LS
    lines = ["", "## Evaluation suite", "",
             f"Every run's final deterministic policy on every family of the evaluation suite "
             f"(`configs/layouts.yaml`, {grid['eval_episodes']} episodes each, each family on its own "
             f"seeds of the **{split} split**); `clone` is the first method's policy before any PPO update (the warm start: "
             "behaviour cloning, plus DAgger when `train.dagger_rounds` > 0), `scripted` the scripted "
             "controller on the same episodes.",
             "", f"Ranking on the suite (success, then fewer touching episodes): "
             f"{' > '.join(label(m) for m in order)}. "
             + (f"{label(reference)} ranks first" if order and order[0] == reference
                else f"{label(reference)} does not rank first")
             + ("" if not baselines else f" and {label(baselines[0])} last" if order[-1] == baselines[0]
                else f"; {label(baselines[0])} is not last")
             + f" (the paper: {label(reference)} first, LS last). Where the intervals below include 0 the "
             "difference is not resolved by these seeds.", ""]
    support: dict[str, str] = {}
    for r in sorted(runs, key=lambda r: r.seed):  # the grid's runs share one training config
        if r.status == "done" and not support:
            support = read_support(Path(grid["out"]) / "runs" / r.name / "suite")
    return lines + suite_section(columns, families, compared, experiment.bootstrap_samples,
                                 support=support or None)


def _suite_order() -> list[str]:
    from ahrm_stack.env.layout_catalog import suite_names
    return suite_names()


def write_report(out: Path | str, experiment: ExperimentConfig | None = None) -> Path:
    """Write ``report.md`` and the figures into ``out`` (an experiment folder); returns the report."""
    out = Path(out)
    if not (out / "grid.json").is_file():
        raise ConfigError(f"{out / 'grid.json'} not found: is {out} an experiment folder?")
    grid = json.loads((out / "grid.json").read_text())
    split = grid.get("split", "validation")  # grids written before the split: the validation seeds
    if experiment is None:
        experiment = load_extra(ExperimentConfig, "experiment", grid.get("experiment_overrides", []))
    runs = load_runs(out, grid)
    methods = list(grid["methods"])
    summaries = {m: method_summary([r for r in runs if r.method == m]) for m in methods}
    scripted_done = out / "scripted" / "done.json"
    scripted = json.loads(scripted_done.read_text())["evaluation"] if scripted_done.is_file() else None
    paper = experiment.paper_table2

    from ahrm_stack.report_plots import plot_curves, plot_objectives, plot_orders
    figures = [plot_curves(out, runs, methods, experiment.curve_window),
               plot_objectives(out, runs, methods, experiment.curve_window),
               plot_orders(out, runs, methods)]

    lines = [f"# AHRM experiment: {', '.join(label(m) for m in methods)}", "",
             f"Generated {time.strftime('%Y-%m-%d %H:%M')} by `python -m ahrm_stack.experiment` from the "
             f"files in this folder. {grid['seeds']} seed(s) per method, {budget(grid)} of "
             f"training per run, {grid['eval_episodes']} deterministic evaluation episodes per run on the "
             f"`{grid['layout']}` layout, **{split} split** (configs/seeds.yaml; "
             + ("sealed: read only by this final evaluation of the frozen policies" if split == "test" else
                "the seeds of interim evaluations and studies, not the sealed test split")
             + "), every command through the safety filter.",
             f"Training overrides: `{' '.join(grid['train_overrides']) or 'none'}`.", "",
             "## Findings", ""]
    lines += [f"- {line}" for line in findings(summaries, paper, runs, experiment.reference)]
    lines += ["", f"## Table II: this reproduction ({split} split, mean ± std over seeds) and the paper", "",
              "Successes and touches are per 40-episode evaluation in the paper and per "
              f"{grid['eval_episodes']}-episode evaluation here. Time: mean time to success (over "
              "successful episodes), s; cube travel: mean path length of the cube's centre, m. Here "
              "each cell is the mean ± std over seeds of the per-run figure. The paper ran V-REP; "
              "this is MuJoCo.", ""]
    lines += _table(["Method", "Successes", "Success rate", "Touch obstacles", "Time (s)", "Cube travel (m)"],
                    _table2_rows(methods, summaries, paper, scripted))
    lines += ["", "### Per run", ""]
    lines += _table(["Run", "Status", "Successes", "Touched", "Time (s)", "Cube travel (m)",
                     "Interventions/episode", "Joint-limit violations", "Wall time (min)"], _run_rows(runs))
    lines += _suite_lines(out, grid, runs, methods, experiment, split)
    lines += ["", "## Learned priority orders per phase (Fig. 3)", "",
              "The mechanism's order at the end of training (highest priority first), the number of "
              "order changes and where the orders were locked. Only AHRM determines its orders; "
              "MHRM's are set per phase, FHRM's fixed, LS has none (its column shows the unused "
              "default).", ""]
    lines += _table(["Run", *(f"Phase {k} ({name})" for k, name in enumerate(PHASE_NAMES, 1)),
                     "Order changes", "Locked"], _order_rows(runs))
    lines += ["", f"## Episodes to reach {experiment.success_threshold:.0%} success", "",
              f"Training episodes played before the first window of {experiment.success_window} consecutive "
              f"training episodes (stochastic training policy) with {experiment.success_threshold:.0%} "
              "success (reached; 0: from the first episode, i.e. the warm start already met it), and before "
              "the window from which every later window meets it up to the end of training (held; a run "
              "that met it and then lost it never held it). Means over the seeds that reached it.", ""]
    lines += _table(["Method", "Reached after", "Held from", "Per seed"],
                    _threshold_rows(runs, methods, experiment.success_threshold, experiment.success_window))
    lines += ["", "## Safety", "",
              "Evaluation: safety-filter interventions per episode (commands the QP changed), episodes "
              "touching an obstacle, joint-limit violations (steps outside the position limits, from "
              "the simulator; must be 0). Training: interventions per episode and the share of "
              "episodes ended by the priority constraint.", ""]
    lines += _table(["Method", "Interventions/episode (eval)", "Touching episodes (eval)",
                     "Joint-limit violations (eval)", "Interventions/episode (training)",
                     "Constraint terminations (training share)"],
                    _safety_rows(runs, methods, summaries, scripted))
    lines += ["", "## Figures", ""]
    lines += [f"![{f.stem}]({f.name})" for f in figures if f is not None]
    videos = sorted((out / "videos").glob("*.mp4")) if (out / "videos").is_dir() else []
    lines += ["", "## Videos", ""]
    lines += [f"- [{v.stem}](videos/{v.name})" for v in videos] or ["- none"]
    failed = [r for r in runs if r.status == "failed"]
    if failed:
        lines += ["", "## Failed runs", ""]
        for r in failed:
            lines += [f"- `{r.name}`: {r.error} (traceback in `runs/{r.name}/failed.json`, output in "
                      f"`runs/{r.name}/log.txt`)"]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    args = quiet_argv(argv)  # --verbose: the libraries' warnings too
    if len(args) != 1 or args[0].startswith("-"):
        print("usage: python -m ahrm_stack.report [--verbose] OUT_DIR", file=sys.stderr)
        return 2
    try:
        print(write_report(Path(args[0])))
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
