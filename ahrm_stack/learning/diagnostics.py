"""Diagnostics of a training run, plotted from its ``episodes.csv``: where a failing run fails.

    python -m ahrm_stack.learning.diagnostics RUN_DIR [RUN_DIR ...]

One PNG per run (``diagnostics.png`` in the run folder): success and failure modes (never reached
the cube, reached it but could not push, hit obstacles, stalled), closest approach of the pusher to
the cube, largest cube displacement, time in each phase, each ±1 component's sum per phase, the
learning return, constraint terminations and safety-filter interventions — all per episode, with a
moving average.
"""

from __future__ import annotations

import ast
import csv
import sys
from pathlib import Path

import numpy as np

from ahrm_stack.names import OBJECTIVE_NAMES as OBJECTIVES

FAILURE_MODES = ("success", "touched", "never reached the cube", "reached the cube, could not push",
                 "hit obstacles", "stalled")
REQUIRED = ("episode", "success", "constraint_terminated", "failure_mode", "learning_return",
            "closest_approach", "cube_displacement", "phase_steps", "touched_steps", "interventions",
            "component_sums", "levels")  # the columns the plot reads


def read_episodes(run_dir: Path) -> dict[str, np.ndarray]:
    """Columns of ``episodes.csv`` as arrays (lists parsed)."""
    path = Path(run_dir) / "episodes.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no episodes.csv; is {run_dir} a run folder?")
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        header = reader.fieldnames or []
        rows = list(reader)
    needed = [key for key in REQUIRED if key not in header]
    if header and needed:
        raise ValueError(f"{path}: the first line is not the header (no column {needed[0]!r}: "
                         f"{','.join(header)[:60]!r}); `python -m ahrm_stack.train --resume "
                         f"{Path(run_dir)}` repairs it")
    if not rows:
        raise ValueError(f"{path} holds no episodes yet")
    out: dict[str, np.ndarray] = {}
    for key in header:
        values = [row[key] for row in rows]
        try:
            if key in ("phase_steps", "component_sums", "levels"):
                out[key] = np.array([ast.literal_eval(v) for v in values], dtype=float)
            elif key in ("success", "constraint_terminated", "constraint_excluded"):
                out[key] = np.array([v == "True" for v in values])
            elif key in ("phases_visited", "failure_mode", "orders"):
                out[key] = np.array(values)
            elif key == "lane_agrees":  # True, False, or blank (not pushed along a lane): 1, 0, NaN
                out[key] = np.array([{"True": 1.0, "False": 0.0, "": np.nan}[v] for v in values])
            else:
                out[key] = np.array([float(v) for v in values])
        except (ValueError, SyntaxError, TypeError, KeyError) as error:
            raise ValueError(f"{path}: column {key!r} holds a malformed value ({error})") from None
    return out


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start)."""
    values = np.asarray(values, dtype=float)
    cumulative = np.concatenate([[0.0], np.cumsum(values)])
    index = np.arange(1, len(values) + 1)
    start = np.maximum(index - window, 0)
    return (cumulative[index] - cumulative[start]) / (index - start)


def pyplot():
    """matplotlib's pyplot on the Agg backend (files only; no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, dpi: int) -> Path:
    """Lay ``fig`` out, write it to ``path`` (PNG at ``dpi``), close it; returns ``path``."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def episode_shares(rows: list[dict]) -> dict[str, float | str]:
    """A batch's learning diagnostics from the episodes that ended in it (``episodes.csv`` rows):
    the shares won, that reached the cube (entered phase 3, as :meth:`EpisodeSummary.failure_mode`
    counts it), that touched an obstacle and that the hierarchy's constraint cut (or, checked at
    the end, left out of the update), and among those
    that pushed the cube along a lane the share by the planner's lane. Blank ("") where no episode
    counts."""
    def share(values: list[bool]) -> float | str:
        return float(np.mean(values)) if values else ""

    lanes = [bool(r["lane_agrees"]) for r in rows if r.get("lane_agrees") is not None]
    return {"success_share": share([bool(r["success"]) for r in rows]),
            "reach_share": share([r["phase_steps"][2] > 0 for r in rows]),
            "touch_share": share([r["touched_steps"] > 0 for r in rows]),
            "constraint_share": share([bool(r["constraint_terminated"]) or bool(r.get("constraint_excluded"))
                                       for r in rows]),
            "lane_agreement": share(lanes)}


def read_batches(run_dir: Path) -> dict[str, np.ndarray]:
    """The numeric columns of ``batches.csv`` (blank cells NaN); empty without the file or rows.
    Runs before a column existed lack it."""
    path = Path(run_dir) / "batches.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    if not rows:
        return {}

    def number(text: str) -> float:
        try:
            return float(text)
        except ValueError:
            return float("nan")

    return {key: np.array([number(row[key] or "") for row in rows]) for key in rows[0]}


BATCH_SHARES = ("success_share", "reach_share", "touch_share", "constraint_share", "lane_agreement")


def _plot_batches(axes, batches: dict[str, np.ndarray]) -> None:
    """The bottom row: PPO's approximate KL and the policy's std; the batch shares; the start
    curriculum's level, all against frames."""
    frames = batches["frames"]
    ax = axes[0]
    if "kl_approx" in batches:
        ax.plot(frames, batches["kl_approx"], label="approximate KL")
    ax.set_yscale("log")
    ax.set_title("PPO: approximate KL (log) and policy std")
    twin = ax.twinx()
    if "std" in batches:
        twin.plot(frames, batches["std"], color="tab:red", label="std")
    twin.set_ylabel("std", color="tab:red")
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[1]
    for key in BATCH_SHARES:
        if key in batches:
            ax.plot(frames, batches[key], label=key.replace("_", " "))
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("per batch: shares of its episodes")
    ax.legend(fontsize=7)
    ax = axes[2]
    if "curriculum_level" in batches:
        ax.plot(frames, batches["curriculum_level"], label="start curriculum level")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("start curriculum level")
    for ax in axes:
        ax.set_xlabel("frames")
        ax.grid(alpha=0.3)


