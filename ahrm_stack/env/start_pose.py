"""Random start postures: the pusher tip at a given point, the pusher pointing down, found by IK.

The IK runs on the simulator's own model and data (MuJoCo's site Jacobians), over the arm's joints
only, by damped least squares on six residuals: the tip's position error (m, world frame) and the
tilt of the pusher axis from world -z (rad, as a rotation vector). Joint limits are enforced by
clipping after each step. A posture is accepted when the tip is within ``position_tolerance`` of
the target, the pusher within ``tilt_tolerance`` of vertical (``task.arm.start_ik``), and no arm or pusher geom touches
anything but the arm itself (the table, the cube, the obstacles).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from ahrm_stack.config import StartIKConfig

DOWN = np.array([0.0, 0.0, -1.0])  # world frame



@dataclasses.dataclass(frozen=True)
class StartPoseResult:
    q: np.ndarray  # arm joint angles, rad
    position_error: float  # m
    tilt: float  # rad
    ok: bool  # within tolerance and free of contact


def solve_start_pose(model: mujoco.MjModel, data: mujoco.MjData, qpos_index: np.ndarray,
                     dof_index: np.ndarray, tip_site: int, target: np.ndarray, q_init: np.ndarray,
                     lower: np.ndarray, upper: np.ndarray, arm_geoms: np.ndarray,
                     ik: StartIKConfig) -> StartPoseResult:
    """IK from ``q_init`` (rad) for the tip site ``tip_site`` at ``target`` (m, world) pointing down.

    ``qpos_index`` / ``dof_index``: the arm joints' addresses in qpos / qvel; ``lower`` / ``upper``:
    joint limits (rad; +-inf for continuous joints); ``arm_geoms``: boolean mask over geoms of the
    arm and pusher (a contact between two of them is the arm's own business, any other is a
    collision); ``ik``: iterations, damping, step bound and tolerances (``task.arm.start_ik``).
    ``data.qpos`` is left at the result, kinematics updated.
    """
    q = np.clip(np.asarray(q_init, dtype=float), lower, upper)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    error = np.zeros(6)
    for _ in range(ik.iterations):
        data.qpos[qpos_index] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        tip = data.site_xpos[tip_site]
        axis = data.site_xmat[tip_site].reshape(3, 3)[:, 2]
        error[:3] = target - tip
        error[3:] = np.cross(axis, DOWN)  # rotation (axis-angle, small) turning the axis down
        if np.linalg.norm(error[:3]) < ik.position_tolerance * 0.1 and np.linalg.norm(error[3:]) < 1e-4:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, tip_site)
        jac = np.vstack([jacp[:, dof_index], jacr[:, dof_index]])
        step = jac.T @ np.linalg.solve(jac @ jac.T + ik.damping * np.eye(6), error)
        largest = float(np.max(np.abs(step)))
        if largest > ik.max_step:
            step *= ik.max_step / largest
        q = np.clip(q + step, lower, upper)
    data.qpos[qpos_index] = q
    mujoco.mj_forward(model, data)
    tip = data.site_xpos[tip_site]
    axis = data.site_xmat[tip_site].reshape(3, 3)[:, 2]
    position_error = float(np.linalg.norm(target - tip))
    tilt = float(np.arccos(np.clip(axis @ DOWN, -1.0, 1.0)))
    clear = True
    for i in range(data.ncon):
        g1, g2 = data.contact.geom1[i], data.contact.geom2[i]
        if (arm_geoms[g1] or arm_geoms[g2]) and not (arm_geoms[g1] and arm_geoms[g2]):
            if data.contact.dist[i] < 0:
                clear = False
                break
    ok = position_error <= ik.position_tolerance and tilt <= ik.tilt_tolerance and clear
    return StartPoseResult(q=q.copy(), position_error=position_error, tilt=tilt, ok=ok)
