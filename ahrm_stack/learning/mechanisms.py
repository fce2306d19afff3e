"""Reward mechanisms of spec §4: LS, FHRM, MHRM and AHRM.

All of them turn the learning components g = (g1, g2, g3) of a step (penalty form, spec §3), its
phase k and the signed distances to the two phase regions into one scalar reward. Statistics —
level convergence, the priority constraint's threshold, AHRM's priority determination — use the
±1 components f of completed episodes.

One :class:`RewardMechanism` owns the adaptive state (orders, levels, histories, lock flags). Its
per-step reward reads that state and never changes it; the state changes only in
:meth:`RewardMechanism.end_episode`, called once per completed episode in a fixed order, so the
result is the same with one or several environment workers.

The methods are a registry of small subclasses (:data:`MECHANISMS`, by ``mechanism.method``):
the base holds the hierarchy (levels, their convergence, the history, the priority constraint);
a subclass says where its orders come from and whether it is a hierarchy at all, and AHRM adds the
priority determination. ``RewardMechanism(config)`` builds the registered class of
``config.method``. A new mechanism is one class with :func:`register` (and its name in
``config.fields.Method``); the report takes its label from here.

Objectives are indexed 0 = avoid, 1 = manipulate, 2 = time; phases are 1-based (1 approach,
2 pre-manipulate, 3 manipulate). An order is a permutation of objective indices, highest priority
first.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from typing import Callable, ClassVar, Literal

import numpy as np

from ahrm_stack.config import MechanismConfig
from ahrm_stack.names import NUM_OBJECTIVES, NUM_PHASES
from ahrm_stack.names import OBJECTIVE_NAMES as OBJECTIVES

__all__ = ["MECHANISMS", "MechanismConfig", "RewardMechanism", "ConstraintMonitor", "Event", "EpisodeStats",
           "blend_weight", "label", "parse_order", "register"]


def parse_order(names: tuple[str, ...], where: str) -> tuple[int, ...]:
    """Objective names -> indices; raises ValueError naming ``where`` if not a permutation."""
    if sorted(names) != sorted(OBJECTIVES):
        raise ValueError(f"{where}: {list(names)} must be a permutation of {list(OBJECTIVES)}")
    return tuple(OBJECTIVES.index(n) for n in names)


def blend_weight(s: np.ndarray | float, band: float, slope: float) -> np.ndarray:
    """Weight of the far side of a boundary: w = 0.5 (1 - tanh(alpha s) / tanh(alpha delta)) inside
    the band |s| <= delta, 0 beyond it on the near side (s > delta), 1 beyond on the far side."""
    s = np.asarray(s, dtype=float)
    w = 0.5 * (1.0 - np.tanh(slope * s) / np.tanh(slope * band))
    return np.where(s >= band, 0.0, np.where(s <= -band, 1.0, w))


@dataclasses.dataclass
class Event:
    """Something the mechanism did, for the training log."""

    episode: int
    kind: Literal["level_advanced", "order_changed", "order_locked", "constraint_termination",
                  "constraint_exclusion"]
    phase: int
    detail: str


@dataclasses.dataclass
class EpisodeStats:
    """Per-phase statistics of one completed episode, from its ±1 components."""

    steps: np.ndarray  # (3,) steps spent in each phase
    sums: np.ndarray  # (3 phases, 3 objectives) sum of f_i over the steps in the phase

    @classmethod
    def from_steps(cls, f: np.ndarray, phase: np.ndarray) -> "EpisodeStats":
        f = np.asarray(f, dtype=float).reshape(-1, NUM_OBJECTIVES)
        phase = np.asarray(phase, dtype=int).reshape(-1)
        steps = np.array([(phase == k).sum() for k in range(1, NUM_PHASES + 1)], dtype=float)
        sums = np.stack([f[phase == k].sum(axis=0) for k in range(1, NUM_PHASES + 1)])
        return cls(steps, sums)


MECHANISMS: dict[str, type["RewardMechanism"]] = {}
"""The registered mechanisms by ``mechanism.method`` name."""


def register(name: str, label: str) -> Callable[[type["RewardMechanism"]], type["RewardMechanism"]]:
    """Class decorator: the mechanism ``name`` (a ``mechanism.method`` value), shown as ``label``."""
    def add(cls: type["RewardMechanism"]) -> type["RewardMechanism"]:
        cls.name, cls.label = name, label
        MECHANISMS[name] = cls
        return cls
    return add


def label(method: str) -> str:
    """A method's display name (``AHRM``); the name itself when it is not registered."""
    return MECHANISMS[method].label if method in MECHANISMS else method


