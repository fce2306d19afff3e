"""A lean episode runner for :class:`PushOffTask`: the task's hooks, without composer's buffers.

``composer.Environment`` recompiles the physics at every reset and refreshes every observable at
every physics substep; this runner compiles the model once, resets with ``mj_resetData``, steps the
physics ``substeps`` times per control step and evaluates the task's declared observables once, at
the end of the control step. The task is the same object either way (``composer.Environment(task)``
still works), so the episode logic lives in one place.

Contacts are read at the end of each control step; a touch that does not last to the end of the
step is caught by the obstacle-speed test of f1.

With ``task.episode.sleep`` the stepped physics uses MuJoCo's body sleeping
(:meth:`PushOffTask.enable_sleep`): the obstacles, once at rest, leave the step until a contact with
an awake body or a write to their state wakes them (``mj_resetData`` wakes every tree; the arm and
the cube never sleep).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

import mujoco
import numpy as np
from dm_control import mjcf

from ahrm_stack.config import SafetyConfig
from ahrm_stack.env.control_step import ControlStep, filter_call, make_task_filter
from ahrm_stack.env.layout import lane_clearance
from ahrm_stack.env.observation_layout import observation_layout
from ahrm_stack.env.realism import ObservationSensing, VelocityEstimator
from ahrm_stack.realism import ActuatorModel, RealismConfig
from ahrm_stack.env.task import PushOffTask, StepInfo
from ahrm_stack.safety import FilterResult, InterventionStats, SafetyFilter

log = logging.getLogger(__name__)


@dataclasses.dataclass
class Transition:
    observation: dict[str, np.ndarray]
    info: StepInfo
    terminated: bool  # success: a terminal state
    truncated: bool  # the episode's time limit


class TaskRunner:
    """Resets and steps one :class:`PushOffTask` on its own physics. Seeded by ``seed``.

    With ``safety`` (the ``safety`` section of the config), every command passes through the QP
    safety filter before it reaches the actuators; :attr:`last_filter_result` and
    :attr:`safety_stats` report what it did. ``safety=None`` steps the raw physics — for
    physics-level tests and the bare-step benchmark only — and ``safety.enabled: false`` is the
    explicit ablation; both are logged as warnings.

    :meth:`step_action` takes a policy's normalised action (``task.action.mode``), mapped to the
    filter's request by :attr:`control` (:class:`~ahrm_stack.env.control_step.ControlStep`);
    :meth:`step_only` and :meth:`step_cartesian` take requests (rad/s, or m/s for the tip).

    ``task.realism``'s command and measurement paths (:mod:`ahrm_stack.realism`) act on its steps
    and observations; ``imperfections=False`` leaves them to a caller that composes them itself
    (the sim backend's arm; the task still draws the episode's dynamics).
    """

    def __init__(self, task: PushOffTask, seed: int | None = None,
                 safety: SafetyConfig | None = None, imperfections: bool = True) -> None:
        self.task = task
        self.physics = mjcf.Physics.from_mjcf_model(task.root_entity.mjcf_model)
        if task.config.episode.sleep:
            task.enable_sleep(self.physics)
        self.safety_config = safety
        self.control = ControlStep(task.robot, task.config.action)
        self.filter: SafetyFilter | None = None
        self.safety_stats = InterventionStats()
        self.last_filter_result: FilterResult | None = None
        self.limit_violations = 0  # steps of this episode with a joint outside its position limits
        if safety is None:
            log.warning("TaskRunner without a safety filter: commands reach the actuators unfiltered")
        elif not safety.enabled:
            log.warning("safety filter OFF (safety.enabled: false): an explicit ablation")
        self.random_state = np.random.RandomState(seed)
        self._substeps = task.config.substeps
        self.max_steps = task.config.max_steps  # control steps before truncation
        self._steps = 0
        # task.realism: the observation measured (noise, perception latency), the commands late
        # and lagged; None for the ideal simulation (no random draw is made then)
        realism = task.config.realism if imperfections else RealismConfig.ideal()
        self._sensing: ObservationSensing | None = None
        self._sensing_rng: np.random.Generator | None = None
        estimate = task.config.observation.joint_velocity == "position_difference"
        if realism.senses or estimate:
            cfg = task.config
            layout = observation_layout(cfg, task.robot.num_joints, len(task.robot.commanded_joints))
            velocity = VelocityEstimator(cfg.observation.velocity_smoothing) if estimate else None
            self._sensing = ObservationSensing(realism, layout, cfg.episode.control_period,
                                               len(cfg.obstacles.fixed_layout), self._lane_clearance,
                                               velocity)
        self._actuators: ActuatorModel | None = None
        if realism.actuates:
            self._actuators = ActuatorModel(realism, task.config.episode.physics_timestep,
                                            task.robot.num_joints)
        self._observe: dict[str, Callable[[], np.ndarray]] = {
            name: obs.observation_callable(self.physics, self.random_state)
            for name, obs in task.observables.items()}
        self.observation_order = task.observation_order

    def seed(self, seed: int) -> None:
        self.random_state.seed(seed)

    def observe(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(fn()) for name, fn in self._observe.items()}

    def flat_observation(self) -> np.ndarray:
        """The observation vector: the keys of ``observation_order``, flattened and concatenated;
        with ``task.realism``'s sensing, as measured (:class:`ObservationSensing`). Call it once
        per control step (the perception latency counts calls)."""
        observation = self.task.flat_observation(self.physics)
        if self._sensing is None:
            return observation
        return self._sensing(observation, self._sensing_rng)

    def _lane_clearance(self, cube_xy: np.ndarray, obstacle_xy: np.ndarray) -> np.ndarray:
        """The task's clipped lane clearances for measured positions (m, world frame)."""
        task, cfg = self.task, self.task.config
        return lane_clearance(cube_xy, obstacle_xy, cfg.cube.size / 2, task._obstacle_half_sizes[0, :2],
                              cfg.table, cfg.layout, (float(cfg.observation.lane_clip[0]),
                                                                  float(cfg.observation.lane_clip[1])))

    def reset(self) -> Transition:
        mujoco.mj_resetData(self.physics.model.ptr, self.physics.data.ptr)
        self.task.initialize_episode(self.physics, self.random_state)
        self._steps = 0
        if self._sensing is not None:
            self._sensing.reset()
            self._sensing_rng = (np.random.default_rng(self.random_state.randint(2**31))
                                 if self.task.config.realism.senses else None)
        if self._actuators is not None:
            self._actuators.reset()
        if self.safety_config is not None and self.safety_config.enabled:
            if self.filter is None:  # needs the task bound to this physics: built at first reset
                self._scene = self.task.make_collision_scene(self.physics)
                self.filter = make_task_filter(self.task, self.safety_config, scene=self._scene)
            self.filter.reset()
        self.safety_stats.reset()
        self.last_filter_result = None
        self.limit_violations = 0
        self.control.reset()
        return Transition(self.observe(), self.task.step_info, False, False)

    def _filtered(self, request: np.ndarray, cartesian: bool) -> np.ndarray:
        if self.filter is None:
            if cartesian:
                raise RuntimeError("cartesian actions need the safety filter (safety.enabled: true)")
            return np.asarray(request, dtype=float)
        q, dq = self.task.arm_state(self.physics)
        if self.safety_config.obstacle_rows:
            self.task.place_objects(self._scene, self.physics)
        result = filter_call(self.filter, cartesian)(q, dq, request)
        self.last_filter_result = result
        self.safety_stats.add(result)
        return result.command

    def step_action(self, action: np.ndarray) -> tuple[StepInfo, bool, bool]:
        """Advance one control step on a policy's normalised ``action`` (shape
        ``(control.action_size,)``, a wrong shape is a ``ValueError``): :attr:`control` maps it to
        the request of ``task.action.mode`` — joint velocities (rad/s) or the tip velocity (m/s,
        world frame) — smoothed over the episode (``task.action.smoothing``), and the safety filter
        makes the joint command from it."""
        request = self.control.smooth(self.control.request(action))
        return self._advance(self._filtered(request, cartesian=self.control.cartesian))

    def step_only(self, request: np.ndarray) -> tuple[StepInfo, bool, bool]:
        """Advance one control step without building the observation dict.

        ``request``: joint velocities for all arm joints, rad/s; the safety filter (if any) turns
        it into the command that reaches the actuators.
        """
        return self._advance(self._filtered(request, cartesian=False))

    def step_cartesian(self, tip_velocity: np.ndarray) -> tuple[StepInfo, bool, bool]:
        """Advance one control step toward a pusher-tip linear velocity (m/s, world frame), turned
        into joint velocities by the safety filter's differential IK (spec §5)."""
        return self._advance(self._filtered(tip_velocity, cartesian=True))

    def _advance(self, command: np.ndarray) -> tuple[StepInfo, bool, bool]:
        self.task.before_step(self.physics, command, self.random_state)
        if self._actuators is None:
            self.physics.step(self._substeps)
        else:  # task.realism: the command arrives late and the actuators follow it with a lag
            actuators, ctrl = self._actuators, self.physics.data.ctrl
            index = self.task._arm_actuators
            actuators.command(command)
            for count, output in actuators.run(self._substeps):  # the sim arm steps it alike
                ctrl[index] = output
                self.physics.step(count)
        self.task.after_step(self.physics, self.random_state)
        self.limit_violations += self._count_limit_violations()
        self._steps += 1
        info = self.task.step_info
        terminated = self.task.should_terminate_episode(self.physics)
        truncated = not terminated and self._steps >= self.max_steps
        if terminated or truncated:
            self.end_episode()
        return info, terminated, truncated

    def end_episode(self) -> None:
        """Close the episode's cross-episode bookkeeping (f3's phase budgets). Called on success
        and time limit here; a caller that ends an episode early for its own reason calls it."""
        self.task.time_objective.end_episode(success=self.task.step_info.success)

    def _count_limit_violations(self) -> int:
        """1 when a limited joint of the simulated arm is outside its position range, else 0."""
        q, _ = self.task.arm_state(self.physics)
        robot = self.task.robot
        outside = (q < robot.position_lower) | (q > robot.position_upper)
        return int(outside.any())

    def step(self, command: np.ndarray) -> Transition:
        info, terminated, truncated = self.step_only(command)
        return Transition(self.observe(), info, terminated, truncated)

    @property
    def steps(self) -> int:
        return self._steps
