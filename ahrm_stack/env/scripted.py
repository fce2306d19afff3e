"""A scripted push-off controller: Cartesian waypoints for the pusher tip, mink differential IK.

The IK runs on the simulator's own MuJoCo model (``physics.model.ptr``) with a private ``MjData``
that copies ``physics.data.qpos`` every control step, so the cube and obstacle poses it sees are the
real ones. Only the 6 arm DOFs move in the IK; every other DOF (the free joints of the cube and the
obstacles) is held by a :class:`mink.DofFreezingTask` equality constraint.

One :class:`mink.FrameTask` on the pusher tip site carries both objectives, with targets one control
period ahead (positions in metres, world frame):

- position (cost 1): ``tip + v * dt`` for the stage's desired tip velocity ``v`` (m/s);
- orientation: the current rotation turned toward "pusher pointing down" (world -z) by at most
  ``tilt_speed * dt``, with cost ``orientation_cost`` on the tilt (tip-frame x and y) and
  ``roll_cost`` on the spin about the pusher axis (tip-frame z): a spinning pusher drags the cube
  sideways by friction.

Limits: :class:`mink.ConfigurationLimit` (joints 2 and 3) and a collision-avoidance limit keeping
every arm link and the pusher ``collision_margin`` away from the obstacle boxes. In ``travel``
(above the obstacles) the QP also bounds the joint velocities, trading path accuracy for speed;
in the other stages the QP's joint velocities are scaled down uniformly to the velocity limits, so
the tip keeps its Cartesian path and only slows down.

Stages (:attr:`ScriptedPusher.stage`):

- ``lift``: straight up to the travel height (obstacle tops + ``clearance``); skipped when the tip
  starts above it, as it does from the Kinova home posture;
- ``travel``: toward the spot above the push start (behind the cube, on the side opposite the
  chosen free lane) at or above the travel height, until the tip is over it;
- ``descend``: straight down to the push height; the push waits for the pusher to be vertical
  within ``tilt_tolerance``;
- ``push``: along the lane at ``push_speed``, balancing the cube on the pusher and steering it back
  onto the lane's centre line (closed loop on the cube's position and velocity);
- ``hold``: the tip passed the table edge by ``push_overshoot`` without success: stop.
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np

from ahrm_stack.config import ScriptedConfig
from ahrm_stack.env.layout import Layout, choose_lane
from ahrm_stack.env.task import PushOffTask

DOWN = np.array([0.0, 0.0, -1.0])  # world frame


def _saturate(vector: np.ndarray, limit: float) -> np.ndarray:
    """``vector`` scaled down so that its norm is at most ``limit``."""
    norm = float(np.linalg.norm(vector))
    return vector if norm <= limit else vector * (limit / norm)


class _NativeCcdCollisionLimit(mink.CollisionAvoidanceLimit):
    """:class:`mink.CollisionAvoidanceLimit` measuring distances with MuJoCo's native convex solver.

    The task's model disables native CCD (``<flag nativeccd="disable"/>``); the legacy libccd path
    of ``mj_geomDistance`` then misreports separated cylinder/mesh-to-box distances (measured:
    -27 mm for a 12 mm gap). The flag is cleared only while the limit measures, then restored.

    Units: mink 1.3 bounds the step's displacement (m) by ``gain * (distance - margin) / dt``;
    :class:`ScriptedPusher` passes ``gain = collision_gain * dt`` so that a control step closes at
    most ``collision_gain`` of the gap beyond the margin.
    """

    def compute_qp_inequalities(self, configuration: mink.Configuration,
                                dt: float) -> mink.Constraint:
        opt = self.model.opt
        saved = int(opt.disableflags)
        opt.disableflags = saved & ~int(mujoco.mjtDisableBit.mjDSBL_NATIVECCD)
        try:
            return super().compute_qp_inequalities(configuration, dt)
        finally:
            opt.disableflags = saved


class ScriptedPusher:
    """Waypoint pusher for :class:`PushOffTask`; ``__call__`` returns joint velocities in rad/s."""

    def __init__(self, task: PushOffTask, config: ScriptedConfig) -> None:
        self.task = task
        self.config = config
        tc = task.config
        self._dt = tc.episode.control_period  # s
        self._cube_half = tc.cube.size / 2  # m
        self._obstacle_half = np.asarray(tc.obstacles.size[:2]) / 2  # m, (x, y)
        self._edge = tc.table.half_extent[0]  # m, |x| of the table's side edges
        self._travel_z = tc.table.height + tc.obstacles.size[2] + config.clearance  # tip z, m
        self._push_z = tc.table.height + config.push_height  # tip z, m
        self._radius = tc.pusher.radius  # m
        # Horizontal distance from the cube centre back to the pusher axis where the push starts, m.
        self._behind = self._cube_half + self._radius + config.standoff
        self._velocity_limit = task.robot.velocity_limit  # rad/s, per arm joint
        self._model: mujoco.MjModel | None = None
        self._stage = "idle"
        self._direction = 1.0  # +1 pushes toward +x, -1 toward -x
        self._lane_y = 0.0  # m, the lane's centre line is y = lane_y
        self._planned_start_x = 0.0  # m, x of the push start planned at reset (the strip's back)
        self._tilt = 0.0  # rad, angle of the pusher axis from world -z

    @property
    def stage(self) -> str:
        """The current stage: idle, lift, travel, descend, push or hold."""
        return self._stage

    @property
    def lane(self) -> str:
        """The lane chosen at the last :meth:`reset`: ``"+x"`` or ``"-x"``."""
        return "+x" if self._direction > 0 else "-x"

    @property
    def model(self) -> mujoco.MjModel | None:
        """The MuJoCo model the IK is bound to (the simulator's); None before :meth:`reset`."""
        return self._model

    # ------------------------------------------------------------------ episode set-up
    def reset(self, physics) -> None:
        """Bind to ``physics`` (an ``mjcf.Physics``), rebuilding the IK if its model changed, and
        plan the episode from the settled cube and obstacle positions. Call after every
        ``runner.reset()``."""
        if physics.model.ptr is not self._model:
            self._bind(physics)
        self._configuration.update(physics.data.qpos)
        tip = self._tip()
        xpos = physics.data.xpos
        self._choose_lane(tip, Layout(xpos[self._cube_body, :2].copy(),
                                      xpos[self._obstacle_bodies, :2].copy()))
        below = tip[2] < self._travel_z - self.config.waypoint_tolerance
        self._stage = "lift" if below else "travel"

    def _bind(self, physics) -> None:
        """Build the mink problem on the simulator's model and cache ids into it."""
        cfg, task = self.config, self.task
        model = physics.model.ptr
        self._model = model
        self._configuration = mink.Configuration(model)
        self._tip_site = int(physics.bind(task.pusher.tip_site).element_id)
        self._cube_body = int(physics.bind(task.cube.geom).bodyid)
        self._cube_dofs = task.addresses.cube_dof[:2]  # linear (x, y) of its free joint
        self._arm_dofs = np.asarray(physics.bind(task.arm.joints).dofadr, dtype=int)
        frozen = sorted(set(range(model.nv)) - set(self._arm_dofs.tolist()))
        self._freeze = mink.DofFreezingTask(model, dof_indices=frozen)
        tilt_roll_cost = [cfg.orientation_cost, cfg.orientation_cost, cfg.roll_cost]
        self._tip_task = mink.FrameTask(self._tip_site, "site", position_cost=1.0,
                                        orientation_cost=tilt_roll_cost)
        robot = task.arm.mjcf_model.find_all("geom") + task.pusher.mjcf_model.find_all("geom")
        robot_geoms = [int(i) for i in physics.bind(robot).element_id]
        obstacle_geoms = [int(physics.bind(o.geom).element_id) for o in task.obstacles]
        self._obstacle_bodies = np.asarray(
            [int(physics.bind(o.geom).bodyid) for o in task.obstacles], dtype=int)
        self._limits = [
            mink.ConfigurationLimit(model),
            _NativeCcdCollisionLimit(model, [(robot_geoms, obstacle_geoms)],
                                     gain=cfg.collision_gain * self._dt,
                                     minimum_distance_from_collisions=cfg.collision_margin,
                                     collision_detection_distance=cfg.collision_detection),
        ]
        # Above the obstacles (travel) the QP itself respects the velocity limits, trading path
        # accuracy for speed; near them the Cartesian path is kept and only slowed down.
        speeds = {joint.full_identifier: float(limit)
                  for joint, limit in zip(task.arm.joints, self._velocity_limit)}
        self._travel_limits = self._limits + [mink.VelocityLimit(model, speeds)]

    def _tip(self) -> np.ndarray:
        """Pusher tip (centre of its free end face), world frame, m."""
        return self._configuration.data.site_xpos[self._tip_site].copy()

    def _choose_lane(self, tip: np.ndarray, layout: Layout) -> None:
        """Plan the episode's lane (:func:`~ahrm_stack.env.layout.choose_lane`: the free lane with
        the most room, ties to the tip's side) from the settled ``layout`` ((x, y), m) and the
        tip; its centre line is the line through the cube along the lane."""
        tc = self.task.config
        lane = choose_lane(layout, tip[:2], self._cube_half, self._obstacle_half, tc.table, tc.layout)
        self._direction = 1.0 if tc.layout.lane_directions[lane] == "+x" else -1.0
        self._lane_y = float(layout.cube_xy[1])
        self._planned_start_x = float(layout.cube_xy[0] - self._direction * self._behind)

    # ------------------------------------------------------------------ control
    def __call__(self, physics, stateless: bool = False) -> np.ndarray:
        """Joint velocities (rad/s) for the 6 arm joints, within ``task.robot.velocity_limit``
        (``stateless``: see :meth:`tip_velocity`)."""
        tip, tip_velocity = self._plan(physics, stateless)
        return self._solve(tip, tip_velocity)

    def tip_velocity(self, physics, stateless: bool = False) -> np.ndarray:
        """The stage's desired pusher-tip velocity (m/s, world frame), without the IK: the request
        of ``action.mode: cartesian``, where the safety filter's differential IK makes the joint
        command (and holds the pusher's tilt instead of turning it toward vertical).

        ``stateless``: the stage is first inferred from the state alone (:meth:`infer_stage`), not
        carried over from the previous call, so that the label of a state does not depend on how
        the tip got there (the expert a DAgger relabelling needs). The lane stays the one chosen
        at :meth:`reset`, a function of the episode's initial layout."""
        return self._plan(physics, stateless)[1]

    def _plan(self, physics, stateless: bool = False) -> tuple[np.ndarray, np.ndarray]:
        self._configuration.update(physics.data.qpos)
        tip = self._tip()
        axis = self._configuration.data.site_xmat[self._tip_site].reshape(3, 3)[:, 2]
        self._tilt = float(np.arccos(np.clip(axis @ DOWN, -1.0, 1.0)))
        cube = np.asarray(physics.data.xpos[self._cube_body])
        cube_velocity = np.asarray(physics.data.qvel[self._cube_dofs])  # free joint: world, m/s
        if stateless:
            self._stage = self.infer_stage(tip, cube)
        return tip, self._tip_velocity(tip, cube, cube_velocity)

    def infer_stage(self, tip: np.ndarray, cube: np.ndarray) -> str:
        """The stage for this state alone (positions world frame, m), with the lane chosen at
        :meth:`reset`:

        - ``hold``: the tip is past the table edge by ``push_overshoot`` along the lane;
        - ``push``: the tip is at push height (within ``waypoint_tolerance``), in the lane's
          strip (not behind the push start planned at :meth:`reset`), behind the cube's face (less
          ``waypoint_tolerance``) and across the lane within the cube's half-width plus the
          pusher's radius of the push law's line (where the law realigns or advances);
        - ``descend``: elsewhere, with the tip within ``descend_radius`` of the spot over the push
          start (wider than ``travel``'s ``waypoint_tolerance``, so a descent is not undone);
        - ``lift``: below the travel height and not over the push start;
        - ``travel``: at or above the travel height, not over the push start.

        The pusher's tilt only gates the start of the push, in :meth:`_tip_velocity`, which then
        runs on from the inferred stage as it does from a carried-over one."""
        cfg = self.config
        d = self._direction
        if d * tip[0] >= self._edge + cfg.push_overshoot:
            return "hold"
        along = d * (cube[0] - tip[0])  # m, the cube ahead of the tip along the lane
        contact = self._cube_half + self._radius
        lean = np.clip(np.arctan(cfg.steer_gain * d * (cube[1] - self._lane_y)),
                       -cfg.max_heading, cfg.max_heading)
        off = tip[1] - (cube[1] + contact * d * np.sin(lean))  # the push law's offset, m
        in_strip = d * (tip[0] - self._planned_start_x) >= -cfg.waypoint_tolerance
        if (abs(tip[2] - self._push_z) <= cfg.waypoint_tolerance and in_strip
                and along >= contact - cfg.waypoint_tolerance and abs(off) <= contact):
            return "push"
        start = np.array([cube[0] - d * self._behind, cube[1]])
        if np.linalg.norm(start - tip[:2]) <= cfg.descend_radius:
            return "descend"
        return "lift" if tip[2] < self._travel_z - cfg.waypoint_tolerance else "travel"

    def _goto(self, tip: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Proportional approach of ``goal`` at most at ``travel_speed``, m/s."""
        return _saturate(self.config.position_gain * (goal - tip), self.config.travel_speed)

    def _tip_velocity(self, tip: np.ndarray, cube: np.ndarray,
                      cube_velocity: np.ndarray) -> np.ndarray:
        """Desired tip velocity (m/s, world frame); advances the stage at each waypoint."""
        cfg = self.config
        start = np.array([cube[0] - self._direction * self._behind, cube[1]])  # push start, xy
        if self._stage == "lift":
            if tip[2] < self._travel_z - cfg.waypoint_tolerance:
                return self._goto(tip, np.array([tip[0], tip[1], self._travel_z]))
            self._stage = "travel"
        if self._stage == "travel":
            goal = np.array([*start, self._travel_z])
            if np.linalg.norm(goal[:2] - tip[:2]) > cfg.waypoint_tolerance:
                return self._goto(tip, goal)
            self._stage = "descend"
        if self._stage == "descend":
            goal = np.array([*start, self._push_z])
            far = np.linalg.norm(goal - tip) > cfg.waypoint_tolerance
            if far or self._tilt > cfg.tilt_tolerance:
                return self._goto(tip, goal)
            self._stage = "push"
        if self._stage == "push":
            if self._direction * tip[0] < self._edge + cfg.push_overshoot:
                return self._push_velocity(tip, cube, cube_velocity)
            self._stage = "hold"
        return np.zeros(3)

    def _push_velocity(self, tip: np.ndarray, cube: np.ndarray,
                       cube_velocity: np.ndarray) -> np.ndarray:
        """Tip velocity (m/s, world frame) for the push, steering the cube back onto the lane line.

        The contact mostly sticks, so the cube swings about it like a broom balanced on a hand: the
        tip is held at the y of the contact point c = cube - (cube half + pusher radius) * u, where
        the push direction u leans toward the lane line by ``atan(steer_gain * e)`` for a cube
        offset e from it (at most ``max_heading``). Across the lane the tip follows the cube's
        velocity and corrects its distance to c at ``position_gain``; along u it advances at
        ``push_speed``, slowed to a stop as it gets ``realign_distance`` off c's y.
        """
        cfg = self.config
        lean = np.clip(np.arctan(cfg.steer_gain * self._direction * (cube[1] - self._lane_y)),
                       -cfg.max_heading, cfg.max_heading)
        u = self._direction * np.array([np.cos(lean), -np.sin(lean)])
        off = tip[1] - (cube[1] - (self._cube_half + self._radius) * u[1])  # m, across the lane
        advance = cfg.push_speed * max(0.0, 1.0 - abs(off) / cfg.realign_distance)
        v_xy = advance * u + np.array([0.0, cube_velocity[1] - cfg.position_gain * off])
        return np.array([*v_xy, cfg.position_gain * (self._push_z - tip[2])])

    def _solve(self, tip: np.ndarray, tip_velocity: np.ndarray) -> np.ndarray:
        """One differential-IK step toward ``tip + tip_velocity * dt`` with the pusher turned toward
        vertical; returns the arm's joint velocities (rad/s), scaled into the velocity limits."""
        cfg = self.config
        frame = self._configuration.get_transform_frame_to_world(self._tip_site, "site")
        rotation = frame.rotation()
        turn = np.cross(rotation.as_matrix()[:, 2], DOWN)  # world axis tipping the pusher down
        if self._tilt > 1e-6 and np.linalg.norm(turn) > 1e-9:
            step = min(cfg.tilt_gain * self._tilt, cfg.tilt_speed) * self._dt  # rad
            rotation = mink.SO3.exp(turn / np.linalg.norm(turn) * step) @ rotation
        self._tip_task.set_target(
            mink.SE3.from_rotation_and_translation(rotation, tip + tip_velocity * self._dt))
        velocity = mink.solve_ik(self._configuration, [self._tip_task], self._dt, cfg.solver,
                                 damping=cfg.damping, constraints=[self._freeze],
                                 limits=self._travel_limits if self._stage == "travel"
                                 else self._limits)
        command = velocity[self._arm_dofs]
        scale = float(np.max(np.abs(command) / self._velocity_limit))
        return command / scale if scale > 1.0 else command
