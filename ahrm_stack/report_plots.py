"""The experiment report's figures (PNG), from the runs' ``episodes.csv``.

- ``learning_curves.png`` (the paper's Fig. 4): trailing-window success rate and learning return
  per training episode, per method, mean over seeds with a ±1 std band;
- ``objectives_per_phase.png``: each ±1 objective's per-episode sum in each phase, per method;
- ``priority_orders.png`` (Fig. 3 over time): the mechanism's priority order of each phase against
  the training episode, per method and seed.
"""

from __future__ import annotations

from itertools import permutations
from pathlib import Path

import numpy as np

from ahrm_stack.learning.diagnostics import moving_average, pyplot, save_figure
from ahrm_stack.names import OBJECTIVE_NAMES as OBJECTIVES

#: the six priority orders as codes of the objectives' initials ("AMT", "ATM", ...)
ORDER_CODES = ["".join(p) for p in permutations("".join(name[0].upper() for name in OBJECTIVES))]


def seed_band(curves: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episode numbers, mean and population std over seeds, on the episodes all seeds have."""
    length = min(len(c) for c in curves)
    stacked = np.stack([np.asarray(c[:length], dtype=float) for c in curves])
    return np.arange(1, length + 1), stacked.mean(axis=0), stacked.std(axis=0)


def _band(ax, curves: list[np.ndarray], label: str, color) -> None:
    episode, mean, std = seed_band(curves)
    ax.plot(episode, mean, color=color, label=f"{label} ({len(curves)} seeds)")
    ax.fill_between(episode, mean - std, mean + std, color=color, alpha=0.2)


def _by_method(runs, methods):
    return {m: [r for r in runs if r.method == m and r.episodes is not None] for m in methods}


def plot_curves(out: Path, runs, methods: list[str], window: int) -> Path | None:
    grouped = _by_method(runs, methods)
    if not any(grouped.values()):
        return None
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    for i, (method, group) in enumerate(grouped.items()):
        if not group:
            continue
        color = f"C{i}"
        _band(axes[0], [moving_average(r.episodes["success"], window) for r in group], method.upper(), color)
        _band(axes[1], [moving_average(r.episodes["learning_return"], window) for r in group],
              method.upper(), color)
    axes[0].set_title(f"success rate ({window}-episode trailing mean)")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_title(f"learning return ({window}-episode trailing mean; each method's own reward)")
    for ax in axes:
        ax.set_xlabel("training episode")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(fig, Path(out) / "learning_curves.png", dpi=90)


def plot_objectives(out: Path, runs, methods: list[str], window: int) -> Path | None:
    grouped = _by_method(runs, methods)
    if not any(grouped.values()):
        return None
    plt = pyplot()
    fig, axes = plt.subplots(3, 3, figsize=(15, 10), sharex=True)
    for i, (method, group) in enumerate(grouped.items()):
        for k in range(3):
            for j, objective in enumerate(OBJECTIVES):
                if group:
                    curves = [moving_average(r.episodes["component_sums"][:, k, j], window) for r in group]
                    _band(axes[j, k], curves, method.upper(), f"C{i}")
                axes[j, k].set_title(f"phase {k + 1}: {objective} (±1 sum per episode)", fontsize=10)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("training episode")
    axes[0, 0].legend(fontsize=8)
    return save_figure(fig, Path(out) / "objectives_per_phase.png", dpi=80)


def order_index(orders: str, phase: int) -> int:
    """Index in :data:`ORDER_CODES` of the order of ``phase`` (0-based) in ``"AMT AMT MAT"``."""
    return ORDER_CODES.index(orders.split()[phase])


def plot_orders(out: Path, runs, methods: list[str]) -> Path | None:
    grouped = _by_method(runs, methods)
    shown = [m for m in methods if grouped[m]]
    if not shown:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(len(shown), 3, figsize=(15, 2.4 * len(shown) + 0.6), squeeze=False,
                             sharey=True)
    for row, method in enumerate(shown):
        for k in range(3):
            ax = axes[row, k]
            for run in grouped[method]:
                orders = run.episodes["orders"]
                ax.step(run.episodes["episode"], [order_index(str(o), k) for o in orders], where="post",
                        label=f"seed {run.seed}", alpha=0.8)
            ax.set_title(f"{method.upper()}, phase {k + 1}", fontsize=10)
            ax.set_yticks(range(len(ORDER_CODES)), ORDER_CODES)
            ax.set_ylim(-0.5, len(ORDER_CODES) - 0.5)
            ax.grid(alpha=0.3)
        axes[row, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("training episode")
    fig.suptitle("priority order per phase (A avoid, M manipulate, T time; highest first)")
    return save_figure(fig, Path(out) / "priority_orders.png", dpi=80)
