"""The deploy side's picture of the world: a mirror of the scene fed only by feedback and
perception (:class:`WorldModel`)."""

from __future__ import annotations

import numpy as np

from ahrm_stack.config import TaskConfig
from ahrm_stack.env.layout import lane_clearance
from ahrm_stack.env.observation_layout import observation_layout
from ahrm_stack.env.realism import VelocityEstimator
from ahrm_stack.realism import nominal


class WorldModel:
    """A mirror of the scene built only from feedback and perception.

    It holds its own :class:`~ahrm_stack.env.task.PushOffTask` on its own physics; each
    :meth:`update` writes the measured joint state and the perceived object poses into that
    physics, runs MuJoCo's forward kinematics, and lets the task measure the step exactly as in
    training (Pinocchio tip pose, :func:`~ahrm_stack.kinematics.phases.phase_geometry` for the
    phase k and the boundary distance x, success). :meth:`observation` is then the training
    observation vector (:meth:`PushOffTask.flat_observation`), with the previous action recorded
    by :meth:`record_command` from the command actually sent.
    """

    def __init__(self, task_config: TaskConfig, seed: int = 0) -> None:
        import mujoco
        from dm_control import mjcf

        from ahrm_stack.env.task import PushOffTask

        # measured values are written in as they come: no imperfection added on this side
        self.task = PushOffTask(nominal(task_config))
        self.physics = mjcf.Physics.from_mjcf_model(self.task.root_entity.mjcf_model)
        self.random_state = np.random.RandomState(seed)
        self.task.initialize_episode(self.physics, self.random_state)  # binds the task's indices
        self._addresses = self.task.addresses  # where the joints sit in this physics
        self._start = float(self.physics.data.time)
        # task.observation.joint_velocity: position_difference: the observation's joint velocities
        # estimated from the measured angles, as in training (None: the velocity feedback)
        observation = task_config.observation
        self._velocity = (VelocityEstimator(observation.velocity_smoothing)
                          if observation.joint_velocity == "position_difference" else None)
        self._elapsed = -1.0
        self._new_run = False
        self._kinematics = mujoco.mj_kinematics
        self._model_ptr, self._data_ptr = self.physics.model.ptr, self.physics.data.ptr
        # The task's observation written into one preallocated vector; None (the task's own
        # flat_observation) for a layout the builder does not reproduce exactly.
        self._builder = ObservationBuilder.checked(self.task, self.physics)
        # place_objects' work space: the objects' poses (rows: cube, obstacles; position m then
        # rotation matrix, world frame), read from MuJoCo's arrays without dm_control's indexing
        raw = self.physics.data.ptr
        self._xpos, self._xmat = raw.xpos, raw.xmat
        self._object_bodies = self.task.bodies.props.copy()
        self._object_poses = np.zeros((len(self._object_bodies), 12))

    @property
    def robot(self):
        return self.task.robot

    @property
    def arm_qpos(self) -> np.ndarray:
        """The arm's joint addresses in :attr:`physics` (indices into ``qpos``), joint order."""
        return np.asarray(self._addresses.arm_qpos, dtype=int)

    def update(self, feedback, poses, elapsed: float):
        """Write ``feedback`` (joint state) and ``poses`` (objects) into the mirror; returns the
        task's :class:`~ahrm_stack.env.task.StepInfo` for this state. ``elapsed``: s since start."""
        at = self._addresses
        if len(poses.obstacle_positions) != len(at.obstacle_qpos):
            raise ValueError(f"perception gave {len(poses.obstacle_positions)} obstacles; the task "
                             f"has {len(at.obstacle_qpos)}")
        data = self.physics.data
        data.qpos[at.arm_qpos] = feedback.position
        new_run, self._new_run = self._new_run, False
        if self._velocity is None:
            data.qvel[at.arm_dof] = feedback.velocity
        else:
            if new_run or elapsed < self._elapsed:
                self._velocity.reset()
            data.qvel[at.arm_dof] = self._velocity(feedback.position, elapsed - self._elapsed)
        self._elapsed = elapsed
        data.qpos[at.cube_qpos[:3]] = poses.cube_position
        data.qpos[at.cube_qpos[3:]] = poses.cube_quaternion
        data.qvel[at.cube_dof] = poses.cube_velocity
        data.qpos[at.obstacle_qpos[:, :3]] = poses.obstacle_positions
        data.qpos[at.obstacle_qpos[:, 3:]] = poses.obstacle_quaternions
        data.qvel[at.obstacle_dof] = poses.obstacle_velocities
        data.time = self._start + elapsed
        self._kinematics(self._model_ptr, self._data_ptr)
        if new_run:  # the episode's bookkeeping restarts: the lane is planned again, the objectives
            self.task.begin_episode(self.physics)  # and the previous action reset
        self.task.after_step(self.physics, self.random_state)
        return self.task.step_info

    def begin_run(self) -> None:
        """The next :meth:`update` starts an episode (a deploy loop's start): the task's episode
        bookkeeping restarts there (the lane is planned again, the previous action is zero, the
        objectives restart) and the joint-velocity estimate with it."""
        self._new_run = True

    def observation(self, copy: bool = True) -> np.ndarray:
        """The training observation vector (layout: ``task.observation_order``) of the last
        :meth:`update`; ``copy=False``: the model's own buffer, overwritten by the next call (for a
        caller that uses it at once, e.g. the policy controller)."""
        if self._builder is None:
            return self.task.flat_observation(self.physics)
        out = self._builder.fill()
        return out.copy() if copy else out

    def record_command(self, command: np.ndarray) -> None:
        """The command actually sent (rad/s): the next observation's previous action."""
        self.task.before_step(self.physics, command, self.random_state)

    def tip_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pusher tip's position (m, world) and axis (unit, world; straight down is (0, 0, -1))
        with the arm at ``q`` (rad), by MuJoCo's forward kinematics on the mirror (its joints are
        left at ``q`` until the next :meth:`update`)."""
        data = self.physics.data
        data.qpos[self._addresses.arm_qpos] = q
        self._kinematics(self._model_ptr, self._data_ptr)
        site = self.task.bodies.tip_site
        return data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3)[:, 2].copy()

    def tip_ik(self, target: np.ndarray, q_init: np.ndarray) -> tuple[np.ndarray, float, float]:
        """Joint angles (rad) that put the pusher tip at ``target`` (m, world) pointing straight
        down, by the task's IK (:func:`~ahrm_stack.env.start_pose.solve_start_pose`, its
        ``task.arm.start_ik`` settings) from ``q_init`` on the mirror: (q, the tip's miss in m, the
        pusher's tilt from vertical in rad). The mirror's joints are left at q."""
        from ahrm_stack.env.start_pose import solve_start_pose

        task, physics = self.task, self.physics
        result = solve_start_pose(physics.model.ptr, physics.data.ptr, self._addresses.arm_qpos,
                                  self._addresses.arm_dof, task.bodies.tip_site, np.asarray(target, float),
                                  np.asarray(q_init, float), self.robot.position_lower, self.robot.position_upper,
                                  task._is_arm, task.config.arm.start_ik)
        return result.q, result.position_error, result.tilt

    def make_collision_scene(self):
        return self.task.make_collision_scene(self.physics)

    def place_objects(self, scene) -> None:
        """Move ``scene``'s cube and obstacles to their poses in the mirror (what
        :meth:`PushOffTask.place_objects` does; the scene leaves an object whose pose did not
        change as it is). A non-finite pose raises ``ValueError`` naming the object."""
        poses = self._object_poses
        np.take(self._xpos, self._object_bodies, axis=0, out=poses[:, :3], mode="clip")
        np.take(self._xmat, self._object_bodies, axis=0, out=poses[:, 3:], mode="clip")
        scene.update_objects(poses[0, :3], poses[0, 3:].reshape(3, 3), poses[1:, :3], poses[1:, 3:])


class ObservationBuilder:
    """:meth:`PushOffTask.flat_observation` written into one preallocated vector: the same values
    (copies of the same floats, the same ufuncs: a test checks bit equality) without its per-call
    concatenations, and with the lane clearances of all lanes computed at once.

    It reads the task's physics bindings and ``step_info`` as ``flat_observation`` does, so it is
    valid for one physics (the :class:`WorldModel`'s, which is never rebuilt). Build it with
    :meth:`checked`, which compares it with the task's own vector once."""

    def __init__(self, task, physics) -> None:
        cfg = task.config
        self._task, self._physics = task, physics
        raw = physics.data.ptr  # MuJoCo's arrays, views that live as long as the physics
        self._qpos, self._qvel, self._xpos = raw.qpos, raw.qvel, raw.xpos
        n = task.robot.num_joints
        self._arm_qpos, self._arm_dof = task.addresses.arm_qpos, task.addresses.arm_dof
        bodies = task.bodies
        self._cube, self._obstacles = int(bodies.cube), np.asarray(bodies.obstacles)
        self._props = np.asarray(bodies.props)
        self._prop_dofs = np.asarray(bodies.prop_linear_dofs)
        k = len(self._props)  # the cube and the obstacles
        # where each part sits: the task's own layout (env/observation_layout.py), one description
        layout = observation_layout(cfg, n, len(task.previous_action))
        last_prop = layout[f"obstacle_{k - 2}"] if k > 1 else layout["cube"]  # the props sit together
        sl = {"trig": layout["joints_pos"], "dq": layout["joints_vel"], "tip": layout["pusher_tip"],
              "props": slice(layout["cube"].start, last_prop.stop),
              "previous_action": layout["previous_action"], "phase": layout["phase"],
              "x": layout["boundary_distance"]}
        observation = cfg.observation
        optional = (("relative", "relative_to_cube"), ("lanes", "lane_clearance"), ("lane_choice", "lane_choice"))
        sl.update({name: layout[key] for name, key in optional if key in layout})
        self._out = np.zeros(max(part.stop for part in layout.values()))
        out = self._out
        self._sin, self._cos = out[sl["trig"]][0::2], out[sl["trig"]][1::2]
        self._dq, self._tip = out[sl["dq"]], out[sl["tip"]]
        props = out[sl["props"]].reshape(k, 6)
        self._prop_position, self._prop_velocity = props[:, :3], props[:, 3:]
        self._previous, self._phase = out[sl["previous_action"]], out[sl["phase"]]
        self._x = sl["x"].start
        self._q = np.empty(n)
        self._obstacle_xy = np.empty((k - 1, 2))
        self._relative_tip = self._relative_obstacles = self._lanes = None
        if observation.relative:
            relative = out[sl["relative"]]
            self._relative_tip, self._relative_obstacles = relative[:3], relative[3:].reshape(k - 1, 2)
        if observation.lanes:
            self._lane_args = (cfg.cube.size / 2, task.obstacle_half_sizes[0, :2], cfg.table, cfg.layout,
                               tuple(float(v) for v in cfg.observation.lane_clip))
            self._lanes = out[sl["lanes"]]
        self._lane_choice = out[sl["lane_choice"]] if observation.lane_choice else None

    @classmethod
    def checked(cls, task, physics) -> "ObservationBuilder | None":
        """A builder whose vector equals ``task.flat_observation(physics)`` now, bit for bit (and
        in size); None when it does not (a layout it does not know: the task's own is used)."""
        try:
            builder = cls(task, physics)
            built = builder.fill().copy()
        except (AttributeError, IndexError, KeyError, TypeError, ValueError):
            return None
        expected = task.flat_observation(physics)
        task.forget_lane_plan()  # the check must not plan the episode's lane from this state
        if built.shape != expected.shape or not np.array_equal(built, expected):
            return None
        return builder

    def lane_clearance(self, cube_xy, obstacle_xy) -> np.ndarray:
        """:func:`~ahrm_stack.env.layout.lane_clearance` of this task's lanes, clipped to
        ``task.observation.lane_clip`` (m). Positions (x, y), m, world frame."""
        return lane_clearance(cube_xy, obstacle_xy, *self._lane_args)

    def fill(self) -> np.ndarray:
        """The observation of the physics' current state and the task's ``step_info`` (the
        builder's own buffer, overwritten by the next call)."""
        task, info, xpos = self._task, self._task.step_info, self._xpos
        q = np.take(self._qpos, self._arm_qpos, out=self._q, mode="clip")
        np.sin(q, out=self._sin)
        np.cos(q, out=self._cos)
        np.take(self._qvel, self._arm_dof, out=self._dq, mode="clip")
        self._tip[:] = info.tip
        np.take(xpos, self._props, axis=0, out=self._prop_position, mode="clip")
        np.take(self._qvel, self._prop_dofs, out=self._prop_velocity, mode="clip")
        self._previous[:] = task.previous_action
        self._phase[:] = 0.0
        self._phase[info.phase - 1] = 1.0
        self._out[self._x] = info.x
        cube = xpos[self._cube]
        if self._lanes is not None or self._relative_tip is not None:
            self._obstacle_xy[:] = self._prop_position[1:, :2]
        if self._relative_tip is not None:
            np.subtract(info.tip, cube, out=self._relative_tip)
            np.subtract(self._obstacle_xy, cube[:2], out=self._relative_obstacles)
        if self._lanes is not None:
            self._lanes[:] = self.lane_clearance(cube[:2], self._obstacle_xy)
        if self._lane_choice is not None:
            self._lane_choice[:] = task.lane_choice(self._physics)
        return self._out
