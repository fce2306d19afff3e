"""The studies' view of the simulator's contacts on the arm: which bodies are the arm's, and the
generalised torque the contacts put on its joints (MuJoCo's J^T f, each contact's force from
``mj_contactForce``), in the joint frame, N·m, with the names of what the arm touches."""

from __future__ import annotations

import mujoco
import numpy as np

from ahrm_stack.deploy.contact import arm_dofs


class ArmContacts:
    """Of a compiled ``model`` whose arm joints sit at ``qpos`` (indices into ``qpos``)."""

    def __init__(self, model: mujoco.MjModel, qpos: np.ndarray) -> None:
        self.model = model
        self.dofs = arm_dofs(model, qpos)  # indices into qvel, in qpos's order
        bodies = {int(model.dof_bodyid[d]) for d in self.dofs}
        for body in range(model.nbody):  # and their descendants (the pusher)
            parent = body
            while parent > 0:
                if parent in bodies:
                    bodies.add(body)
                    break
                parent = int(model.body_parentid[parent])
        self.bodies = bodies
        self._jacobian, self._force = np.zeros((3, model.nv)), np.zeros(6)

    def torque(self, data: mujoco.MjData) -> tuple[np.ndarray, set[str]]:
        """(n,) N·m on the arm's joints from the contacts of ``data`` now, and the top-level names
        of the bodies the arm touches."""
        model, torque, touching = self.model, np.zeros(len(self.dofs)), set()
        for i in range(data.ncon):
            contact = data.contact[i]
            for geom, sign, other in ((contact.geom2, 1.0, contact.geom1), (contact.geom1, -1.0, contact.geom2)):
                body = int(model.geom_bodyid[geom])
                if body in self.bodies:
                    mujoco.mj_contactForce(model, data, i, self._force)
                    world = sign * (contact.frame.reshape(3, 3).T @ self._force[:3])  # on this body
                    mujoco.mj_jac(model, data, self._jacobian, None, contact.pos, body)
                    torque += (self._jacobian.T @ world)[self.dofs]
                    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[other]))
                    touching.add((name or "world").rstrip("/").split("/")[0])
        return torque, touching
