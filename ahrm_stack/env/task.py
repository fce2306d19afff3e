"""The push-off task: a composer task that composes the arena, the arm with its pusher, the cube and
the obstacles, and owns only the episode logic (layout at reset, reward components, phase, success).

Each control step (``control_period`` s) the task:

1. sends the joint-velocity command (rad/s, all arm joints) to the velocity actuators;
2. after the physics substeps, places the pusher by Pinocchio forward kinematics, computes the
   phase k and the boundary distance x (:mod:`ahrm_stack.kinematics.phases`), the reward components
   f = (f1, f2, f3) and their penalty form g, and whether the cube has left the table.

The results of the last step are in :attr:`PushOffTask.step_info`.
The observation (the observables, the flat vector, the lane plan) lives in the task's base class
:class:`~ahrm_stack.env.task_observation.TaskObservation`.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
from dm_control import composer, mjcf
from dm_env import specs

from ahrm_stack.config import ConfigError, TaskConfig
from ahrm_stack.env.arena import TableArena
from ahrm_stack.env.clearance import Clearance
from ahrm_stack.env.control_step import command_to_action
from ahrm_stack.env.entities import BoxProp, Pusher
from ahrm_stack.env.layout import Layout, LayoutSampler, choose_lane, free_lanes
from ahrm_stack.realism import DynamicsVariation, draw_dynamics
from ahrm_stack.env.start_pose import solve_start_pose
from ahrm_stack.env.task_observation import TaskObservation
from ahrm_stack.env.rewards import (ProgressObjective, TimeObjective, avoid_component,
                                    obstacle_touched, penalty_form, progress)
from ahrm_stack.kinematics.model import make_kinematics, relative_name
from ahrm_stack.kinematics.scene import CollisionScene, link_capsules
from ahrm_stack.kinematics.phases import Cylinder, PhaseScene, RegionParams, phase_geometry
from ahrm_stack.robot import describe, make_arm

CUBE_RGBA = (0.8, 0.1, 0.1, 1.0)
OBSTACLE_RGBA = (0.2, 0.35, 0.8, 1.0)
INTEGRATORS = {"euler": "Euler", "implicitfast": "implicitfast"}  # task.episode.integrator -> MJCF's name


@dataclasses.dataclass
class StepInfo:
    """What one control step produced. Positions in metres, world frame."""

    f: np.ndarray  # (3,) +-1 components: avoid, manipulate, time
    g: np.ndarray  # (3,) penalty form (f - 1) / 2
    phase: int  # 1 approach, 2 pre-manipulate, 3 manipulate
    x: float  # signed distance to the next phase's region, m
    distances: np.ndarray  # (2,) signed distances to B_obstacles and B_target, m, clipped to
    # +-regions.distance_clip (exact within it)
    success: bool  # the cube's centre left the table top
    touched: bool  # an obstacle was touched (contact or moving)
    tip: np.ndarray  # (3,) pusher tip position
    target: np.ndarray  # (3,) cube centre
    progress: float  # P = d - l, m
    elapsed: float  # episode time after this step, s
    # smallest distance of the cube / of the pusher to any obstacle, m; measured only with
    # task.rewards.avoid_margin > 0 (exact within the margin, a lower bound beyond it)
    cube_clearance: float = float("inf")
    pusher_clearance: float = float("inf")

    @property
    def clearance(self) -> float:
        """The nearer of the cube's and the pusher's clearance, m."""
        return min(self.cube_clearance, self.pusher_clearance)

    @classmethod
    def empty(cls) -> "StepInfo":
        return cls(f=np.ones(3), g=np.zeros(3), phase=1, x=0.0, distances=np.zeros(2), success=False, touched=False,
                   tip=np.zeros(3), target=np.zeros(3), progress=0.0, elapsed=0.0)


@dataclasses.dataclass(frozen=True)
class JointAddresses:
    """Where the arm's joints and the free joints of the cube and the obstacles sit in one
    compiled physics (indices into ``data.qpos`` / ``data.qvel``). A free joint has 7 qpos —
    position (3, m, world frame) then orientation quaternion (4, w x y z) — and 6 dofs, of which
    the first 3 (kept here) are the linear velocity, m/s, world frame."""

    arm_qpos: np.ndarray  # (n_joints,) joint angles, rad
    arm_dof: np.ndarray  # (n_joints,) joint velocities, rad/s
    cube_qpos: np.ndarray  # (7,)
    cube_dof: np.ndarray  # (3,) linear velocity
    obstacle_qpos: np.ndarray  # (n_obstacles, 7)
    obstacle_dof: np.ndarray  # (n_obstacles, 3) linear velocities


@dataclasses.dataclass(frozen=True)
class BodyIds:
    """Where the pusher's tip site and the props (the cube, then the obstacles) sit in one compiled
    physics: MuJoCo ids (rows of ``data.site_xpos`` / ``data.xpos``) and the props' linear dofs."""

    tip_site: int  # the pusher tip's site id
    cube: int  # the cube's body id
    obstacles: np.ndarray  # (n_obstacles,) body ids
    props: np.ndarray  # (1 + n_obstacles,) body ids: the cube, then the obstacles
    prop_linear_dofs: np.ndarray  # (1 + n_obstacles, 3) dof addresses: world-frame linear velocity


