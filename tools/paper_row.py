"""The paper's claim in one row (issue 42, item 6; docs/protocol.md, "the paper's setting in one row").

    python tools/paper_row.py summarise RUN [RUN ...] [--out docs/paper-row]

Each RUN is a training run folder of ``profile=paper`` with or without one registered change
(``config.yaml``, ``episodes.csv``, ``batches.csv``, ``evaluations.csv``: its interim evaluations on
validation episodes). ``summarise`` copies those files to ``OUT/runs/<run>/`` (the first two
gzipped) and writes ``OUT/table.md`` from the copies, per run: the training so far (episodes,
frames, training successes, PPO gradient steps), the interim evaluation at the paper's budget (the
last one at or before episode 300), the first evaluation at or above the paper's 37/40 (its frames
and episode) or "never" with the frames reached, and the best evaluation: all of it on validation
episodes. Then the answer's line (:func:`answer`), from its one evaluation on the sealed test split
(``OUT/test/``, beside the scripted controller's, ``OUT/test-scripted/``); that file is why this
script lives in ``tools/``, not ``studies/``, which may not name the test split.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import io
import json
import shutil
import sys
from pathlib import Path

import yaml


def _paper() -> tuple[int, int, int]:
    """The paper's claim, from where the project keeps it: its training budget (``train.episodes`` of
    ``profile=paper``) and AHRM's successes of its evaluation episodes (``configs/experiment.yaml``
    ``paper_table2``)."""
    from ahrm_stack.config import ExperimentConfig, load_config, load_extra

    row = load_extra(ExperimentConfig, "experiment").paper_table2["ahrm"]
    return load_config(["profile=paper"]).train.episodes, row.successes, row.episodes


PAPER_EPISODES, PAPER_SUCCESSES, PAPER_EVALUATIONS = _paper()  # 300, 37, 40
#: keys a run sets that are not part of its setting (its budget, seed and bookkeeping)
BOOKKEEPING = ("schema_version", "train.seed", "train.episodes", "train.frames", "train.eval_every",
               "train.eval_every_frames", "train.eval_episodes")


def _flat(mapping: dict, prefix: str = "") -> dict[str, object]:
    flat: dict[str, object] = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _paper_setting() -> dict[str, object]:
    from ahrm_stack.config import load_config

    return _flat(load_config(["profile=paper"]).to_dict())


def _rows(run_dir: Path, name: str) -> list[dict[str, str]]:
    """The rows of ``run_dir/name`` or of its gzipped copy; [] when neither exists."""
    if (run_dir / name).is_file():
        text = (run_dir / name).read_text()
    elif (run_dir / f"{name}.gz").is_file():
        with gzip.open(run_dir / f"{name}.gz", "rt") as handle:
            text = handle.read()
    else:
        return []
    return list(csv.DictReader(io.StringIO(text)))


def collect(runs: list[Path], out: Path) -> list[Path]:
    """Copy each run's ``config.yaml`` and ``evaluations.csv``, and its ``episodes.csv`` and
    ``batches.csv`` gzipped, to ``OUT/runs/<run>/``; returns the copies' folders."""
    copies = []
    for run_dir in runs:
        for name in ("config.yaml", "evaluations.csv"):
            if not (run_dir / name).is_file():
                raise SystemExit(f"error: {run_dir / name}: no such file (is {run_dir} a training run?)")
        target = out / "runs" / run_dir.name
        target.mkdir(parents=True, exist_ok=True)
        for name in ("config.yaml", "evaluations.csv"):
            shutil.copyfile(run_dir / name, target / name)
        for name in ("episodes.csv", "batches.csv"):
            if (run_dir / name).is_file():
                with open(run_dir / name, "rb") as source, open(target / f"{name}.gz", "wb") as raw:
                    # no time stamp: same data, same bytes
                    with gzip.GzipFile(filename=name, fileobj=raw, mode="wb", mtime=0) as sink:
                        shutil.copyfileobj(source, sink)
        copies.append(target)
    return copies


def _setting(config: dict, paper: dict[str, object]) -> str:
    """What the run changes on top of ``profile=paper``: each key of its ``config.yaml`` whose value
    differs from the profile's as ``configs/`` has it now (keys the run's file lacks, added since it
    was written, and :data:`BOOKKEEPING` are not compared), or "the paper's setting"."""
    changed = [f"{key}={value}".replace(" ", "") for key, value in _flat(config).items()
               if key in paper and key not in BOOKKEEPING and value != paper[key]]
    return ", ".join(changed) or "the paper's setting"


def _evaluation(row: dict[str, str]) -> str:
    return (f"{row['successes']}/{row['episodes']} ({row['touched_episodes']} touching) at episode "
            f"{row['episode']}, {int(row['frames']):,} frames")


