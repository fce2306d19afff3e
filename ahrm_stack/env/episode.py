"""Per-episode diagnostics: what happened, where a failing episode failed.

An :class:`EpisodeRecorder` accumulates the :class:`StepInfo` stream of one episode; its
:class:`EpisodeSummary` is what training logs, evaluation tables and the learning study read.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrm_stack.names import NUM_PHASES
from ahrm_stack.env.task import StepInfo


@dataclasses.dataclass
class EpisodeSummary:
    steps: int
    duration: float  # s of simulated time
    success: bool
    time_to_success: float  # s, nan without success
    touched_steps: int  # steps on which an obstacle was touched
    learning_return: float  # sum of the learner's reward
    phase_steps: list[int]  # steps per phase
    phases_visited: str  # e.g. "1>2>3"
    component_sums: list[list[float]]  # [phase][objective] sums of the ±1 components
    closest_approach: float  # m, smallest tip-to-cube-centre distance
    cube_displacement: float  # m, largest horizontal distance of the cube from its start
    cube_travel: float  # m, path length of the cube's centre
    constraint_terminated: bool
    constraint_phase: int | None
    interventions: int = 0  # safety-filter calls that modified the command
    joint_limit_violations: int = 0  # steps with a joint outside its position limits (simulator)
    # the cube left by the planner's lane (ahrm_stack.lane_agreement; training's diagnostics): None
    # when it was not pushed along a lane, or not measured
    lane_agrees: bool | None = None
    # mechanism.constraint_check: episode: the priority constraint failed at the episode's end, and
    # its transitions were left out of the update
    constraint_excluded: bool = False
    events: list = dataclasses.field(default_factory=list)
    # the process-wide order in which episodes ended (PushOffEnv), for the trainer to log several
    # environments' episodes in the order the mechanism saw them; not a logged column
    end_order: int | None = None

    @property
    def touched(self) -> bool:
        return self.touched_steps > 0

    def failure_mode(self) -> str:
        """Where an episode failed: never reached the cube, reached it but could not push,
        pushed into obstacles, or stalled (the cube moved but did not leave the table)."""
        if self.success:
            return "touched" if self.touched else "success"
        if self.touched:
            return "hit obstacles"
        if self.phase_steps[2] == 0:
            return "never reached the cube"
        if self.cube_displacement < 0.01:
            return "reached the cube, could not push"
        return "stalled"


class EpisodeRecorder:
    """Accumulates one episode, starting from the reset state ``first``."""

    def __init__(self, first: StepInfo) -> None:
        self.f: list[np.ndarray] = []
        self.phase: list[int] = []
        self._start = first.target[:2].copy()
        self._last_target = first.target.copy()
        self._travel = 0.0
        self._displacement = 0.0
        self._closest = float(np.linalg.norm(first.tip - first.target))
        self._touched = 0
        self._return = 0.0
        self._visited = [first.phase]
        self._success_time = float("nan")
        self._elapsed = 0.0
        self.interventions = 0

    def step(self, info: StepInfo, reward: float, intervened: bool = False) -> None:
        self.f.append(info.f.copy())
        self.phase.append(info.phase)
        self._travel += float(np.linalg.norm(info.target - self._last_target))
        self._last_target = info.target.copy()
        self._displacement = max(self._displacement, float(np.linalg.norm(info.target[:2] - self._start)))
        self._closest = min(self._closest, float(np.linalg.norm(info.tip - info.target)))
        self._touched += int(info.touched)
        self._return += reward
        if info.phase != self._visited[-1]:
            self._visited.append(info.phase)
        if info.success and np.isnan(self._success_time):
            self._success_time = info.elapsed
        self._elapsed = info.elapsed
        self.interventions += int(intervened)

    def summary(self, constraint_terminated: bool = False, constraint_phase: int | None = None,
                joint_limit_violations: int = 0) -> EpisodeSummary:
        f = np.asarray(self.f, dtype=float).reshape(-1, 3)
        phase = np.asarray(self.phase, dtype=int)
        sums = [f[phase == k].sum(axis=0).tolist() for k in range(1, NUM_PHASES + 1)]
        return EpisodeSummary(
            steps=len(self.phase), duration=self._elapsed,
            success=not np.isnan(self._success_time), time_to_success=self._success_time,
            touched_steps=self._touched, learning_return=self._return,
            phase_steps=[int((phase == k).sum()) for k in range(1, NUM_PHASES + 1)],
            phases_visited=">".join(str(k) for k in self._visited), component_sums=sums,
            closest_approach=self._closest, cube_displacement=self._displacement,
            cube_travel=self._travel, constraint_terminated=constraint_terminated,
            constraint_phase=constraint_phase, interventions=self.interventions,
            joint_limit_violations=joint_limit_violations)
