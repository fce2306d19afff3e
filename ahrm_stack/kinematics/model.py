"""Pinocchio model of the arm, built from the exact MJCF that the simulator compiles.

The arm entity's MJCF (with the pusher attached) is exported and parsed by
``pin.buildModelFromMJCF``. Two defects of Pinocchio 4.1.0's MJCF parser are repaired here:

* sites on nested bodies without joints are misplaced: every site frame is re-placed from its
  parent body's frame and the site's own ``pos``/``quat`` read from the MJCF element;
* the pose of a top-level body without a joint is dropped: it is folded into the base placement.

Frames are named as in the arm's MJCF (``b_1`` ... ``b_6``, ``wristsite``, ``pusher/tip`` ...).
World placement: the arm's base frame is at ``base_position`` (m), rotated by ``base_yaw`` (rad)
about world z, exactly as the arena attaches it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import pinocchio as pin
from dm_control import mjcf


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


class ArmKinematics:
    """Forward kinematics and Jacobians of the arm (+ pusher) in the world frame.

    ``q`` is the arm's joint vector in the MJCF's joint order, radians.
    """

    def __init__(self, arm_model: mjcf.RootElement, base_position: Sequence[float],
                 base_yaw: float) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            mjcf.export_with_assets(arm_model, tmp, "arm.xml")
            self.model = pin.buildModelFromMJCF(str(Path(tmp) / "arm.xml"))
        self.data = self.model.createData()
        top_bodies = arm_model.worldbody.get_children("body")
        if len(top_bodies) != 1:
            raise ValueError(f"expected one top-level body in the arm MJCF, got {len(top_bodies)}")
        self.base = base_placement(base_position, base_yaw) * _local_pose(top_bodies[0])
        self._fix_sites(arm_model)
        self._arm_model = arm_model
        self._frame_ids = {f.name: i for i, f in enumerate(self.model.frames)}
        self._q = np.full(self.model.nq, np.nan)

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
        pin.forwardKinematics(self.model, self.data, q)
        self._q = np.array(q, dtype=float)

    def frame_pose(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """World position (m) and rotation matrix of frame id ``frame`` at the last ``update``."""
        placement = self.base * pin.updateFramePlacement(self.model, self.data, frame)
        return placement.translation, placement.rotation

    def frame_jacobian(self, frame: int) -> np.ndarray:
        """6 x nv world-frame Jacobian (linear rows first) of frame ``frame``'s origin.

        Needs ``update`` first (and ``computeJointJacobians`` is run here).
        """
        pin.computeJointJacobians(self.model, self.data, self._q)
        jac = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
        rotation = self.base.rotation
        return np.vstack([rotation @ jac[:3], rotation @ jac[3:]])
