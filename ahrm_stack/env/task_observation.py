"""The push-off task's observation (spec §1), all of it read from its one description
(:func:`~ahrm_stack.env.observation_layout.observation_terms`): the composer observables it
declares, the order of the flat observation vector (:attr:`TaskObservation.observation_order`), that
vector read straight from the physics (:meth:`TaskObservation.flat_observation`, each term's value by
its name: :meth:`TaskObservation._term_values`), and the episode's planned lane it shows. Positions
in m, world frame; joint angles as (sin, cos), velocities in rad/s and m/s.

:class:`TaskObservation` is a base class of :class:`~ahrm_stack.env.task.PushOffTask`: it reads
the entities the task composes, the task's last :class:`~ahrm_stack.env.task.StepInfo` and the
physics indices the task caches at each reset (``_bind``); the attributes it needs are declared
below."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from dm_control import mjcf
from dm_control.composer.observation import observable

from ahrm_stack.config import TaskConfig
from ahrm_stack.env.layout import Layout, choose_lane, lane_clearance
from ahrm_stack.env.observation_layout import TASK_TERMS, ObservationTerm, observation_terms
from ahrm_stack.env.rewards import NUM_PHASES


_PHASES = np.eye(NUM_PHASES)  # the phase's one-hot rows
_PHASES.setflags(write=False)


class TaskObservation:
    """The observation half of :class:`~ahrm_stack.env.task.PushOffTask` (see the module)."""

    # Set by PushOffTask: its config, entities, last step, previous action and, at each reset
    # (_bind), the physics indices below.
    config: TaskConfig
    robot: Any  # ahrm_stack.robot.RobotDescription
    step_info: Any  # ahrm_stack.env.task.StepInfo
    previous_action: np.ndarray  # (n_commanded,) the last action, normalised
    _arm: Any  # the arm entity
    _cube: Any  # BoxProp
    _obstacles: list[Any]  # BoxProp
    _obstacle_half_sizes: np.ndarray  # (n_obstacles, 3), m
    _lane_plan: np.ndarray | None  # the episode's lane, one-hot (lane_choice); None: not planned yet
    _bind: Callable[[mjcf.Physics], None]
    _cube_body: int
    _obstacle_bodies: np.ndarray
    _prop_bodies: np.ndarray
    _prop_linear_dofs: np.ndarray
    _arm_qpos: np.ndarray
    _arm_dof: np.ndarray
    _flat: tuple[mjcf.Physics, list[Callable[[], np.ndarray]]] | None = None  # (physics, per-term calls)

    @property
    def observation_terms(self) -> tuple[ObservationTerm, ...]:
        """The flat observation's terms, in order, with this task's composer keys
        (:func:`~ahrm_stack.env.observation_layout.observation_terms`)."""
        return observation_terms(self.config, self.robot.num_joints, len(self.robot.commanded_joints),
                                 arm=self._arm.mjcf_model.model,
                                 props=tuple(p.mjcf_model.model for p in [self._cube, *self._obstacles]))

    def _term_values(self) -> dict[str, Callable[[mjcf.Physics], np.ndarray]]:
        """Each task term's value (physics -> its floats), by name: the composer observables and
        :meth:`flat_observation` both compute a task term with these."""
        return {"pusher_tip": lambda physics: self.step_info.tip,
                "previous_action": lambda physics: self.previous_action,
                "phase": lambda physics: _PHASES[self.step_info.phase - 1],
                "boundary_distance": lambda physics: np.array([self.step_info.x]),
                "relative_to_cube": self._relative_to_cube,
                "lane_clearance": self._lane_clearance,
                "lane_choice": self.lane_choice}

    def _declare_observables(self) -> None:
        """The observables of :attr:`observation_terms`: the arm's and the props' own, and one
        ``Generic`` per task term."""
        self._arm.observables.joints_pos.enabled = True
        self._arm.observables.joints_vel.enabled = True
        for prop in [self._cube, *self._obstacles]:
            prop.observables.position.enabled = True
            prop.observables.linear_velocity.enabled = True
        values = self._term_values()
        self._task_observables = {term.name: observable.Generic(values[term.name])
                                  for term in self.observation_terms if term.name in TASK_TERMS}
        for obs in self._task_observables.values():
            obs.enabled = True
        # Sample once per control step (at its last substep), not at every physics substep.
        for obs in self.observables.values():
            obs.update_interval = self.config.substeps

    @property
    def observables(self) -> dict:
        """All enabled observables, keyed as in the composer observation dict."""
        found = {}
        for entity in [self._arm, self._cube, *self._obstacles]:
            for name, obs in entity.observables.as_dict().items():
                if obs.enabled:
                    found[name] = obs
        found.update(self._task_observables)
        return found

    @property
    def task_observables(self) -> dict:
        return self._task_observables

    @property
    def observation_order(self) -> list[str]:
        """Composer observation keys in the order of the flat observation vector."""
        return [key for term in self.observation_terms for key in term.keys]

    def _relative_to_cube(self, physics: mjcf.Physics) -> np.ndarray:
        """Tip - cube (3) and each obstacle - cube in (x, y) (2 each), m, world frame."""
        if not hasattr(self, "_cube_body"):  # composer evaluates observables before the first reset
            self._bind(physics)
        xpos = physics.data.xpos
        cube = xpos[self._cube_body]
        return np.concatenate([self.step_info.tip - cube,
                               (xpos[self._obstacle_bodies, :2] - cube[:2]).ravel()])

    def _lane_clearance(self, physics: mjcf.Physics) -> np.ndarray:
        """Each reachable lane's clearance from the current cube and obstacle positions, m."""
        if not hasattr(self, "_cube_body"):
            self._bind(physics)
        xpos = physics.data.xpos
        cfg = self.config
        return lane_clearance(xpos[self._cube_body, :2], xpos[self._obstacle_bodies, :2],
                              cfg.cube.size / 2, self._obstacle_half_sizes[0, :2], cfg.table, cfg.layout,
                              cfg.observation.lane_clip)

    def lane_choice(self, physics: mjcf.Physics) -> np.ndarray:
        """One-hot over ``layout.lane_directions``: the episode's lane
        (:func:`~ahrm_stack.env.layout.choose_lane`), planned from the first state observed after
        a reset — the settled layout in training, the first perceived one in deployment — and
        kept for the episode, as the scripted controller keeps its plan."""
        if self._lane_plan is None:
            self._lane_plan = np.eye(len(self.config.layout.lane_directions))[self.plan_lane(physics)]
        return self._lane_plan

    def forget_lane_plan(self) -> None:
        """The next :meth:`lane_choice` plans the lane again from the state it sees (a look at the
        observation that must not fix the episode's plan)."""
        self._lane_plan = None

    def plan_lane(self, physics: mjcf.Physics) -> int:
        """The planner's lane for the current state (its index in ``layout.lane_directions``):
        :func:`~ahrm_stack.env.layout.choose_lane` on the cube's and obstacles' positions now and
        the pusher tip of :attr:`step_info` (m, world frame). At an episode's first observation,
        the scripted controller's plan; ``lane_choice`` shows it, lane agreement
        (:mod:`ahrm_stack.lane_agreement`) measures against it."""
        if not hasattr(self, "_cube_body"):
            self._bind(physics)
        xpos = physics.data.xpos
        cfg = self.config
        layout = Layout(xpos[self._cube_body, :2].copy(), xpos[self._obstacle_bodies, :2].copy())
        return choose_lane(layout, self.step_info.tip[:2], cfg.cube.size / 2,
                           self._obstacle_half_sizes[0, :2], cfg.table, cfg.layout)

    def cube_xy(self, physics: mjcf.Physics) -> np.ndarray:
        """The cube centre's (x, y) now, m, world frame (a copy)."""
        if not hasattr(self, "_cube_body"):
            self._bind(physics)
        return physics.data.xpos[self._cube_body, :2].copy()

    def flat_observation(self, physics: mjcf.Physics) -> np.ndarray:
        """The observation vector of :attr:`observation_terms`, read straight from the physics.

        Equal to concatenating the declared observables (a test checks it) but without composer's
        per-observable overhead: this runs every control step.
        """
        if self._flat is None or self._flat[0] is not physics:
            self._flat = (physics, self._flat_parts(physics))
        return np.concatenate([part() for part in self._flat[1]])

    def _flat_parts(self, physics: mjcf.Physics) -> list[Callable[[], np.ndarray]]:
        """Calls giving :attr:`observation_terms`' floats from ``physics`` now, in order (the
        cube's and the obstacles' terms, which sit together, by one call)."""
        data = physics.data
        values = self._term_values()

        def joints_pos() -> np.ndarray:
            q = data.qpos[self._arm_qpos]
            return np.stack([np.sin(q), np.cos(q)], axis=1).ravel()

        def props() -> np.ndarray:  # position then linear velocity per prop, the cube first
            return np.concatenate([data.xpos[self._prop_bodies], data.qvel[self._prop_linear_dofs]],
                                  axis=1).ravel()

        parts: list[Callable[[], np.ndarray]] = []
        for term in self.observation_terms:
            if term.name == "joints_pos":
                parts.append(joints_pos)
            elif term.name == "joints_vel":
                parts.append(lambda: data.qvel[self._arm_dof])
            elif term.keys[0].endswith("/position"):  # a prop: the cube or an obstacle
                if term.name == "cube":
                    parts.append(props)
            else:
                parts.append(self._task_part(values[term.name], physics))
        return parts

    @staticmethod
    def _task_part(value: Callable[[mjcf.Physics], np.ndarray], physics: mjcf.Physics) -> Callable[[], np.ndarray]:
        return lambda: value(physics)  # each value is a 1-D array
