"""The planner-free runs of issue 56 (item 2) in one table: does the start curriculum rise, and what
do the interim evaluations win? (registered in docs/protocol.md; report docs/planner-free.md)

    python studies/planner_free.py summarise NAME=RUN_DIR ... [--evaluation NAME=DIR ...] [--out docs/planner-free]

``summarise`` copies each run's ``config.yaml``, ``evaluations.csv``, ``timing.json`` and its
``batches.csv`` (gzip) into ``--out/runs/NAME/`` and writes ``--out/table.md`` from the copies
(nothing typed by hand): per run, the frames trained, the first frames at which the curriculum
level left 0 and reached 1, the batches' success, constraint and touch shares over the last 20
batches, and each interim evaluation's wins and touching (40 validation episodes). A run folder
with ``batches.csv.gz`` (a committed copy) is read as it is. ``--evaluation`` copies standalone
evaluations (``evaluation.csv``/``.json``) into ``--out/evaluations/NAME/`` and adds their table:
wins, touching, and touching after the planner's lane and after the other one. Validation seeds only.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import shutil
import sys
from pathlib import Path

import numpy as np

from ahrm_stack.cli import named_folders

DEFAULT_OUT = Path("docs/planner-free")
def _rows(run_dir: Path, name: str) -> list[dict]:
    for path, opener in ((run_dir / f"{name}.gz", gzip.open), (run_dir / name, open)):
        if path.is_file():
            with opener(path, "rt", newline="") as handle:  # type: ignore[operator]
                return list(csv.DictReader(handle))
    return []


def _mean(rows: list[dict], key: str) -> float:
    values = [float(r[key]) for r in rows if r.get(key, "") != ""]
    return float(np.mean(values)) if values else float("nan")


def summarise_run(run_dir: Path) -> dict:
    """One run's row, from its CSV files."""
    batches = _rows(run_dir, "batches.csv")
    evaluations = _rows(run_dir, "evaluations.csv")
    level = [(int(r["frames"]), float(r["curriculum_level"])) for r in batches]
    tail = batches[-20:]
    return {
        "frames": level[-1][0] if level else 0,
        "rose": next((f for f, v in level if v > 0), None),
        "full": next((f for f, v in level if v >= 1.0), None),
        "level": level[-1][1] if level else float("nan"),
        "success": _mean(tail, "success_share"),
        "constraint": _mean(tail, "constraint_share"),
        "touch": _mean(tail, "touch_share"),
        "evaluations": [(int(r["frames"]), int(r["successes"]), int(r["touched_episodes"])) for r in evaluations],
    }


def table(runs: dict[str, dict]) -> str:
    lines = ["| run | frames | curriculum left 0 at | reached 1 at | level at end | success share "
             "(last 20 batches) | constraint share | touch share | evaluations: wins/40 (touching) at frames |",
             "|---|---|---|---|---|---|---|---|---|"]

    def at(value: int | None) -> str:
        return "never" if value is None else f"{value:,}"

    for name, s in runs.items():
        evaluations = "; ".join(f"{w} ({t}) at {f // 1000}k" for f, w, t in s["evaluations"]) or "—"
        lines.append(f"| {name} | {s['frames']:,} | {at(s['rose'])} | {at(s['full'])} | {s['level']:.2f} | "
                     f"{s['success']:.3f} | {s['constraint']:.2f} | {s['touch']:.2f} | {evaluations} |")
    return "\n".join(lines) + "\n"


def summarise_evaluation(folder: Path) -> dict:
    """A standalone evaluation's row (``python -m ahrm_stack.evaluate``'s ``evaluation.csv``): wins,
    touching, the cube's lane against the planner's (agreement, and touching after each), time."""
    rows = _rows(folder, "evaluation.csv")
    won = [r for r in rows if r["success"] == "True"]
    pushed = [r for r in rows if r.get("lane_agrees", "") in ("True", "False")]
    wrong = [r for r in pushed if r["lane_agrees"] == "False"]
    return {"episodes": len(rows), "wins": len(won),
            "touched": sum(int(r["touched_steps"]) > 0 for r in rows),
            "pushed": len(pushed), "agree": len(pushed) - len(wrong), "wrong": len(wrong),
            "wrong_touched": sum(int(r["touched_steps"]) > 0 for r in wrong),
            "right_touched": sum(int(r["touched_steps"]) > 0 for r in pushed if r["lane_agrees"] == "True"),
            "time": _mean(won, "time_to_success")}


def evaluation_table(evaluations: dict[str, dict]) -> str:
    lines = ["| evaluation | wins | touching | lane agreement (pushed episodes) | touching after the planner's "
             "lane | after the other lane | time to success (s, won) |", "|---|---|---|---|---|---|---|"]
    for name, e in evaluations.items():
        lines.append(f"| {name} | {e['wins']}/{e['episodes']} | {e['touched']} | {e['agree']}/{e['pushed']} | "
                     f"{e['right_touched']}/{e['agree']} | {e['wrong_touched']}/{e['wrong']} | {e['time']:.2f} |")
    return "\n".join(lines) + "\n"


def write_table(out: Path) -> str:
    runs = {path.name: summarise_run(path) for path in sorted((out / "runs").iterdir()) if path.is_dir()}
    text = ("<!-- generated by `python studies/planner_free.py summarise`; do not edit -->\n"
            "Evaluations: 40 episodes of the validation split (configs/seeds.yaml) each; the test split "
            "is not read.\n\n" + table(runs))
    if (out / "evaluations").is_dir():
        evaluations = {path.name: summarise_evaluation(path)
                       for path in sorted((out / "evaluations").iterdir()) if path.is_dir()}
        text += ("\nStandalone evaluations (`python -m ahrm_stack.evaluate RUN --episodes 40 [--config ...]`, "
                 "each folder's `evaluation.json` names the policy and the config), the same 40 validation "
                 "episodes; lanes: the side the cube left by against the scripted controller's plan:\n\n"
                 + evaluation_table(evaluations))
    (out / "table.md").write_text(text)
    return text


def _copy(source: Path, target: Path) -> None:
    """Copy unless ``source`` is already ``target`` (a committed copy named again)."""
    if not (target.exists() and source.resolve() == target.resolve()):
        shutil.copyfile(source, target)


def summarise(named: dict[str, Path], out: Path, evaluations: dict[str, Path] | None = None) -> str:
    for name, folder in (evaluations or {}).items():
        target = out / "evaluations" / name
        target.mkdir(parents=True, exist_ok=True)
        for file in ("evaluation.csv", "evaluation.json"):
            _copy(folder / file, target / file)
    for name, run_dir in named.items():
        target = out / "runs" / name
        target.mkdir(parents=True, exist_ok=True)
        for file in ("config.yaml", "evaluations.csv", "timing.json"):
            if (run_dir / file).is_file():
                _copy(run_dir / file, target / file)
        if (run_dir / "batches.csv").is_file():
            with open(run_dir / "batches.csv", "rb") as source, \
                    gzip.GzipFile(target / "batches.csv.gz", "wb", mtime=0) as sink:
                shutil.copyfileobj(source, sink)
        elif (run_dir / "batches.csv.gz").is_file():
            _copy(run_dir / "batches.csv.gz", target / "batches.csv.gz")
    return write_table(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    summary = sub.add_parser("summarise")
    summary.add_argument("runs", nargs="*", help="NAME=RUN_DIR")
    summary.add_argument("--evaluation", nargs="*", default=[], metavar="NAME=DIR",
                         help="standalone evaluation folders (evaluation.csv and .json) to tabulate too")
    summary.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    print(summarise(named_folders(args.runs), args.out, named_folders(args.evaluation)), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