class RewardMechanism:
    """The adaptive state and the reward of one method; ``RewardMechanism(config)`` is the
    registered subclass of ``config.method`` (:data:`MECHANISMS`)."""

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    hierarchical: ClassVar[bool] = True  # levels learned one by one, the priority constraint
    adaptive: ClassVar[bool] = False  # orders determined from the episodes (AHRM)

    def __new__(cls, config: MechanismConfig) -> "RewardMechanism":
        if cls is RewardMechanism:
            if config.method not in MECHANISMS:
                raise ValueError(f"mechanism.method: {config.method!r} is not registered; choose one of "
                                 f"{sorted(MECHANISMS)}")
            cls = MECHANISMS[config.method]
        return super().__new__(cls)

    def initial_orders(self, config: MechanismConfig) -> list[tuple[int, ...]]:
        """Each phase's order before any episode (from the config)."""
        return self._phase_orders(config.initial_orders, "mechanism.initial_orders")

    def __init__(self, config: MechanismConfig) -> None:
        self.config = config
        self.method = config.method
        self.orders = [tuple(o) for o in self.initial_orders(config)]
        # LS sums all objectives from the start; the hierarchies learn level by level.
        self.levels = [1 if self.hierarchical else NUM_OBJECTIVES] * NUM_PHASES
        self.locked = [not self.adaptive] * NUM_PHASES
        self.episodes = 0
        self.visits = [0] * NUM_PHASES
        self._level_sums: list[list[float]] = [[] for _ in range(NUM_PHASES)]
        self._history: list[deque] = [deque(maxlen=max(config.constraint_window, config.priority_period))
                                      for _ in range(NUM_PHASES)]
        self._last_determined: list[tuple[int, ...] | None] = [None] * NUM_PHASES
        self.events: list[Event] = []

    @staticmethod
    def _phase_orders(orders: tuple, where: str) -> list[tuple[int, ...]]:
        if len(orders) != NUM_PHASES:
            raise ValueError(f"{where}: expected {NUM_PHASES} orders (one per phase), got {len(orders)}")
        return [parse_order(o, f"{where}[{k}]") for k, o in enumerate(orders)]

    # ------------------------------------------------------------------ per-step reward
    def phase_rewards(self, values: np.ndarray) -> np.ndarray:
        """Hierarchical rewards R^k = sum of the first j_k objectives of pi_k, for k = 1..3.

        ``values``: (..., 3) component vectors. Returns (..., 3 phases).
        """
        values = np.asarray(values, dtype=float)
        out = np.empty(values.shape[:-1] + (NUM_PHASES,))
        for k in range(NUM_PHASES):
            out[..., k] = values[..., list(self.orders[k][: self.levels[k]])].sum(axis=-1)
        return out

    def reward(self, g: np.ndarray, distances: np.ndarray) -> np.ndarray:
        """The learning reward of step(s) with components ``g`` (..., 3) and region distances
        ``distances`` (..., 2) = (signed distance to B_obstacles, to B_target), m.

        The phase is implied by the distances (spec §2); across each boundary the rewards of the
        two phases are blended with the normalised tanh weight, so the reward is continuous in the
        pusher's pose: R = (1 - w23) [(1 - w12) R^1 + w12 R^2] + w23 R^3, with w12 from the distance
        to B_obstacles and w23 from the distance to B_target. Away from the bands this is R^k of the
        step's phase; within one band it is spec §4's (1 - w) R^k + w R^(k+1).
        """
        rewards = self.phase_rewards(g)
        if not self.hierarchical:  # one sum of every objective, the same in every phase
            return rewards[..., 0]
        distances = np.asarray(distances, dtype=float)
        w12 = blend_weight(distances[..., 0], self.config.blend_band, self.config.blend_slope)
        w23 = blend_weight(distances[..., 1], self.config.blend_band, self.config.blend_slope)
        low = (1 - w12) * rewards[..., 0] + w12 * rewards[..., 1]
        return (1 - w23) * low + w23 * rewards[..., 2]

    # ------------------------------------------------------------------ priority constraint
    def constraint_thresholds(self) -> np.ndarray:
        """tau_k per phase (nan where no constraint applies): the mean over the last W episodes
        visiting phase k of the per-step average of R_{j-1}^k, computed with the ±1 components."""
        tau = np.full(NUM_PHASES, np.nan)
        if not self.hierarchical:
            return tau
        window = self.config.constraint_window
        for k in range(NUM_PHASES):
            level = self.levels[k]
            history = list(self._history[k])[-window:]
            if level < 2 or len(history) < window:
                continue
            prefix = list(self.orders[k][: level - 1])
            tau[k] = np.mean([sums[prefix].sum() / steps for steps, sums in history])
        return tau

    def constraint_monitor(self) -> "ConstraintMonitor":
        """A checker of the priority constraint for one new episode (``mechanism.constraint_check``:
        online, at the episode's end, or never)."""
        prefixes = [list(self.orders[k][: max(self.levels[k] - 1, 0)]) for k in range(NUM_PHASES)]
        thresholds = (np.full(NUM_PHASES, np.nan) if self.config.constraint_check == "none"
                      else self.constraint_thresholds())
        return ConstraintMonitor(thresholds, prefixes, self.config.constraint_min_steps,
                                 self.config.constraint_margin,
                                 at_end=self.config.constraint_check == "episode")

    # ------------------------------------------------------------------ learning from episodes
    def end_episode(self, f: np.ndarray, phase: np.ndarray, constraint_terminated: bool = False,
                    terminated_phase: int | None = None, constraint_excluded: bool = False) -> list[Event]:
        """Update the state from one completed episode's ±1 components ``f`` (T, 3) and phases (T,).
        ``constraint_terminated``: the running check ended it; ``constraint_excluded``: the check at
        its end failed (``constraint_check: episode``), in phase ``terminated_phase``."""
        self.episodes += 1
        stats = EpisodeStats.from_steps(f, phase)
        events: list[Event] = []
        if constraint_terminated:
            events.append(Event(self.episodes, "constraint_termination", terminated_phase or 0,
                                "per-step reward of the higher levels fell below tau - margin"))
        if constraint_excluded:
            events.append(Event(self.episodes, "constraint_exclusion", terminated_phase or 0,
                                "the episode's per-step reward of the higher levels was below tau - "
                                "margin: left out of the update"))
        for k in range(NUM_PHASES):
            if stats.steps[k] == 0:
                continue
            self.visits[k] += 1
            self._history[k].append((stats.steps[k], stats.sums[k].copy()))
            if self.hierarchical:
                level_sum = stats.sums[k][list(self.orders[k][: self.levels[k]])].sum()
                self._level_sums[k].append(float(level_sum))
                events += self._advance_level(k)
            if self.adaptive and not self.locked[k] and self.visits[k] % self.config.priority_period == 0:
                events += self._determine_priority(k)
        self.events += events
        return events

    def _advance_level(self, k: int) -> list[Event]:
        window = self.config.convergence_window
        sums = self._level_sums[k]
        if self.levels[k] >= NUM_OBJECTIVES or len(sums) < 2 * window:
            return []
        recent, before = np.mean(sums[-window:]), np.mean(sums[-2 * window:-window])
        if abs(recent - before) > self.config.convergence_tolerance * max(1.0, abs(recent)):
            return []
        self.levels[k] += 1
        self._level_sums[k] = []
        return [Event(self.episodes, "level_advanced", k + 1,
                      f"level {self.levels[k] - 1} -> {self.levels[k]} (episode-sum mean {recent:.3f} "
                      f"vs {before:.3f})")]

    def _determine_priority(self, k: int) -> list[Event]:
        period = self.config.priority_period
        history = list(self._history[k])[-period:]
        if self.config.priority_rule == "violation":
            # the per-step average of f_i, low to high: the objective violated on the largest share
            # of the phase's steps comes first (with ±1 components, average = 1 - 2 x violated share)
            means = np.mean([sums / steps for steps, sums in history], axis=0)
            key, label, shown = means, "per-step mean", means
        else:
            # spec Eqs. 3-5: the per-episode sum's |mean|, high to low
            means = np.mean([sums for _, sums in history], axis=0)
            key, label, shown = -np.abs(means), "|mean|", np.abs(means)
        # ties by objective index (a stable sort)
        order = tuple(int(i) for i in np.argsort(key, kind="stable"))
        events = []
        if order != self.orders[k]:
            events.append(Event(self.episodes, "order_changed", k + 1,
                                f"{_names(self.orders[k])} -> {_names(order)} ({label} "
                                f"{np.round(shown, 3).tolist()})"))
            self.orders[k] = order
            self.levels[k] = 1
            self._level_sums[k] = []
        if self._last_determined[k] == order:
            self.locked[k] = True
            events.append(Event(self.episodes, "order_locked", k + 1, _names(order)))
        self._last_determined[k] = order
        return events

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        return {
            "method": self.method,
            "orders": [list(o) for o in self.orders],
            "levels": list(self.levels),
            "locked": list(self.locked),
            "episodes": self.episodes,
            "visits": list(self.visits),
            "level_sums": [list(s) for s in self._level_sums],
            "history": [[[float(steps), sums.tolist()] for steps, sums in h] for h in self._history],
            "last_determined": [None if o is None else list(o) for o in self._last_determined],
        }

    def load_state_dict(self, state: dict) -> None:
        if state["method"] != self.method:
            raise ValueError(f"checkpoint holds the state of {state['method']!r}, not {self.method!r}")
        self.orders = [tuple(int(i) for i in o) for o in state["orders"]]
        self.levels = [int(v) for v in state["levels"]]
        self.locked = [bool(v) for v in state["locked"]]
        self.episodes = int(state["episodes"])
        self.visits = [int(v) for v in state["visits"]]
        self._level_sums = [[float(v) for v in s] for s in state["level_sums"]]
        maxlen = self._history[0].maxlen
        self._history = [deque(((steps, np.asarray(sums, dtype=float)) for steps, sums in h), maxlen=maxlen)
                         for h in state["history"]]
        self._last_determined = [None if o is None else tuple(o) for o in state["last_determined"]]


