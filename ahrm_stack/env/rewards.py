"""Reward components f1-f3 of spec §3, as small objects with no simulator inside.

Each component is +1 (objective satisfied on this step) or -1 (violated). The learner sees the
penalty form g = (f - 1) / 2 (0 when satisfied, -1 when violated); both are reported every step.
Index order everywhere: 0 = avoid obstacles, 1 = manipulate, 2 = minimise time.
"""

from __future__ import annotations

import numpy as np

from ahrm_stack.names import NUM_PHASES


def penalty_form(f: np.ndarray) -> np.ndarray:
    """g = (f - 1) / 2: 0 where the objective is satisfied, -1 where it is violated."""
    return (np.asarray(f, dtype=float) - 1.0) / 2.0


def avoid_component(touched: bool, too_close: bool = False) -> float:
    """f1: -1 on a step in which any obstacle is touched, or (``too_close``) the cube or the pusher
    is within ``task.rewards.avoid_margin`` of one; +1 otherwise (spec §3: the touch alone)."""
    return -1.0 if touched or too_close else 1.0


def obstacle_touched(contact_geoms: np.ndarray, is_obstacle: np.ndarray, is_toucher: np.ndarray,
                     obstacle_speeds: np.ndarray, speed_threshold: float) -> bool:
    """Whether the robot or the target touches an obstacle.

    ``contact_geoms``: (n, 2) geom ids of the active contacts. ``is_obstacle`` / ``is_toucher``:
    boolean masks over all geom ids (obstacle geoms; robot and target geoms).
    ``obstacle_speeds``: linear speed of each obstacle, m/s; faster than ``speed_threshold`` counts
    as touched (it was pushed or is falling).
    """
    if obstacle_speeds.size and float(obstacle_speeds.max()) > speed_threshold:
        return True
    if len(contact_geoms) == 0:
        return False
    a, b = contact_geoms[:, 0], contact_geoms[:, 1]
    hit = (is_obstacle[a] & is_toucher[b]) | (is_obstacle[b] & is_toucher[a])
    return bool(hit.any())


class ProgressObjective:
    """f2 against the best so far: P = d - l, +1 when P exceeds the episode's best by ``eps``.

    d is the target's horizontal distance from the table centre, l the distance from the pusher tip
    to the target centre (both m).
    """

    def __init__(self, eps: float) -> None:
        self.eps = eps
        self.best = -np.inf

    def reset(self, progress: float) -> None:
        self.best = progress

    def step(self, progress: float) -> float:
        improved = progress > self.best + self.eps
        self.best = max(self.best, progress)
        return 1.0 if improved else -1.0


def progress(target: np.ndarray, table_center: np.ndarray, tip: np.ndarray) -> float:
    """P = d - l (m): target's horizontal distance from the table centre minus tip-target distance."""
    d = float(np.hypot(target[0] - table_center[0], target[1] - table_center[1]))
    l = float(np.linalg.norm(tip - target))
    return d - l


class TimeObjective:
    """f3: +1 while the time spent in the current phase is below that phase's budget Gamma_k.

    ``reference`` says which episode sets Gamma_k:

    - ``"previous"`` (spec §3): the time spent in phase k in the previous episode that visited it;
    - ``"success"``: the time spent in phase k in the latest *successful* episode, 0 for a phase
      that episode did not visit (so that a phase a success never needed costs time at once).

    Before any episode has set it, Gamma_k is the remaining episode time. Times in seconds. This
    state spans episodes and belongs in checkpoints (``state_dict`` / ``load_state_dict``).
    """

    def __init__(self, episode_duration: float, num_phases: int = NUM_PHASES,
                 reference: str = "previous") -> None:
        if reference not in ("previous", "success"):
            raise ValueError(f"time reference must be 'previous' or 'success', got {reference!r}")
        self.episode_duration = episode_duration
        self.reference = reference
        self.budget = np.full(num_phases, np.nan)  # nan: never visited
        self.spent = np.zeros(num_phases)

    def reset(self) -> None:
        self.spent[:] = 0.0

    def step(self, phase: int, dt: float, elapsed: float) -> float:
        """Account ``dt`` seconds in ``phase`` (1-based); ``elapsed``: episode time after the step."""
        k = phase - 1
        self.spent[k] += dt
        budget = self.budget[k]
        if np.isnan(budget):
            budget = self.episode_duration - elapsed
        return 1.0 if self.spent[k] < budget else -1.0

    def end_episode(self, success: bool = False) -> None:
        """``"previous"``: visited phases take this episode's time as their new budget.
        ``"success"``: a successful episode sets every phase's budget to its time there (0 where
        it did not go); a failed one changes nothing."""
        if self.reference == "success":
            if success:
                self.budget[:] = self.spent
            return
        visited = self.spent > 0
        self.budget[visited] = self.spent[visited]

    def state_dict(self) -> dict:
        return {"budget": self.budget.tolist()}

    def load_state_dict(self, state: dict) -> None:
        budget = np.asarray(state["budget"], dtype=float)
        if budget.shape != self.budget.shape:
            raise ValueError(f"time objective state has {budget.shape} budgets, expected "
                             f"{self.budget.shape}")
        self.budget = budget


def staged_push_reward(tip: np.ndarray, cube: np.ndarray, lane_sign: float, cube_half: float,
                       table_half_x: float, touched: bool, success: bool, tanh_scale: float,
                       push_offset: float, reached_distance: float) -> float:
    """The oracle control's staged dense reward of one step (``task.rewards.learning: staged``).

    ``tip``, ``cube``: the pusher tip and the cube centre (m, world frame); ``lane_sign``: +1 to
    push toward +x, -1 toward -x. Reach = 1 - tanh(scale d), d the tip's distance to the push pose
    (``push_offset`` behind the cube's back face, at its centre); push = 1 - tanh(scale e), e how
    far the cube's centre still is from leaving the table along the lane (0 once off). The step's
    reward is (reach + push) / 2 once the tip is within ``reached_distance`` of the pose, reach / 2
    before; 1 on success; minus 1 when an obstacle is touched. In [-1, 1]."""
    if success:
        value = 1.0
    else:
        tip, cube = np.asarray(tip, dtype=float), np.asarray(cube, dtype=float)
        pose = cube - np.array([lane_sign * (cube_half + push_offset), 0.0, 0.0])
        d = float(np.linalg.norm(tip - pose))
        reach = 1.0 - np.tanh(tanh_scale * d)
        remaining = max(0.0, table_half_x - lane_sign * float(cube[0]))
        push = 1.0 - np.tanh(tanh_scale * remaining)
        value = 0.5 * (reach + (push if d <= reached_distance else 0.0))
    return float(value - (1.0 if touched else 0.0))
