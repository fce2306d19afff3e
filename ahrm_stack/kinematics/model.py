"""Pinocchio model of the arm: from the exact MJCF that the simulator compiles (dm_control's JACO),
or straight from the URDF that the simulated arm was built from (:class:`UrdfArmKinematics`).

The arm entity's MJCF (with the pusher attached) is exported and parsed by
``pin.buildModelFromMJCF``. Two defects of Pinocchio 4.1.0's MJCF parser are repaired here:

* sites on nested bodies without joints are misplaced: every site frame is re-placed from its
  parent body's frame and the site's own ``pos``/``quat`` read from the MJCF element;
* the pose of a top-level body without a joint is dropped: it is folded into the base placement.

Frames are named as in the arm's MJCF (``b_1`` ... ``b_6``, ``wristsite``, ``pusher/tip`` ...).
World placement: the arm's base frame is at ``base_position`` (m), rotated by ``base_yaw`` (rad)
about world z, exactly as the arena attaches it.

The arm's joint vector ``q`` (one angle per joint, rad, in the MJCF's joint order) and Pinocchio's
configuration vector differ where Pinocchio represents an unbounded (URDF ``continuous``) joint by
(cos q, sin q): :class:`ConfigurationMap` converts between them; velocities and Jacobian columns
are one per joint in both.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import pinocchio as pin
from dm_control import mjcf

from ahrm_stack.robot import RobotDescription


def _local_pose(element: mjcf.Element) -> pin.SE3:
    """Pose of a body or site relative to its parent, from the MJCF attributes (pos, quat)."""
    for attr in ("axisangle", "euler", "xyaxes", "zaxis"):
        if getattr(element, attr, None) is not None:
            raise ValueError(f"{element.full_identifier}: orientation given by '{attr}' is not "
                             "supported by the kinematics model; use 'quat'")
    pos = np.zeros(3) if element.pos is None else np.asarray(element.pos, dtype=float)
    quat = np.array([1.0, 0, 0, 0]) if element.quat is None else np.asarray(element.quat, dtype=float)
    w, x, y, z = quat / np.linalg.norm(quat)
    return pin.SE3(pin.Quaternion(w, x, y, z).toRotationMatrix(), pos)


def relative_name(element: mjcf.Element, root: mjcf.RootElement) -> str:
    """Name of ``element`` as seen from ``root`` (the arm model), without any attachment prefix."""
    name = element.full_identifier
    prefix = root.model
    if prefix and name.startswith(prefix + "/"):
        return name[len(prefix) + 1:]
    return name


def base_placement(base_position: Sequence[float], base_yaw: float) -> pin.SE3:
    """World placement of the arm's root frame (m, rad)."""
    c, s = np.cos(base_yaw), np.sin(base_yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return pin.SE3(rotation, np.asarray(base_position, dtype=float))


class ConfigurationMap:
    """The arm's joint vector ``q`` (rad, ``joint_names`` order) <-> Pinocchio's configuration.

    A revolute joint (nq = 1) takes its angle in place; an unbounded revolute joint (Pinocchio's
    ``JointModelRUBZ`` and kin, nq = 2) takes (cos q, sin q). Every joint must have one velocity,
    the i-th joint of ``joint_names`` the i-th, so Jacobian columns are in ``q``'s order.
    """

    def __init__(self, model: pin.Model, joint_names: Sequence[str]) -> None:
        angle_q, angle_i, circle_q, circle_i = [], [], [], []
        for i, name in enumerate(joint_names):
            if not model.existJointName(name):
                raise ValueError(f"joint {name!r} is not in the Pinocchio model; its joints: "
                                 f"{list(model.names)[1:]}")
            joint = model.joints[model.getJointId(name)]
            if joint.nv != 1 or joint.idx_v != i:
                raise ValueError(f"joint {name!r} has nv={joint.nv} at velocity index {joint.idx_v}; "
                                 f"expected one velocity at index {i}")
            if joint.nq == 1:
                angle_q.append(joint.idx_q)
                angle_i.append(i)
            elif joint.nq == 2:
                circle_q.append(joint.idx_q)
                circle_i.append(i)
            else:
                raise ValueError(f"joint {name!r} has nq={joint.nq}: not a revolute joint")
        if len(joint_names) != model.nv:
            raise ValueError(f"{len(joint_names)} joint names for a model with nv={model.nv}")
        self.nq = model.nq
        self._angle_q, self._angle_i = np.array(angle_q, int), np.array(angle_i, int)
        self._cos_q = np.array(circle_q, int)
        self._sin_q, self._circle_i = self._cos_q + 1, np.array(circle_i, int)

    @property
    def continuous(self) -> np.ndarray:
        """Indices (into ``q``) of the joints Pinocchio stores as (cos, sin)."""
        return self._circle_i.copy()

    def to_pinocchio(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's configuration vector (nq) of the joint angles ``q`` (rad)."""
        q = np.asarray(q, dtype=float)
        out = np.empty(self.nq)
        out[self._angle_q] = q[self._angle_i]
        angles = q[self._circle_i]
        out[self._cos_q] = np.cos(angles)
        out[self._sin_q] = np.sin(angles)
        return out

    def from_pinocchio(self, configuration: np.ndarray) -> np.ndarray:
        """Joint angles (rad) of a configuration vector; continuous joints come back in (-pi, pi]."""
        configuration = np.asarray(configuration, dtype=float)
        q = np.empty(len(self._angle_i) + len(self._circle_i))
        q[self._angle_i] = configuration[self._angle_q]
        q[self._circle_i] = np.arctan2(configuration[self._sin_q], configuration[self._cos_q])
        return q


class ArmKinematics:
    """Forward kinematics and Jacobians of the arm (+ pusher) in the world frame.

    ``q`` is the arm's joint vector in the MJCF's joint order, radians; :attr:`configuration` maps
    it to Pinocchio's configuration vector.
    """

    def __init__(self, arm_model: mjcf.RootElement, base_position: Sequence[float],
                 base_yaw: float) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            mjcf.export_with_assets(arm_model, tmp, "arm.xml")
            model = pin.buildModelFromMJCF(str(Path(tmp) / "arm.xml"))
        self._setup(model, arm_model, base_position, base_yaw)
        self._fix_sites(arm_model)
        self._frame_ids = {f.name: i for i, f in enumerate(self.model.frames)}

    def _setup(self, model: pin.Model, arm_model: mjcf.RootElement,
               base_position: Sequence[float], base_yaw: float) -> None:
        """State shared by every way of building the model: base placement, joint map, data."""
        self.model = model
        self.data = self.model.createData()
        top_bodies = arm_model.worldbody.get_children("body")
        if len(top_bodies) != 1:
            raise ValueError(f"expected one top-level body in the arm MJCF, got {len(top_bodies)}")
        self.base = base_placement(base_position, base_yaw) * _local_pose(top_bodies[0])
        self._arm_model = arm_model
        joint_names = [relative_name(j, arm_model) for j in arm_model.find_all("joint")]
        self.joint_map = ConfigurationMap(model, joint_names)
        self._q = np.full(len(joint_names), np.nan)
        self._configuration = pin.neutral(model)

    def configuration(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's configuration vector of the joint angles ``q`` (rad)."""
        return self.joint_map.to_pinocchio(q)

    def _fix_sites(self, arm_model: mjcf.RootElement) -> None:
        for site in arm_model.find_all("site"):
            name = relative_name(site, arm_model)
            body = site.parent
            body_name = relative_name(body, arm_model) if body.tag == "body" else None
            if body_name is None or not self.model.existFrame(name) or not self.model.existFrame(body_name):
                continue
            body_frame = self.model.frames[self.model.getFrameId(body_name)]
            frame = self.model.frames[self.model.getFrameId(name)]
            frame.parentJoint = body_frame.parentJoint
            frame.placement = body_frame.placement * _local_pose(site)
            self.model.frames[self.model.getFrameId(name)] = frame

    @property
    def frame_names(self) -> list[str]:
        return list(self._frame_ids)

    def element_frame_id(self, element: mjcf.Element) -> int:
        """Frame id of an MJCF body or site of the arm model."""
        return self.frame_id(relative_name(element, self._arm_model))

    def frame_id(self, name: str) -> int:
        try:
            return self._frame_ids[name]
        except KeyError:
            raise KeyError(f"no frame {name!r} in the arm model") from None

    def update(self, q: np.ndarray) -> None:
        """Compute joint placements for ``q`` (rad); cached when ``q`` is unchanged."""
        if np.array_equal(q, self._q):
            return
        self._configuration = self.joint_map.to_pinocchio(q)
        pin.forwardKinematics(self.model, self.data, self._configuration)
        self._q = np.array(q, dtype=float)

    def frame_pose(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """World position (m) and rotation matrix of frame id ``frame`` at the last ``update``."""
        placement = self.base * pin.updateFramePlacement(self.model, self.data, frame)
        return placement.translation, placement.rotation

    def frame_jacobian(self, frame: int) -> np.ndarray:
        """6 x nv world-frame Jacobian (linear rows first) of frame ``frame``'s origin.

        Needs ``update`` first (and ``computeJointJacobians`` is run here).
        """
        pin.computeJointJacobians(self.model, self.data, self._configuration)
        jac = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
        rotation = self.base.rotation
        return np.vstack([rotation @ jac[:3], rotation @ jac[3:]])


class UrdfArmKinematics(ArmKinematics):
    """The kinematics of an arm built from a URDF (:class:`ahrm_stack.arms.entity.UrdfArm`), read
    straight from that URDF by ``pin.buildModelFromUrdf``.

    The URDF's link frames keep their names (the entity's bodies are named like them); every body
    and site of the arm MJCF that the URDF lacks (the pusher's mount, the pusher and its sites) is
    added as a frame on its parent body, from the MJCF's own ``pos``/``quat``. The arm MJCF's top
    body must be the URDF's root link.
    """

    def __init__(self, urdf: Path | str, arm_model: mjcf.RootElement,
                 base_position: Sequence[float], base_yaw: float) -> None:
        model = pin.buildModelFromUrdf(str(urdf))
        root = arm_model.worldbody.get_children("body")
        if len(root) == 1 and not model.existFrame(relative_name(root[0], arm_model)):
            raise ValueError(f"the arm MJCF's top body {relative_name(root[0], arm_model)!r} is not a "
                             f"link of {urdf}")
        self._setup(model, arm_model, base_position, base_yaw)
        self._add_mjcf_frames(arm_model.worldbody.get_children("body")[0])
        self._frame_ids = {f.name: i for i, f in enumerate(self.model.frames)}

    def _add_mjcf_frames(self, body: mjcf.Element) -> None:
        """Add a frame for every descendant body and site of ``body`` the model lacks (depth first)."""
        parent_id = self.model.getFrameId(relative_name(body, self._arm_model))
        parent = self.model.frames[parent_id]
        for child in body.all_children():
            if child.tag not in ("body", "site"):
                continue
            name = relative_name(child, self._arm_model)
            if not self.model.existFrame(name):
                kind = pin.FrameType.BODY if child.tag == "body" else pin.FrameType.OP_FRAME
                self.model.addFrame(pin.Frame(name, parent.parentJoint, parent_id,
                                              parent.placement * _local_pose(child), kind))
            if child.tag == "body":
                self._add_mjcf_frames(child)
        self.data = self.model.createData()


def make_kinematics(robot: RobotDescription, arm_model: mjcf.RootElement,
                    base_position: Sequence[float], base_yaw: float) -> ArmKinematics:
    """The kinematics of ``robot`` from its source: its URDF if it has one, else its MJCF."""
    if robot.urdf is not None:
        return UrdfArmKinematics(robot.urdf, arm_model, base_position, base_yaw)
    return ArmKinematics(arm_model, base_position, base_yaw)