@register("ls", "LS")
class LinearSum(RewardMechanism):
    """LS: every objective summed from the start, in every phase; no levels, no constraint."""

    hierarchical = False


@register("fhrm", "FHRM")
class FixedHierarchy(RewardMechanism):
    """FHRM: one fixed order (``mechanism.fixed_order``) in every phase, learned level by level."""

    def initial_orders(self, config: MechanismConfig) -> list[tuple[int, ...]]:
        return [parse_order(config.fixed_order, "mechanism.fixed_order")] * NUM_PHASES


@register("mhrm", "MHRM")
class ManualHierarchy(RewardMechanism):
    """MHRM: a hand-set order per phase (``mechanism.manual_orders``), learned level by level."""

    def initial_orders(self, config: MechanismConfig) -> list[tuple[int, ...]]:
        return self._phase_orders(config.manual_orders, "mechanism.manual_orders")


@register("ahrm", "AHRM")
class AdaptiveHierarchy(RewardMechanism):
    """AHRM: the orders start at ``mechanism.initial_orders`` and are determined from the episodes
    every ``priority_period`` visits of a phase (``priority_rule``), locked once repeated."""

    adaptive = True


def _names(order: tuple[int, ...]) -> str:
    return ">".join(OBJECTIVES[i] for i in order)


