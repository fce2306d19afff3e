"""The QP safety filter (spec §5): every joint-velocity command passes through here.

Joint mode (:meth:`SafetyFilter.__call__`)::

    u = argmin ||u - u_nom||^2
        s.t.  max(-v_max, u_prev - a_max dt, (q_min + m - q) / T)
                 <= u <=  min(v_max, u_prev + a_max dt, (q_max - m - q) / T)      (hard box)
              p_z + T (J u)_z >= table + margin              tip and wrist
              lower <= p + T J u <= upper                    tip and wrist (workspace box)
              d_i + T n_i^T J_i u >= d_safe                  robot parts / table; / obstacles (optional)
              d_ab + T n_ab^T (J_a - J_b) u >= d_safe        pairs of arm parts (self-collision)

Cartesian mode (:meth:`SafetyFilter.cartesian`): the same constraints, objective
``||J_tip u - v_nom||^2 + lambda ||u||^2 + w ||P_perp J_w u||^2`` (the last term holds the pusher's
axis direction; ``P_perp`` leaves the spin about the axis free); joints the policy does not command
hold zero velocity (within the box).

``T`` is the horizon over which the rows are linearised: the control period ``dt``, or with
``braking_horizon`` the braking time ``max(dt, max_i v_max_i / a_max_i)``. With the latter every
row stays satisfiable step after step: if ``u`` met the rows at one step, ``(1 - dt/T) u`` meets
them at the next (for a slowly varying Jacobian) and is within the acceleration limit, so the arm
slows down on its way to a bound instead of finding it one period too late.

After the solve the command is verified: it is clipped into the hard box, so every hard bound holds
to rounding whatever the solver's tolerance, and the coupled rows' clearances are measured and
reported. When no command meets every constraint (the QP is infeasible, or a joint is past its
position bound by more than one period's deceleration) or the solver fails, the filter returns the
safest command: the one that violates the coupled rows least and otherwise brakes towards zero,
within the velocity and acceleration limits and as close to the position bounds as they allow.
NaN or inf never pass: a non-finite request is read as a request for zero; a non-finite state gives
a brake towards zero within the acceleration limit.
"""

from __future__ import annotations

import math
import time
from typing import cast

import numpy as np

from ahrm_stack.config import ConfigError, SafetyConfig, arm_acceleration_limit
from ahrm_stack.kinematics.model import ArmKinematics
from ahrm_stack.kinematics.scene import CollisionScene
from ahrm_stack.robot import RobotDescription
from ahrm_stack.safety.constraints import (AccelerationLimit, ArmSnapshot,
                                           CoordinateRows, DistanceLimit, PositionLimit, TableLimit,
                                           VelocityLimit, WorkspaceLimit)
from ahrm_stack.safety.constraints.base import JointBounds
from ahrm_stack.safety.result import (DISABLED, INFEASIBLE, NONFINITE_INPUT, OPTIMAL, SOLVER_FAILED,
                                      FilterResult)
from ahrm_stack.safety.solvers import DaqpSolver, Outcome, OsqpSolver, QPSolver

CONTROL_POINTS = ("tip", "wrist")
ACTIVE_TOLERANCE = 1e-7  # rad/s for bounds, m for rows: closer than this counts as active
VIOLATION_TOLERANCE = 1e-6  # m: a coupled row short by more than this is reported as violated
# The fallback problem: min 1/2 ||u||^2 + rho s + 1/2 s^2 over the box, rows A u - s <= b, s >= 0.
# rho (per metre of violation) is far above what braking is worth, so the worst violation s is
# minimised first and the brake towards zero second.
VIOLATION_WEIGHT = 1e4
SANE = 1e300  # inputs beyond this magnitude (rad, rad/s, m/s) take the careful path
# ndarray.all / .any without their Python wrappers (the same reductions): these run at every call
_all, _any = np.logical_and.reduce, np.logical_or.reduce


class SafetyFilterError(ValueError):
    """The filter was built or called inconsistently (wrong sizes, missing scene); the message
    names the bad value."""


def velocity_margin(robot: RobotDescription, config: SafetyConfig) -> float:
    """The fraction of each velocity limit the filter leaves unused:
    ``max(safety.velocity_margin, robot.min_velocity_margin)`` (an arm whose servo lags more under
    gravity carries a larger lower bound in its description)."""
    return max(float(config.velocity_margin), float(robot.min_velocity_margin))