def plot_run(run_dir: Path, window: int = 20) -> Path:
    plt = pyplot()
    data = read_episodes(run_dir)
    episode = data["episode"]
    batches = read_batches(run_dir)
    fig, axes = plt.subplots(4 if batches else 3, 3, figsize=(15, 15 if batches else 11))
    fig.suptitle(f"{Path(run_dir).name}: {len(episode)} episodes", fontsize=13)

    ax = axes[0, 0]
    ax.plot(episode, moving_average(data["success"], window), label=f"success ({window}-episode mean)")
    ax.plot(episode, moving_average(data["constraint_terminated"], window), label="constraint terminations")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("success")
    ax.legend(fontsize=8)

    ax = axes[0, 1]
    modes = data["failure_mode"]
    for mode in FAILURE_MODES:
        ax.plot(episode, moving_average(modes == mode, window), label=mode)
    ax.set_title(f"episode outcome ({window}-episode share)")
    ax.legend(fontsize=7)

    ax = axes[0, 2]
    ax.plot(episode, data["learning_return"], ".", ms=3, alpha=0.4)
    ax.plot(episode, moving_average(data["learning_return"], window))
    ax.set_title("learning return (mechanism reward)")

    ax = axes[1, 0]
    ax.plot(episode, data["closest_approach"], ".", ms=3, alpha=0.4, label="closest tip-cube distance")
    ax.plot(episode, data["cube_displacement"], ".", ms=3, alpha=0.4, label="largest cube displacement")
    ax.set_title("reach and push (m)")
    ax.legend(fontsize=8)

    ax = axes[1, 1]
    steps = data["phase_steps"]
    for k in range(3):
        ax.plot(episode, moving_average(steps[:, k], window), label=f"phase {k + 1}")
    ax.set_title("steps per phase")
    ax.legend(fontsize=8)

    ax = axes[1, 2]
    ax.plot(episode, data["touched_steps"], ".", ms=3, alpha=0.4, label="obstacle-touching steps")
    ax.plot(episode, data["interventions"], ".", ms=3, alpha=0.4, label="filter interventions")
    ax.set_title("contacts and filter interventions per episode")
    ax.legend(fontsize=8)

    sums = data["component_sums"]
    for k in range(3):
        ax = axes[2, k]
        for i, name in enumerate(OBJECTIVES):
            ax.plot(episode, moving_average(sums[:, k, i], window), label=name)
        levels = data["levels"][:, k]
        ax.set_title(f"phase {k + 1}: ±1 component sums (level now {int(levels[-1])})")
        ax.legend(fontsize=8)
    for ax in axes.flat:
        ax.set_xlabel("episode")
        ax.grid(alpha=0.3)
    if batches:
        _plot_batches(axes[3], batches)
    return save_figure(fig, Path(run_dir) / "diagnostics.png", dpi=80)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print("usage: python -m ahrm_stack.learning.diagnostics RUN_DIR [RUN_DIR ...]", file=sys.stderr)
        return 2
    for run_dir in args:
        try:
            print(plot_run(Path(run_dir)))
        except (FileNotFoundError, ValueError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
