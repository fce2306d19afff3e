"""The deploy side's picture of the world: a mirror of the scene fed only by feedback and
perception (:class:`WorldModel`)."""

from __future__ import annotations

import numpy as np

from ahrm_stack.config import TaskConfig


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

        self._mujoco = mujoco
        self.task = PushOffTask(task_config)
        self.physics = mjcf.Physics.from_mjcf_model(self.task.root_entity.mjcf_model)
        self.random_state = np.random.RandomState(seed)
        self.task.initialize_episode(self.physics, self.random_state)  # binds the task's indices
        self._addresses = self.task.addresses  # where the joints sit in this physics
        self._start = float(self.physics.data.time)

    @property
    def robot(self):
        return self.task.robot

    def update(self, feedback, poses, elapsed: float):
        """Write ``feedback`` (joint state) and ``poses`` (objects) into the mirror; returns the
        task's :class:`~ahrm_stack.env.task.StepInfo` for this state. ``elapsed``: s since start."""
        at = self._addresses
        if len(poses.obstacle_positions) != len(at.obstacle_qpos):
            raise ValueError(f"perception gave {len(poses.obstacle_positions)} obstacles; the task "
                             f"has {len(at.obstacle_qpos)}")
        data = self.physics.data
        data.qpos[at.arm_qpos] = feedback.position
        data.qvel[at.arm_dof] = feedback.velocity
        data.qpos[at.cube_qpos[:3]] = poses.cube_position
        data.qpos[at.cube_qpos[3:]] = poses.cube_quaternion
        data.qvel[at.cube_dof] = poses.cube_velocity
        data.qpos[at.obstacle_qpos[:, :3]] = poses.obstacle_positions
        data.qpos[at.obstacle_qpos[:, 3:]] = poses.obstacle_quaternions
        data.qvel[at.obstacle_dof] = poses.obstacle_velocities
        data.time = self._start + elapsed
        self._mujoco.mj_kinematics(self.physics.model.ptr, data.ptr)
        self.task.after_step(self.physics, self.random_state)
        return self.task.step_info

    def observation(self) -> np.ndarray:
        """The training observation vector (layout: ``task.observation_order``)."""
        return self.task.flat_observation(self.physics)

    def record_command(self, command: np.ndarray) -> None:
        """The command actually sent (rad/s): the next observation's previous action."""
        self.task.before_step(self.physics, command, self.random_state)

    def make_collision_scene(self):
        return self.task.make_collision_scene(self.physics)

    def place_objects(self, scene) -> None:
        self.task.place_objects(scene, self.physics)