class PushOffTask(TaskObservation, composer.Task):
    """Push the target cube off the table without touching the obstacles (spec §1-3)."""

    def __init__(self, config: TaskConfig) -> None:
        self.config = config
        self._arena = TableArena(config.table)
        self._arm = make_arm(config.robot)
        self.robot = describe(config.robot, self._arm)
        if len(config.arm.home) != self.robot.num_joints:
            raise ConfigError(f"task.arm.home_deg: {len(config.arm.home)} angles for robot "
                              f"{config.robot!r}, which has {self.robot.num_joints} joints")
        self._pusher = Pusher(config.pusher.radius, config.pusher.length, config.pusher.mass)
        self._arm.attach(self._pusher, self._arm.wrist_site)
        frame = self._arena.attach(self._arm)
        frame.pos = config.arm.base_position
        half_yaw = config.arm.base_yaw / 2
        frame.quat = [np.cos(half_yaw), 0, 0, np.sin(half_yaw)]
        self._arena.add_pedestal(config.arm.base_position, config.arm.base_position[2])
        self.kinematics = make_kinematics(self.robot, self._arm.mjcf_model, config.arm.base_position,
                                          config.arm.base_yaw)
        self._tip_frame = self.kinematics.element_frame_id(self._pusher.tip_site)
        self._center_frame = self.kinematics.element_frame_id(self._pusher.center_site)

        self._cube = BoxProp("cube", [config.cube.size / 2] * 3, config.cube.mass, CUBE_RGBA)
        self._arena.add_free_entity(self._cube)
        obstacle_half = [s / 2 for s in config.obstacles.size]
        self._obstacles = []
        for i in range(len(config.obstacles.fixed_layout)):
            obstacle = BoxProp(f"obstacle_{i}", obstacle_half, config.obstacles.mass, OBSTACLE_RGBA)
            self._arena.add_free_entity(obstacle)
            self._obstacles.append(obstacle)
        self.layout_sampler = LayoutSampler(config.table, config.cube, config.obstacles, config.layout)
        self.set_timesteps(control_timestep=config.episode.control_period,
                           physics_timestep=config.episode.physics_timestep)
        # the composer arena sets 5 (with noslip_tolerance 0: every pass runs); the config decides
        self._arena.mjcf_model.option.noslip_iterations = config.episode.noslip_iterations
        self._arena.mjcf_model.option.integrator = INTEGRATORS[config.episode.integrator]
        self._arena.mjcf_model.option.impratio = config.episode.impratio

        regions = config.regions
        self._region_params = RegionParams(regions.target_half_width, regions.target_height,
                                           regions.obstacle_margin, regions.obstacle_height)
        self._obstacle_half_sizes = np.tile(obstacle_half, (len(self._obstacles), 1))
        margin = config.rewards.avoid_margin
        self._clearance = (Clearance([config.cube.size / 2] * 3, self._obstacle_half_sizes, self._pusher.radius,
                                     self._pusher.half_length, reach=margin) if margin > 0 else None)
        self._table_center = np.zeros(2)
        self.progress_objective = ProgressObjective(config.rewards.progress_eps)
        self.time_objective = TimeObjective(config.episode.duration,
                                            reference=config.rewards.time_reference)
        self.layout: Layout | None = None
        self._lane_plan: np.ndarray | None = None  # the episode's lane, one-hot (lane_choice)
        self.start_target: np.ndarray | None = None  # the random start's tip target, m (world)
        self.start_fallbacks = 0  # random starts that fell back to the home posture
        # share of episodes that start near the cube (task.arm.near_cube) instead of by
        # task.arm.start: the trainer's start curriculum sets it; 0 leaves the random stream as is
        self.near_cube_share = 0.0
        # the reverse curriculum's start states: a callable(random_state) -> StartState | None
        # (ahrm_stack.learning.start_states); None: the task draws every start itself
        self.start_states = None
        self.step_info = StepInfo.empty()  # observables are evaluated once before the first reset
        self.previous_action = np.zeros(len(self.robot.commanded_joints))
        self._command = np.zeros(self.robot.num_joints)
        self.addresses: JointAddresses | None = None  # set for the physics of each reset
        self._declare_observables()

    # ------------------------------------------------------------------ composition
    @property
    def root_entity(self) -> TableArena:
        return self._arena

    @property
    def arm(self) -> composer.Entity:
        return self._arm

    @property
    def pusher(self) -> Pusher:
        return self._pusher

    @property
    def cube(self) -> BoxProp:
        return self._cube

    @property
    def obstacles(self) -> list[BoxProp]:
        return list(self._obstacles)

    def enable_sleep(self, physics: mjcf.Physics) -> None:
        """Turn on MuJoCo's body sleeping in ``physics`` (``task.episode.sleep``): the resting
        obstacles leave the physics step until a contact with an awake body or a write to their
        state wakes them. The arm (actuated) never sleeps, and neither does the cube: MuJoCo makes
        no contact between two sleeping bodies, so a cube come to rest against an obstacle would
        stop counting as a touch (f1) if both slept."""
        model = physics.model.ptr
        model.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        cube_body = int(physics.bind(self._cube.geom).bodyid)
        model.tree_sleep_policy[model.body_treeid[cube_body]] = int(mujoco.mjtSleepPolicy.mjSLEEP_NEVER)

    def arm_state(self, physics: mjcf.Physics) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (rad) and velocities (rad/s) of the arm."""
        return physics.data.qpos[self._arm_qpos].copy(), physics.data.qvel[self._arm_dof].copy()

    def place_objects(self, scene: CollisionScene, physics: mjcf.Physics) -> None:
        """Move the scene's cube and obstacles to their poses in ``physics``."""
        xpos, xmat = physics.data.ptr.xpos, physics.data.ptr.xmat  # MuJoCo's arrays: no dm_control indexing
        scene.update_objects(xpos[self._cube_body], xmat[self._cube_body].reshape(3, 3),
                             xpos[self._obstacle_bodies], xmat[self._obstacle_bodies].reshape(-1, 3, 3))

    def make_collision_scene(self, physics: mjcf.Physics) -> CollisionScene:
        """The collision scene of this task: pusher, base and link capsules (from the compiled
        geoms), table, cube and obstacles, placed at the current state of ``physics``."""
        kin = self.kinematics
        parts = (self.robot.base_body, *self.robot.link_bodies)
        bodies = [(int(physics.bind(body).element_id), relative_name(body, self._arm.mjcf_model))
                  for body in self._arm.mjcf_model.find_all("body")
                  if relative_name(body, self._arm.mjcf_model) in parts]
        scene = CollisionScene(
            kin, link_capsules(physics.model.ptr, bodies),
            relative_name(self._pusher.center_site, self._arm.mjcf_model), self._pusher.radius,
            self._pusher.half_length, self.config.table.half_extent, self.config.table.height,
            self.config.table.thickness, self.config.cube.size, self._obstacle_half_sizes,
            base_frame=self.robot.base_body)
        kin.update(physics.data.qpos[self._arm_qpos])
        scene.update_robot()
        self.place_objects(scene, physics)
        return scene

    def get_reward_spec(self) -> specs.Array:
        return specs.Array(shape=(3,), dtype=np.float64, name="f")

    # ------------------------------------------------------------------ episode logic
    def initialize_episode(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        self._bind(physics)
        self._vary_dynamics(physics, random_state)
        if self.start_states is not None:
            start = self.start_states(random_state)
            if start is not None:
                self._restore(physics, start)
                return
        cfg = self.config
        self.layout = self.layout_sampler.sample(random_state)
        z_table = cfg.table.height
        self._cube.set_pose(physics, [*self.layout.cube_xy, z_table + cfg.cube.size / 2], [1, 0, 0, 0])
        for obstacle, xy in zip(self._obstacles, self.layout.obstacle_xy):
            obstacle.set_pose(physics, [*xy, z_table + cfg.obstacles.size[2] / 2], [1, 0, 0, 0])
        q0 = np.asarray(cfg.arm.home) + random_state.uniform(-1, 1, self.robot.num_joints) * cfg.arm.joint_jitter
        q0 = np.clip(q0, self.robot.position_lower, self.robot.position_upper)
        if self.near_cube_share > 0 and random_state.uniform() < self.near_cube_share:
            q0 = self._ik_start(physics, random_state, q0, self._near_cube_target)
        elif cfg.arm.start == "random":
            q0 = self._random_start(physics, random_state, q0)
        physics.data.qpos[self._arm_qpos] = q0
        physics.data.ctrl[:] = 0.0
        self._settle(physics, q0)
        self.begin_episode(physics)

    def _vary_dynamics(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """``task.realism``'s episode draw of the cube's and obstacles' mass and friction (from
        ``random_state``; nothing drawn when the ranges are all [1, 1])."""
        realism = self.config.realism
        if not realism.varies_dynamics:
            return
        variation = getattr(self, "_dynamics", None)
        if variation is None or variation.physics is not physics:
            variation = DynamicsVariation(physics, int(self._cube_body), self._obstacle_bodies,
                                          int(self._cube_geom), self._obstacle_geoms)
            self._dynamics = variation
        variation.apply(draw_dynamics(realism, random_state, len(self._obstacle_bodies)))

    @property
    def dynamics_factors(self) -> dict[str, np.ndarray]:
        """This episode's mass and friction factors (empty without ``task.realism`` dynamics)."""
        variation = getattr(self, "_dynamics", None)
        return {} if variation is None else variation.factors

    @property
    def obstacle_half_sizes(self) -> np.ndarray:
        """(n_obstacles, 3) half sizes of the obstacle boxes, m (a copy)."""
        return self._obstacle_half_sizes.copy()

    def begin_episode(self, physics: mjcf.Physics) -> None:
        """The episode's bookkeeping once its state is set: no previous command, the clock and
        the objectives restarted, the first step measured, the lane to be planned."""
        self.previous_action = np.zeros(len(self.robot.commanded_joints))
        self._command = np.zeros(self.robot.num_joints)
        self._episode_start = physics.data.time
        self.time_objective.reset()
        self.step_info = self._measure(physics, phase_time=0.0)
        self.progress_objective.reset(self.step_info.progress)
        self._lane_plan = None  # planned at the episode's first observation

    def _restore(self, physics: mjcf.Physics, start) -> None:
        """Start the episode from a recorded state (its layout, qpos and qvel); the arm at rest,
        so that the previous command in the observation (zero) is true."""
        self.layout = start.layout
        data = physics.data
        data.qpos[:] = start.qpos
        data.qvel[:] = start.qvel
        data.qvel[self._arm_dof] = 0.0
        data.ctrl[:] = 0.0
        data.qacc_warmstart[:] = 0.0
        physics.forward()
        self.start_target = None
        self.begin_episode(physics)

    def _random_start(self, physics: mjcf.Physics, random_state: np.random.RandomState,
                      q_home: np.ndarray) -> np.ndarray:
        """A posture with the pusher tip at a uniform point of ``task.arm.start_region``, pointing
        down, free of contact (:func:`solve_start_pose` from the jittered home ``q_home``); up to
        ``task.arm.start_ik.tries`` targets are drawn, then the home posture is kept (and counted)."""
        region = np.asarray(self.config.arm.start_region, dtype=float)
        return self._ik_start(physics, random_state, q_home,
                              lambda rs: rs.uniform(region[:, 0], region[:, 1]))

    def _near_cube_target(self, random_state: np.random.RandomState) -> np.ndarray:
        """A tip target (m, world) around the cube centre, at a uniform horizontal distance in
        ``task.arm.near_cube.distance`` and height above the table top in
        ``task.arm.near_cube.height``; its bearing uniform (``bearing: any``) or within
        ``behind_spread_deg`` of the side opposite the episode's lane (``bearing: behind``; the
        lane as :func:`~ahrm_stack.env.layout.choose_lane` plans it, ties as from the cube), or
        opposite a lane drawn uniformly among the free ones (``bearing: behind_free``,
        :func:`~ahrm_stack.env.layout.free_lanes`: no planner; every lane when none is free)."""
        near = self.config.arm.near_cube
        assert self.layout is not None, "drawn after the episode's layout"
        if near.bearing in ("behind", "behind_free"):
            cfg = self.config
            lane: str
            if near.bearing == "behind":
                lane = cfg.layout.lane_directions[choose_lane(
                    self.layout, np.asarray(self.layout.cube_xy, dtype=float), cfg.cube.size / 2,
                    self._obstacle_half_sizes[0, :2], cfg.table, cfg.layout)]
            else:
                free = free_lanes(self.layout, cfg.cube.size / 2, self._obstacle_half_sizes[0, :2], cfg.table,
                                  cfg.layout) or list(cfg.layout.lane_directions)
                lane = free[random_state.randint(len(free))]
            back = np.pi if lane == "+x" else 0.0  # push toward the lane
            spread = np.deg2rad(near.behind_spread_deg)
            bearing = back + random_state.uniform(-spread, spread)
        else:
            bearing = random_state.uniform(0.0, 2 * np.pi)
        distance = random_state.uniform(*near.distance)
        height = random_state.uniform(*near.height)
        x, y = self.layout.cube_xy
        return np.array([x + distance * np.cos(bearing), y + distance * np.sin(bearing),
                         self.config.table.height + height])

    def _ik_start(self, physics: mjcf.Physics, random_state: np.random.RandomState,
                  q_home: np.ndarray, draw_target) -> np.ndarray:
        """The first contact-free IK posture for targets from ``draw_target(random_state)``; after
        ``task.arm.start_ik.tries`` failures the home posture is kept (and counted)."""
        model, data = physics.model.ptr, physics.data.ptr
        for _ in range(self.config.arm.start_ik.tries):
            target = draw_target(random_state)
            result = solve_start_pose(model, data, self._arm_qpos, self._arm_dof, self._tip_site_id,
                                      target, q_home, self.robot.position_lower,
                                      self.robot.position_upper, self._is_arm, self.config.arm.start_ik)
            if result.ok:
                self.start_target = target
                return result.q
        self.start_fallbacks += 1
        self.start_target = None
        return q_home

    def _settle(self, physics: mjcf.Physics, q0: np.ndarray) -> None:
        """Let the free bodies come to rest on the table, then restore the arm and zero velocities."""
        physics.data.qvel[:] = 0.0
        physics.data.qacc_warmstart[:] = 0.0  # stale from before the bodies were placed
        physics.forward()
        for _ in range(self.config.layout.settle_steps):
            physics.data.qpos[self._arm_qpos] = q0
            physics.data.qvel[self._arm_dof] = 0.0
            physics.step()
        physics.data.qpos[self._arm_qpos] = q0
        physics.data.qvel[:] = 0.0
        physics.forward()

    def _bind(self, physics: mjcf.Physics) -> None:
        """Cache indices into the (possibly rebuilt) physics; called at every reset. The joint
        addresses are :attr:`addresses`, which every reader of the joints' state uses."""
        model = physics.model
        joints = physics.bind(self._arm.joints)
        self._arm_qpos = np.asarray(joints.qposadr, dtype=int)
        self._arm_dof = np.asarray(joints.dofadr, dtype=int)
        self._arm_actuators = np.asarray(physics.bind(self._arm.actuators).element_id, dtype=int)
        props = [self._cube, *self._obstacles]
        bodies = [int(physics.bind(p.geom).bodyid) for p in props]
        self._cube_body, self._obstacle_bodies = bodies[0], np.asarray(bodies[1:], dtype=int)
        free_joints = [int(model.body_jntadr[b]) for b in bodies]
        prop_qpos = np.asarray([model.jnt_qposadr[j] for j in free_joints], int)[:, None] + np.arange(7)
        prop_dofs = np.asarray([model.jnt_dofadr[j] for j in free_joints], int)
        self._prop_bodies = np.asarray(bodies, dtype=int)
        self._prop_linear_dofs = prop_dofs[:, None] + np.arange(3)  # free joint: world-frame velocity
        self._obstacle_linear_dofs = self._prop_linear_dofs[1:]
        self.addresses = JointAddresses(
            arm_qpos=self._arm_qpos, arm_dof=self._arm_dof, cube_qpos=prop_qpos[0],
            cube_dof=self._prop_linear_dofs[0], obstacle_qpos=prop_qpos[1:].reshape(-1, 7),
            obstacle_dof=self._obstacle_linear_dofs.reshape(-1, 3))
        self._is_obstacle = np.zeros(model.ngeom, dtype=bool)
        self._obstacle_geoms = np.asarray([int(physics.bind(o.geom).element_id) for o in self._obstacles], int)
        self._is_obstacle[self._obstacle_geoms] = True
        self._cube_geom = int(physics.bind(self._cube.geom).element_id)
        arm_bodies = {int(physics.bind(b).element_id) for b in self._arm.mjcf_model.find_all("body")}
        arm_bodies |= {int(physics.bind(b).element_id) for b in self._pusher.mjcf_model.find_all("body")}
        toucher = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in arm_bodies]
        toucher.append(int(physics.bind(self._cube.geom).element_id))
        self._is_toucher = np.zeros(model.ngeom, dtype=bool)
        self._is_toucher[toucher] = True
        self._is_arm = np.zeros(model.ngeom, dtype=bool)
        self._is_arm[[g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in arm_bodies]] = True
        self._tip_site_id = int(physics.bind(self._pusher.tip_site).element_id)
        self.bodies = BodyIds(self._tip_site_id, self._cube_body, self._obstacle_bodies,
                              self._prop_bodies, self._prop_linear_dofs)

    def before_step(self, physics: mjcf.Physics, action: np.ndarray,
                    random_state: np.random.RandomState) -> None:
        """``action``: joint velocities for all arm joints, rad/s, already checked by the caller."""
        command = np.asarray(action, dtype=float)
        self._command = command
        physics.data.ctrl[self._arm_actuators] = command
        self.previous_action = command_to_action(command, self.robot.velocity_limit,
                                                 self.robot.commanded_joints)

    def after_step(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        self.step_info = self._measure(physics, phase_time=self.config.episode.control_period)

    def _measure(self, physics: mjcf.Physics, phase_time: float) -> StepInfo:
        cfg = self.config
        data = physics.data
        q = data.qpos[self._arm_qpos]
        self.kinematics.update(q)
        tip, _ = self.kinematics.frame_pose(self._tip_frame)
        center, rotation = self.kinematics.frame_pose(self._center_frame)
        target = data.xpos[self._cube_body].copy()
        obstacle_centers = data.xpos[self._obstacle_bodies]
        # Per-step constructors: the inputs come from the simulator and the validated config.
        scene = PhaseScene.unchecked(cfg.table.height, target, obstacle_centers,
                                     self._obstacle_half_sizes, self._region_params)
        pusher = Cylinder.unchecked(center, rotation, self._pusher.radius, self._pusher.half_length)
        phase, x, distances = phase_geometry(scene, pusher, cfg.regions.distance_clip)

        raw = data.ptr  # MuJoCo's own struct: its contact view is ~10x cheaper than dm_control's
        pairs = raw.contact.geom  # (ncon, 2) geom ids of the active contacts
        velocities = data.qvel[self._obstacle_linear_dofs]
        speeds = np.sqrt((velocities * velocities).sum(axis=1))
        touched = obstacle_touched(pairs, self._is_obstacle, self._is_toucher, speeds,
                                   cfg.rewards.obstacle_speed_threshold)
        elapsed = data.time - self._episode_start
        prog = progress(target, self._table_center, tip)
        cube_clear = pusher_clear = float("inf")
        if self._clearance is not None:
            gx, gm = data.geom_xpos, data.geom_xmat
            cube_clear, pusher_clear = self._clearance.distances(
                gx[self._cube_geom], gm[self._cube_geom].reshape(3, 3), gx[self._obstacle_geoms],
                gm[self._obstacle_geoms].reshape(-1, 3, 3), center, rotation)
        if phase_time > 0:
            too_close = min(cube_clear, pusher_clear) < cfg.rewards.avoid_margin
            f = np.array([avoid_component(touched, too_close), self.progress_objective.step(prog),
                          self.time_objective.step(phase, phase_time, elapsed)])
        else:  # the reset state: no step was taken, nothing was violated
            f = np.ones(3)
        (hx, hy), (tx, ty, tz) = cfg.table.half_extent, target.tolist()
        success = abs(tx) > hx or abs(ty) > hy or tz < cfg.table.height
        return StepInfo(f=f, g=penalty_form(f), phase=phase, x=x, distances=distances,
                        success=success, touched=touched,
                        tip=tip.copy(), target=target, progress=prog, elapsed=elapsed,
                        cube_clearance=cube_clear, pusher_clearance=pusher_clear)

    def get_reward(self, physics: mjcf.Physics) -> np.ndarray:
        return self.step_info.f

    def should_terminate_episode(self, physics: mjcf.Physics) -> bool:
        return self.step_info.success

    def get_discount(self, physics: mjcf.Physics) -> float:
        return 0.0 if self.step_info.success else 1.0

    @property
    def command(self) -> np.ndarray:
        """The joint-velocity command of the last step, rad/s."""
        return self._command