class ConstraintMonitor:
    """Spec §4's priority constraint for one episode.

    Online (``at_end`` false, ``constraint_check: running``): after at least ``min_steps`` steps in
    phase k, the running per-step average of R_{j-1}^k (±1 components) over those steps must stay
    at or above tau_k - margin; otherwise the episode ends early (as a truncation).

    At the end (``at_end``, ``constraint_check: episode``, the paper's Algorithm 1): :meth:`step`
    only accounts; :meth:`violated_at_end` compares each phase's per-step average over the whole
    episode (phases visited for at least ``min_steps`` steps) with tau_k - margin. The running
    form compares an episode's first steps, mostly approach in phase 3 where manipulate is -1 until
    the cube moves, with whole-episode averages: it ended 69 % of the scripted controller's won
    near-cube episodes at their 20th step (``tests/test_priority_constraint.py``).
    """

    def __init__(self, thresholds: np.ndarray, prefixes: list[list[int]], min_steps: int,
                 margin: float, at_end: bool = False) -> None:
        self.thresholds = thresholds
        self.prefixes = prefixes
        self.min_steps = min_steps
        self.margin = margin
        self.at_end = at_end
        self.steps = np.zeros(NUM_PHASES)
        self.sums = np.zeros(NUM_PHASES)
        self.violated_phase: int | None = None

    def step(self, f: np.ndarray, phase: int) -> bool:
        """Account one step; True when the episode must end now (never when checked at the end)."""
        k = phase - 1
        if np.isnan(self.thresholds[k]):
            return False
        self.steps[k] += 1
        self.sums[k] += float(np.asarray(f)[self.prefixes[k]].sum())
        if self.at_end:
            return False
        if self.steps[k] >= self.min_steps and self.sums[k] / self.steps[k] < self.thresholds[k] - self.margin:
            self.violated_phase = phase
            return True
        return False

    def violated_at_end(self) -> bool:
        """Checked at the end: whether a phase's per-step average fell below tau_k - margin (its
        phase in :attr:`violated_phase`, the first such). False for the online check."""
        if not self.at_end:
            return False
        for k in range(NUM_PHASES):
            if (not np.isnan(self.thresholds[k]) and self.steps[k] >= self.min_steps
                    and self.sums[k] / self.steps[k] < self.thresholds[k] - self.margin):
                self.violated_phase = k + 1
                return True
        return False
