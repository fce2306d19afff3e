"""What a held arm's joint torque sensors read, for the fakes' contact tests (the fake Gen2 SDK and
the fake ``kortex_api`` have no dynamics: a test sets their torques)."""

from __future__ import annotations

import mujoco
import numpy as np


def held_torques(task_config, degrees) -> np.ndarray:
    """N·m per joint: MuJoCo's gravity (bias minus passive force, at rest) on the task's arm model
    (``task_config.robot``) at joint angles ``degrees`` (model convention, deg)."""
    from ahrm_stack.deploy.contact import arm_dofs
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    sim = SimArm(task_config, seed=0, clock=FastClock())
    model = sim.physics.model.ptr
    data = mujoco.MjData(model)
    data.qpos[sim._arm_qpos] = np.radians(degrees)
    mujoco.mj_forward(model, data)
    dofs = arm_dofs(model, sim._arm_qpos)
    return data.qfrc_bias[dofs] - data.qfrc_passive[dofs]