def acceleration_limit(robot: RobotDescription, config: SafetyConfig) -> tuple[float, ...]:
    """``robot``'s joint acceleration limits, rad/s^2 (``safety.acceleration_limit``: its entry of
    the per-arm mapping, or the one list; :func:`~ahrm_stack.config.arm_acceleration_limit`)."""
    try:
        return arm_acceleration_limit(config.acceleration_limit, robot.name)
    except ConfigError as error:
        raise SafetyFilterError(str(error)) from None


def braking_time(robot: RobotDescription, config: SafetyConfig) -> float:
    """max_i v_i / a_max_i, s, with v_i the commandable speed ``(1 - margin) v_max_i`` (margin:
    :func:`velocity_margin`): the longest time any joint needs to stop from full speed."""
    speed = robot.velocity_limit * (1.0 - velocity_margin(robot, config))
    return float(np.max(speed / np.asarray(acceleration_limit(robot, config), dtype=float)))


class SafetyFilter:
    """QP filter of joint-velocity commands (rad/s) for one arm; one call per control step.

    Args:
        robot: joint position and velocity limits (rad, rad/s).
        kinematics: the Pinocchio model of the arm. The filter works on a private copy of the
            model and its own ``Data``, so calls leave the caller's kinematics alone.
        config: margins, acceleration limits, rows on/off, the solver (``configs/safety.yaml``).
        dt: the control period, s (a command is held this long).
        table_height: z of the table top, m, world frame.
        tip_frame, wrist_frame: frame ids (in ``kinematics``) of the pusher tip and the wrist.
        scene: the collision scene, needed for the distance rows (``config.table_distance_rows``,
            ``config.obstacle_rows``, ``config.self_collision_rows``, or a call with
            ``obstacles=True``). The filter places its
            robot parts itself (on transforms of its own; the scene's robot objects move only when
            a query takes the guarded path); the caller keeps its environment objects current
            (``scene.update_objects``). Building the filter calls ``scene.kinematics.update`` (at
            q = 0) and ``scene.update_robot`` once, to learn where each part sits on its link.

    Raises:
        SafetyFilterError, ConstraintDefinitionError: inconsistent settings (the message names the
            value), at construction, never mid-run.
    """

    def __init__(self, robot: RobotDescription, kinematics: ArmKinematics, config: SafetyConfig, *,
                 dt: float, table_height: float, tip_frame: int, wrist_frame: int,
                 scene: CollisionScene | None = None) -> None:
        nv = robot.num_joints
        if kinematics.model.nv != nv or kinematics.joint_map.nq != kinematics.model.nq:
            raise SafetyFilterError(f"the kinematics model has nq={kinematics.model.nq}, "
                                    f"nv={kinematics.model.nv}; {robot.name} has {nv} joints")
        for name, frame in (("tip_frame", tip_frame), ("wrist_frame", wrist_frame)):
            if not 0 <= frame < len(kinematics.model.frames):
                raise SafetyFilterError(f"{name}={frame!r} is not a frame of the kinematics model")
        if config.solver not in ("daqp", "osqp"):
            raise SafetyFilterError(f"safety.solver is {config.solver!r}; choose daqp or osqp")
        for switch in ("table_distance_rows", "obstacle_rows", "self_collision_rows"):
            if getattr(config, switch) and scene is None:
                raise SafetyFilterError(f"safety.{switch} is on but no collision scene was given "
                                        "(pass task.make_collision_scene(physics))")
        if not (np.isfinite(dt) and dt > 0):
            raise SafetyFilterError(f"dt must be a finite control period > 0 s, got {dt!r}")
        self.robot = robot
        self.config = config
        self.dt = float(dt)
        self.num_joints = nv
        self.velocity = VelocityLimit(robot, velocity_margin(robot, config))
        self.acceleration = AccelerationLimit(acceleration_limit(robot, config), self.dt, nv)
        self.horizon = max(self.dt, braking_time(robot, config)) if config.braking_horizon else self.dt
        self.position = PositionLimit(robot, config.position_margin, self.horizon)
        self.table = (TableLimit(table_height, {"tip": config.table_margin,
                                                "wrist": config.wrist_table_margin}, self.horizon)
                      if config.table_rows else None)
        self.workspace = (WorkspaceLimit(config.workspace_lower, config.workspace_upper, self.horizon,
                                         CONTROL_POINTS) if config.workspace_rows else None)
        # Pinocchio's configuration is q itself when every joint stores its angle (nq = nv): no map
        identity_map = kinematics.model.nq == nv and not len(kinematics.joint_map.continuous)
        self._snapshot = ArmSnapshot(kinematics.model, kinematics.base,
                                     None if identity_map else kinematics.configuration)
        self.distances: DistanceLimit | None = None
        if scene is not None:
            if scene.kinematics.model.nq != kinematics.model.nq or scene.kinematics.model.nv != nv:
                raise SafetyFilterError("the collision scene was built on another kinematics model")
            reference = np.zeros(nv)
            scene.kinematics.update(reference)
            scene.update_robot()
            self._snapshot.update(reference)
            frames = {name: kinematics.frame_id(name) for name in scene.robot if name != "pusher"}
            frames["pusher"] = int(tip_frame)  # the pusher is one rigid body with its tip
            self.distances = DistanceLimit(
                scene, self._snapshot, frames, config.obstacle_safe_distance,
                config.obstacle_activation_distance, config.max_obstacle_rows, self.horizon,
                self_collision_pairs(robot, config, scene))
        self._frames = (int(tip_frame), int(wrist_frame))
        self._commanded = np.zeros(nv, dtype=bool)
        self._commanded[list(robot.commanded_joints)] = True
        point_families = [f for f in (self.table, self.workspace) if f is not None]
        self._point_rows = CoordinateRows.stacked(point_families) if point_families else None
        self.max_rows = (len(self._point_rows.names) if self._point_rows else 0) + \
            (self.distances.max_rows(config.table_distance_rows, True, config.self_collision_rows)
             if self.distances else 0)
        self.solver: QPSolver = (DaqpSolver(nv, self.max_rows) if config.solver == "daqp" else
                                 OsqpSolver(nv, self.max_rows, config.osqp_eps, config.osqp_max_iter))
        self._fallback_solver = DaqpSolver(nv + 1, self.max_rows)
        self._identity = np.eye(nv)
        self._regularization = config.cartesian_regularization * self._identity
        self._previous = np.zeros(nv)
        self.last_rows: tuple[str, ...] = ()  # names of the coupled rows built by the last call
        self._bound_names = (self.position.names, self.velocity.names, self.acceleration.names)
        # Per-call work space: the three families' bounds side by side, (lower/upper, family, joint);
        # velocity (index 1) is constant, acceleration and position are rewritten in place.
        self._box = np.empty((2, 3, nv))
        self._box[0, 1], self._box[1, 1] = self.velocity.bounds()
        self._step = np.stack((-self.acceleration.step, self.acceleration.step))  # (2, nv)
        self._position_limits = np.stack((self.position.lower, self.position.upper))  # (2, nv)
        box = self._box  # views into it, made once: the per-family bounds as each call writes them
        self._box_position, self._box_acceleration = box[:, 0], box[:, 2]
        self._box_families = (JointBounds(box[0, 1], box[1, 1]), JointBounds(box[0, 2], box[1, 2]),
                              JointBounds(box[0, 0], box[1, 0]))  # velocity, acceleration, position
        self._negative_velocity_limit = -self.velocity.limit
        self._rate = 1.0 / self.position.horizon
        self._check = np.empty(3 * nv)
        # Per-call work space of the coupled rows: the control points' rows first, then the
        # distance rows, written in place; each call's rows are the first ones.
        self._point_count = len(self._point_rows.names) if self._point_rows else 0
        self._matrix = np.zeros((self.max_rows, nv))
        self._bound = np.zeros(self.max_rows)
        self._point_matrix, self._point_bound = self._matrix[:self._point_count], self._bound[:self._point_count]
        self._point_jacobians = np.empty((3 * len(CONTROL_POINTS), nv))  # tip, then wrist (x, y, z)
        self._tip_jacobian, self._wrist_jacobian = self._point_jacobians[:3], self._point_jacobians[3:]
        self._point_positions = np.empty((len(CONTROL_POINTS), 3))
        self._point_positions_flat = self._point_positions.reshape(-1)
        self._distance_rows = bool(config.table_distance_rows or config.self_collision_rows)
        # The same bounds as plain floats, for the fast path (six joints are cheaper so than in arrays)
        self._velocity_lower, self._velocity_upper = self._box[0, 1].tolist(), self._box[1, 1].tolist()
        self._step_list: list[float] = np.asarray(self.acceleration.step).tolist()
        self._position_lower, self._position_upper = self.position.lower.tolist(), self.position.upper.tolist()
        self._commanded_list = self._commanded.tolist()

    # ------------------------------------------------------------------ public API
    @property
    def previous_command(self) -> np.ndarray:
        """The command the acceleration limit is measured from (the last returned one), rad/s."""
        return self._previous.copy()

    def reset(self) -> None:
        """Start of an episode: the previous command is zero."""
        self._previous = np.zeros(self.num_joints)

    def __call__(self, q: np.ndarray, dq: np.ndarray, u_nom: np.ndarray, *,
                 obstacles: bool | None = None, u_prev: np.ndarray | None = None) -> FilterResult:
        """Filter the joint-velocity request ``u_nom`` (rad/s, all joints) at joint positions ``q``
        (rad) and velocities ``dq`` (rad/s).

        ``obstacles`` turns the obstacle rows on or off for this call (default: the config).
        ``u_prev`` overrides the stored previous command (e.g. what the hardware executed); the
        returned command becomes the stored previous command either way.
        """
        return self._filter(q, dq, u_nom, False, obstacles, u_prev)

    def cartesian(self, q: np.ndarray, dq: np.ndarray, v_nom: np.ndarray, *,
                  obstacles: bool | None = None, u_prev: np.ndarray | None = None) -> FilterResult:
        """Differential IK under the same constraints: the joint velocities (rad/s) that best give
        the pusher tip the linear velocity ``v_nom`` (m/s, world frame) while holding the pusher's
        axis direction. Arguments as for ``__call__``."""
        return self._filter(q, dq, v_nom, True, obstacles, u_prev)

    # ------------------------------------------------------------------ one call
    def _filter(self, q, dq, request, cartesian: bool, obstacles: bool | None,
                u_prev: np.ndarray | None) -> FilterResult:
        """One call: the fast path (:meth:`_filter_fast`) when the filter is on and every input is
        finite and sane, else the general one (:meth:`_filter_general`), which handles every case."""
        nv = self.num_joints
        q = _vector(q, nv, "q")
        dq = _vector(dq, nv, "dq")
        request = _vector(request, 3 if cartesian else nv, "v_nom" if cartesian else "u_nom")
        given = u_prev is not None
        if given:
            u_prev = _vector(u_prev, nv, "u_prev")
        q_list, request_list = q.tolist(), request.tolist()
        previous = u_prev.tolist() if given else self._previous.tolist()
        # hypot >= every |x| (NaN or inf give NaN or inf), and never overflows below SANE
        if self.config.enabled and math.hypot(*q_list, *dq.tolist(), *request_list, *previous) < SANE:
            return self._filter_fast(q, dq, q_list, request, request_list, previous, given, cartesian,
                                     self.config.obstacle_rows if obstacles is None else obstacles, u_prev)
        return self._filter_general(q, dq, request, cartesian, obstacles, u_prev)

    def _filter_fast(self, q, dq, q_list, request, request_list, previous, given, cartesian, with_obstacles,
                     u_prev) -> FilterResult:
        """:meth:`_filter_general` for a filter that is on and finite, sane inputs, with the per-joint
        work in plain floats (the same operations, so the same numbers; the tests hold the two paths
        to the same results): falls back to it when a position bound is out of reach."""
        if with_obstacles and self.distances is None:
            raise SafetyFilterError("obstacle rows requested but the filter has no collision scene")
        velocity_lower, velocity_upper = self._velocity_lower, self._velocity_upper
        if given:  # as _given_previous: clipped to the velocity limits
            previous = [min(max(p, lo), hi) for p, lo, hi in zip(previous, velocity_lower, velocity_upper)]
        # The hard box: position, velocity, acceleration bounds (as _filter_general writes self._box).
        rate = self._rate
        position_lower = [(b - x) * rate for b, x in zip(self._position_lower, q_list)]
        position_upper = [(b - x) * rate for b, x in zip(self._position_upper, q_list)]
        step = self._step_list
        acceleration_lower = [p - s for p, s in zip(previous, step)]
        acceleration_upper = [p + s for p, s in zip(previous, step)]
        lower = list(map(max, position_lower, velocity_lower, acceleration_lower))
        upper = list(map(min, position_upper, velocity_upper, acceleration_upper))
        if True in map(float.__gt__, lower, upper):  # a position bound out of reach: pinned there
            return self._filter_general(q, dq, request, cartesian, with_obstacles, u_prev)

        # Coupled rows (views of the work space) and the objective.
        if cartesian or self._point_count or with_obstacles or self._distance_rows:
            self._snapshot.update(q)
        matrix, bound, names = self._rows(with_obstacles)
        self.last_rows = names
        if cartesian:
            hessian, linear = self._cartesian_objective(request)
            lower = [lo if c else min(max(0.0, lo), hi) for c, lo, hi in zip(self._commanded_list, lower, upper)]
            upper = [hi if c else lo for c, lo, hi in zip(self._commanded_list, lower, upper)]
            free = np.linalg.solve(hessian, -linear)
            free_list = free.tolist()
        else:
            hessian = self._identity
            free_list = [min(max(r, lo), hi) for r, lo, hi in zip(request_list, velocity_lower, velocity_upper)]
            free = np.array(free_list)
            linear = -free

        # When the unconstrained optimum meets every constraint it is the solution: no solver call.
        start = time.perf_counter()
        fallback = False
        status = OPTIMAL
        if (False not in map(float.__le__, lower, free_list) and False not in map(float.__le__, free_list, upper)
                and (not len(names) or False not in map(float.__le__, (matrix @ free).tolist(), bound.tolist()))):
            command = free_list
        else:
            lower_array, upper_array = np.array(lower), np.array(upper)
            outcome = self.solver.solve(hessian, linear, lower_array, upper_array, matrix, bound)
            if outcome.x is not None:
                command = [min(max(x, lo), hi) for x, lo, hi in zip(outcome.x.tolist(), lower, upper)]
            else:
                status = INFEASIBLE if outcome.status == INFEASIBLE else SOLVER_FAILED
                command, fallback = self._safest(lower_array, upper_array, matrix, bound).tolist(), True
        solve_time = time.perf_counter() - start

        active = self._box_names(command, lower, upper, ((position_lower, position_upper),
                                                         (velocity_lower, velocity_upper),
                                                         (acceleration_lower, acceleration_upper)))
        worst = math.inf
        violated_rows: tuple[str, ...] = ()
        result = np.array(command)
        if names:
            margins = (bound - matrix @ result).tolist()
            worst = min(margins)
            if worst <= ACTIVE_TOLERANCE:
                active += tuple([n for n, m in zip(names, margins) if m <= ACTIVE_TOLERANCE])
                if worst < -VIOLATION_TOLERANCE:
                    violated_rows = tuple([n for n, m in zip(names, margins) if m < -VIOLATION_TOLERANCE])
        if cartesian:
            modified = fallback or bool(active)
        else:
            modified = not all([abs(c - r) <= ACTIVE_TOLERANCE for c, r in zip(command, request_list)])
        self._previous = np.array(command)
        return FilterResult(result, modified, active, status, solve_time, fallback, worst, violated_rows)

    def _filter_general(self, q, dq, request, cartesian: bool, obstacles: bool | None,
                        u_prev: np.ndarray | None) -> FilterResult:
        """One call, any input: non-finite or absurd values, the filter switched off, a position
        bound out of reach."""
        nv = self.num_joints
        q = _vector(q, nv, "q")
        dq = _vector(dq, nv, "dq")
        request = _vector(request, 3 if cartesian else nv, "v_nom" if cartesian else "u_nom")
        with_obstacles = self.config.obstacle_rows if obstacles is None else obstacles
        if with_obstacles and self.distances is None:
            raise SafetyFilterError("obstacle rows requested but the filter has no collision scene")
        # One reduction on the common path: every input finite and of sane size (NaN fails it).
        check = self._check[:2 * nv + len(request)]
        check[:nv], check[nv:2 * nv], check[2 * nv:] = q, dq, request
        if np.maximum.reduce(np.abs(check, out=check)) < SANE:
            state_ok = request_ok = True
        else:
            state_ok = bool(np.isfinite(q).all() and np.isfinite(dq).all())
            request_ok = bool(np.isfinite(request).all())
            q = np.minimum(np.maximum(q, -SANE), SANE)  # absurd but finite: nothing may overflow
        if u_prev is None:
            previous, previous_ok = self._previous, True
        else:
            previous, previous_ok = self._given_previous(u_prev, dq)
        raw_request = request
        if not request_ok:
            request = np.zeros_like(request)  # a non-finite request asks for nothing
        if not self.config.enabled:
            return self._unfiltered(q, request, raw_request, cartesian, state_ok)
        if not state_ok:
            return self._brake_blind(previous, raw_request, cartesian)

        # The hard box. Velocity and acceleration always intersect (|u_prev| <= v_max); where the
        # position bound lies beyond them the joint is pinned to the closest value they allow, and
        # the problem as posed is infeasible.
        # (The velocity and acceleration families' ``bounds``, and the position family's limits
        # as (limit - q) / horizon, written into the preallocated work space.)
        box = self._box
        velocity, acceleration, position = self._box_families
        np.add(previous, self._step, out=self._box_acceleration)
        position_box = self._box_position  # (limit - q) / T
        np.subtract(self._position_limits, q, out=position_box)
        position_box *= self._rate
        lower, upper = np.maximum.reduce(box[0]), np.minimum.reduce(box[1])
        box_violated: tuple[str, ...] = ()
        if _any(np.greater(lower, upper)):
            lower, upper, box_violated = self._pin_unreachable(velocity, acceleration, position)

        # Coupled rows (views of the work space) and the objective.
        self._snapshot.update(q)
        matrix, bound, names = self._rows(with_obstacles)
        if cartesian:
            hessian, linear = self._cartesian_objective(request)
            hold = np.minimum(np.maximum(0.0, lower), upper)
            lower = np.where(self._commanded, lower, hold)
            upper = np.where(self._commanded, upper, hold)
        else:
            hessian = self._identity
            linear = -np.minimum(np.maximum(request, velocity.lower), velocity.upper)
        self.last_rows = names

        # When the unconstrained optimum meets every constraint it is the solution: no solver call
        # (this also keeps OSQP from printing its no-active-set notice, osqp/osqp#785).
        free = -linear if hessian is self._identity else np.linalg.solve(hessian, -linear)
        start = time.perf_counter()
        if box_violated:
            outcome = None
        elif (_all(np.less_equal(lower, free)) and _all(np.less_equal(free, upper))
              and (not len(bound) or _all(np.less_equal(matrix @ free, bound)))):
            outcome = Outcome(free, "optimal")
        else:
            outcome = self.solver.solve(hessian, linear, lower, upper, matrix, bound)
        if outcome is not None and outcome.x is not None:
            command, status, fallback = np.minimum(np.maximum(outcome.x, lower), upper), OPTIMAL, False
        else:
            status = INFEASIBLE if outcome is None or outcome.status == INFEASIBLE else SOLVER_FAILED
            command, fallback = self._safest(lower, upper, matrix, bound), True
        solve_time = time.perf_counter() - start
        if not (state_ok and previous_ok and request_ok):
            status, fallback = NONFINITE_INPUT, True

        active = self._active_box(command, lower, upper)
        worst, violated = np.inf, box_violated
        if len(bound):
            margins = bound - matrix @ command
            worst = float(np.minimum.reduce(margins))
            if worst <= ACTIVE_TOLERANCE:
                active += tuple([names[i] for i in (margins <= ACTIVE_TOLERANCE).nonzero()[0].tolist()])
                if worst < -VIOLATION_TOLERANCE:
                    violated += tuple([names[i] for i in (margins < -VIOLATION_TOLERANCE).nonzero()[0].tolist()])
        if cartesian:
            modified = fallback or bool(active)
        else:
            modified = not (request_ok and np.maximum.reduce(np.abs(command - raw_request)) <= ACTIVE_TOLERANCE)
        self._previous = command.copy()
        return FilterResult(command, modified, active, status, solve_time, fallback, worst, violated)

    def _pin_unreachable(self, velocity, acceleration, position):
        """Box bounds where each joint whose position bound is out of reach this period is pinned
        to the reachable value closest to it, and the names of those position bounds."""
        reachable_lower = np.maximum(velocity.lower, acceleration.lower)
        reachable_upper = np.minimum(velocity.upper, acceleration.upper)
        lower = np.maximum(reachable_lower, position.lower)
        upper = np.minimum(reachable_upper, position.upper)
        conflict = lower > upper
        pinned = np.where(position.upper < reachable_lower, reachable_lower, reachable_upper)
        return (np.where(conflict, pinned, lower), np.where(conflict, pinned, upper),
                tuple(self.position.names[i] for i in np.flatnonzero(conflict)))

    def _given_previous(self, u_prev, dq) -> tuple[np.ndarray, bool]:
        """A caller-given previous command, made finite (non-finite entries are replaced by the
        measured velocity, or zero) and clipped to the velocity limits."""
        previous = _vector(u_prev, self.num_joints, "u_prev")
        ok = bool(_all(np.isfinite(previous)))
        if not ok:
            previous = np.where(np.isfinite(previous), previous, np.where(np.isfinite(dq), dq, 0.0))
        return np.minimum(np.maximum(previous, self._negative_velocity_limit), self.velocity.limit), ok

    def _rows(self, with_obstacles: bool) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
        """This call's coupled rows, written into the work space: (matrix, bound) as views of its
        first rows, and their names. The table and workspace rows first, then the distance rows."""
        count, names = self._point_count, cast(tuple[str, ...], ())
        if count:
            snap = self._snapshot
            tip, wrist = self._frames
            self._tip_jacobian[...] = snap.jacobian(tip)[:3]
            self._wrist_jacobian[...] = snap.jacobian(wrist)[:3]
            snap.positions_into(self._frames, self._point_positions)
            self._point_rows.write(self._point_jacobians, self._point_positions_flat, self._point_matrix,
                                   self._point_bound)
            names = self._point_rows.names
        if with_obstacles or self._distance_rows:
            distance_rows = self.distances.rows(self._snapshot, self.config.table_distance_rows,
                                                with_obstacles, self.config.self_collision_rows)
            added = len(distance_rows.names)
            if added:
                self._matrix[count:count + added] = distance_rows.matrix
                self._bound[count:count + added] = distance_rows.bound
                names = names + distance_rows.names if names else distance_rows.names
                count += added
        return self._matrix[:count], self._bound[:count], names

    def _cartesian_objective(self, v_nom: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tip = self._frames[0]
        jac = self._snapshot.jacobian(tip)
        linear_jac, angular_jac = jac[:3], jac[3:]
        # A request faster than any command could give is scaled down along its direction.
        # (np.linalg.norm(linear_jac, axis=0), without its wrapper: the same sums)
        reach = float(np.sqrt(np.add.reduce(linear_jac * linear_jac, axis=0)) @ self.velocity.limit)
        largest = max(map(abs, v_nom.tolist()))
        if largest > 0:
            unit = v_nom / largest
            speed = math.sqrt(unit @ unit)  # np.linalg.norm's sum (x.dot(x)), without its wrapper
            if largest * speed > reach:
                v_nom = unit * (reach / speed)
        axis = self._snapshot.placement(tip)[1][:, 2]
        off_axis = angular_jac - axis[:, None] * (axis @ angular_jac)  # P_perp J_w (np.outer's product)
        hessian = (linear_jac.T @ linear_jac + self._regularization
                   + self.config.cartesian_orientation_weight * (off_axis.T @ off_axis))
        return hessian, -(linear_jac.T @ v_nom)

    def _safest(self, lower, upper, matrix, bound) -> np.ndarray:
        """The command that violates the coupled rows least (worst row first), then is closest to
        zero, within the box; the box clip of zero if even that solve fails."""
        brake = np.minimum(np.maximum(0.0, lower), upper)
        if not len(bound) or np.all(matrix @ brake <= bound):
            return brake
        nv = self.num_joints
        hessian = np.eye(nv + 1)
        linear = np.zeros(nv + 1)
        linear[-1] = VIOLATION_WEIGHT
        outcome = self._fallback_solver.solve(hessian, linear, np.r_[lower, 0.0], np.r_[upper, np.inf],
                                              np.hstack((matrix, -np.ones((len(bound), 1)))), bound)
        if outcome.x is None:
            return brake
        return np.minimum(np.maximum(outcome.x[:nv], lower), upper)

    def _brake_blind(self, previous, raw_request, cartesian) -> FilterResult:
        """Non-finite state: position and Cartesian bounds cannot be evaluated; brake towards zero
        as fast as the acceleration limit allows."""
        velocity, acceleration = self.velocity.bounds(), self.acceleration.bounds(previous)
        lower = np.maximum(velocity.lower, acceleration.lower)
        upper = np.minimum(velocity.upper, acceleration.upper)
        command = np.clip(0.0, lower, upper)
        active = self._active_bounds(command, lower, upper, (None, velocity, acceleration))
        self._previous = command
        return FilterResult(command, True, active, NONFINITE_INPUT, 0.0, True, np.nan, ())

    def _unfiltered(self, q, request, raw_request, cartesian, state_ok) -> FilterResult:
        """The ablation (``enabled: false``): the request clipped to the robot's velocity limits
        (joint mode) or the unconstrained differential IK (Cartesian mode); NaN/inf still never pass."""
        limit = self.robot.velocity_limit
        if not cartesian:
            command = np.clip(request, -limit, limit)
        elif state_ok:
            self._snapshot.update(q)
            hessian, linear = self._cartesian_objective(request)
            command = np.clip(np.linalg.solve(hessian, -linear), -limit, limit) * self._commanded
        else:
            command = np.zeros(self.num_joints)
        finite = bool(np.isfinite(raw_request).all()) and state_ok
        modified = not (finite and (cartesian or np.array_equal(command, raw_request)))
        self._previous = command
        return FilterResult(command, modified, (), DISABLED if finite else NONFINITE_INPUT, 0.0,
                            False, np.inf, ())

    def _active_box(self, command, lower, upper) -> tuple[str, ...]:
        """:meth:`_active_bounds` of the three families in the work space ``self._box`` (as
        :meth:`_filter_general` writes it), by :meth:`_box_names`: the same names in the same order
        (family, joint)."""
        box_low, box_high = self._box.tolist()  # (family, joint) each
        return self._box_names(command.tolist(), lower.tolist(), upper.tolist(),
                               tuple(zip(box_low, box_high)))

    def _box_names(self, values: list[float], low: list[float], high: list[float],
                   families) -> tuple[str, ...]:
        """Names of the hard bounds the command ``values`` sits on (within ACTIVE_TOLERANCE), in
        plain floats (the same comparisons as numpy's; six joints are cheaper so than in arrays):
        ``low``/``high`` the effective box, ``families`` the (lower, upper) lists of the position,
        velocity and acceleration bounds, whose max (min) the effective bound is, so it equals its
        owners' exactly."""
        at_lower = [c <= b + ACTIVE_TOLERANCE for c, b in zip(values, low)]
        at_upper = [c >= b - ACTIVE_TOLERANCE for c, b in zip(values, high)]
        if not (True in at_lower or True in at_upper):
            return ()
        names = self._bound_names
        joints = [i for i in range(len(low)) if at_lower[i] or at_upper[i]]
        return tuple([names[f][i] for f, (family_low, family_high) in enumerate(families) for i in joints
                      if (at_lower[i] and family_low[i] == low[i]) or (at_upper[i] and family_high[i] == high[i])])

    def _active_bounds(self, command, lower, upper, families) -> tuple[str, ...]:
        """Names of the hard bounds the command sits on (within ACTIVE_TOLERANCE); ``families``:
        the position, velocity and acceleration bounds (position None when not evaluated). The
        effective bound is the max (min) of the families', so it equals its owners' exactly."""
        at_lower = command <= lower + ACTIVE_TOLERANCE
        at_upper = command >= upper - ACTIVE_TOLERANCE
        either = at_lower | at_upper
        if not either.any():
            return ()
        joints = np.flatnonzero(either).tolist()
        low, high = lower.tolist(), upper.tolist()
        low_side, high_side = at_lower.tolist(), at_upper.tolist()
        names = []
        for owner, family in zip(self._bound_names, families):
            if family is None:
                continue
            family_low, family_high = family.lower.tolist(), family.upper.tolist()
            for i in joints:
                if (low_side[i] and family_low[i] == low[i]) or (high_side[i] and family_high[i] == high[i]):
                    names.append(owner[i])
        return tuple(names)


def self_collision_pairs(robot: RobotDescription, config: SafetyConfig,
                         scene: CollisionScene) -> tuple[tuple[str, str], ...]:
    """The configured self-collision pairs of ``robot`` (``safety.self_collision_pairs.<robot>``),
    as the scene's part names: ``base`` is the robot's base body, ``link<i>`` the body joint i
    turns, ``pusher`` the pusher. Empty when ``safety.self_collision_rows`` is off.

    Raises:
        SafetyFilterError: no pair list for the robot, or a part the arm or the scene lacks.
    """
    if not config.self_collision_rows:
        return ()
    listed = config.self_collision_pairs.get(robot.name)
    if listed is None:
        raise SafetyFilterError(f"safety.self_collision_pairs has no entry for robot {robot.name!r}")
    names = {"base": robot.base_body, "pusher": "pusher"}
    names.update({f"link{i + 1}": body for i, body in enumerate(robot.link_bodies)})
    pairs = []
    for k, pair in enumerate(listed):
        for part in pair:
            if names.get(part) not in scene.robot:
                raise SafetyFilterError(
                    f"safety.self_collision_pairs.{robot.name}[{k}]: {part!r} is not a part of the "
                    f"{robot.name} collision scene; its parts: {sorted(names)}")
        pairs.append((names[pair[0]], names[pair[1]]))
    return tuple(pairs)


def _vector(value, size: int, name: str) -> np.ndarray:
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        return value  # the common case, as np.asarray would return it
    array = np.asarray(value, dtype=float)
    if array.shape != (size,):
        raise SafetyFilterError(f"{name} must have shape ({size},), got {array.shape}")
    return array


def make_filter(robot: RobotDescription, kinematics: ArmKinematics, config: SafetyConfig, *,
                control_period: float, table_height: float, tip_site, wrist_site,
                scene: CollisionScene | None = None) -> SafetyFilter:
    """The filter for an arm whose pusher tip and wrist are the MJCF sites ``tip_site`` and
    ``wrist_site`` of the kinematics' model; ``control_period`` in s, ``table_height`` in m.
    For a task, :func:`ahrm_stack.env.control_step.make_task_filter` fills these in from it."""
    return SafetyFilter(robot, kinematics, config, dt=control_period, table_height=table_height,
                        tip_frame=kinematics.element_frame_id(tip_site),
                        wrist_frame=kinematics.element_frame_id(wrist_site), scene=scene)


__all__ = ["SafetyFilter", "SafetyFilterError", "braking_time", "make_filter", "self_collision_pairs"]