def table(copies: list[Path]) -> str:
    lines = ["Generated by `python tools/paper_row.py summarise` from the run data in `runs/`. Seeds: the "
             "validation split of configs/seeds.yaml (interim evaluations, 40 episodes of the paper's one "
             "layout); the sealed test split is read only by the answer's final evaluation.", "",
             "| run | setting: its changes to profile=paper | trained: episodes, frames, training successes, "
             "PPO gradient steps | at the paper's budget "
             f"(last evaluation ≤ episode {PAPER_EPISODES}) | ≥ {PAPER_SUCCESSES}/{PAPER_EVALUATIONS} after "
             f"{PAPER_EPISODES} episodes? | first ≥ {PAPER_SUCCESSES}/{PAPER_EVALUATIONS} | best |",
             "|---|---|---|---|---|---|---|"]
    paper = _paper_setting()
    for run_dir in copies:
        config = yaml.safe_load((run_dir / "config.yaml").read_text())
        episodes = _rows(run_dir, "episodes.csv")
        steps = sum(int(row["updates"]) for row in _rows(run_dir, "batches.csv") if row.get("updates"))
        with open(run_dir / "evaluations.csv") as handle:
            evaluations = list(csv.DictReader(handle))
        frames = int(episodes[-1]["frames"]) if episodes else 0
        won = sum(row["success"] == "True" for row in episodes)
        budget = [row for row in evaluations if int(row["episode"]) <= PAPER_EPISODES]
        at_budget = _evaluation(budget[-1]) if budget else "–"
        reached = [row for row in evaluations if int(row["successes"]) >= PAPER_SUCCESSES]
        first = _evaluation(reached[0]) if reached else f"never (up to {frames:,} frames)"
        best = max(evaluations, key=lambda row: (int(row["successes"]), -int(row["frames"])), default=None)
        if best is None:
            best_text = "–"
        elif int(best["successes"]) == 0:
            best_text = f"0 at all {len(evaluations)} evaluations"
        else:
            best_text = _evaluation(best)
        if len(episodes) < PAPER_EPISODES:
            verdict = f"not yet ({len(episodes)} of {PAPER_EPISODES} episodes)"
        else:
            verdict = "yes" if budget and int(budget[-1]["successes"]) >= PAPER_SUCCESSES else "no"
        lines.append(f"| {run_dir.name} | {_setting(config, paper)} | {len(episodes)}, {frames:,}, {won}, {steps:,} | "
                     f"{at_budget} | {verdict} | {first} | {best_text} |")
    return "\n".join(lines) + "\n"


def _episodes(folder: Path) -> list[tuple[bool, bool]]:
    with open(folder / "evaluation.csv") as handle:
        return [(row["success"] == "True", int(row["touched_steps"]) > 0) for row in csv.DictReader(handle)]


def answer(out: Path) -> str:
    """The answer's line, from its one evaluation on the test split (``OUT/test/``, by
    ``python -m ahrm_stack.evaluate RUN --split test --episodes 40 --out OUT/test``) and the scripted
    controller's on the same episodes (``OUT/test-scripted/``): successes with the exact 95 %
    interval, touching, and the exact sign test on the episodes only one of the two won; "" before
    that evaluation exists."""
    from scipy.stats import binomtest

    if not (out / "test" / "evaluation.json").is_file():
        return ""
    summary = json.loads((out / "test" / "evaluation.json").read_text())
    if summary.get("split") != "test":
        raise SystemExit(f"error: {out / 'test' / 'evaluation.json'}: split {summary.get('split')!r}, not test")
    mine, theirs = _episodes(out / "test"), _episodes(out / "test-scripted")
    if len(mine) != len(theirs):
        raise SystemExit(f"error: {out / 'test-scripted'}: {len(theirs)} episodes, the policy's {len(mine)}")
    won = sum(w for w, _ in mine)
    low, high = binomtest(won, len(mine)).proportion_ci(0.95, method="exact")
    only_mine = sum(a and not b for (a, _), (b, _) in zip(mine, theirs))
    only_theirs = sum(b and not a for (a, _), (b, _) in zip(mine, theirs))
    p = binomtest(only_mine, only_mine + only_theirs).pvalue if only_mine + only_theirs else 1.0
    return (f"\nThe answer, `{Path(summary['policy']).name}`'s frozen final policy, evaluated once on the "
            f"**test split** ({len(mine)} episodes of the paper's layout): {won}/{len(mine)} "
            f"[{low:.1%}, {high:.1%}], {sum(t for _, t in mine)} touching; the scripted controller on the "
            f"same episodes {sum(w for w, _ in theirs)}/{len(theirs)}, {sum(t for _, t in theirs)} touching; "
            f"won by one only: policy {only_mine} / scripted {only_theirs} (exact sign test p = {p:.2g}).\n")


def summarise(runs: list[Path], out: Path) -> Path:
    copies = collect(runs, out)
    (out / "table.md").write_text(table(sorted(copies)) + answer(out))
    return out / "table.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_summary = sub.add_parser("summarise", help="collect the runs' data and write table.md")
    p_summary.add_argument("runs", type=Path, nargs="+", help="training run folders")
    p_summary.add_argument("--out", type=Path, default=Path("docs/paper-row"))
    args = parser.parse_args(argv)
    path = summarise(args.runs, args.out)
    print(path.read_text(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
