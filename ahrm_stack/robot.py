"""The one robot description: everything that reads the arm reads it from here.

Each arm of :data:`ARMS` is a dm_control composer entity. ``jaco`` is dm_control's curved-wrist
JACO2, whose MJCF is its source of truth; ``j2s6s200`` is the spherical-wrist JACO2 of
``example-robot-data``, whose URDF is (the entity and the Pinocchio model are both built from it,
:mod:`ahrm_stack.arms`). Joint limits and velocity limits are read from the *compiled* MJCF
(MuJoCo's ``jnt_range`` and the velocity actuators' ``ctrlrange``), never restated in code; the
simulator, the Pinocchio model, the safety filter and the hardware adapter all take them from a
:class:`RobotDescription`.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Callable

import numpy as np
from dm_control import composer, mjcf
from dm_control.entities.manipulators.kinova import jaco_arm

from ahrm_stack.arms.assets import robot_file
from ahrm_stack.arms.entity import UrdfArm
from ahrm_stack.arms.urdf import Urdf, read_urdf
from ahrm_stack.config import load_robot_config


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """Joint-space facts about one arm, in SI units and radians.

    Arrays are indexed like ``joint_names``. Unlimited (continuous) joints have position limits
    of -inf / +inf.
    """

    name: str
    joint_names: tuple[str, ...]
    position_lower: np.ndarray  # rad
    position_upper: np.ndarray  # rad
    velocity_limit: np.ndarray  # rad/s, symmetric: |dq| <= velocity_limit
    commanded_joints: tuple[int, ...]  # indices driven by the policy; the rest hold zero velocity
    link_bodies: tuple[str, ...]  # body names of the links, base to wrist (arm-model names)
    base_body: str  # arm-model name of the fixed body the first link turns on (the base)
    attachment_site: str  # arm-model name of the site the pusher is attached to
    urdf: Path | None = None  # the URDF the arm is built from (None: the MJCF is the source); the
    # kinematics then read the URDF directly
    min_velocity_margin: float = 0.0  # fraction of each velocity limit the safety filter leaves
    # unused at least, whatever safety.velocity_margin says: a joint moving with gravity runs ahead
    # of its velocity command by up to (gravity torque - friction) / servo gain, which the margin
    # must cover (configs/robots/<name>.yaml; 0 for dm_control's jaco)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def limited(self) -> np.ndarray:
        """Boolean mask of joints with finite position limits."""
        return np.isfinite(self.position_lower) & np.isfinite(self.position_upper)


@dataclasses.dataclass(frozen=True)
class _ArmSpec:
    make_entity: Callable[[], composer.Entity]
    commanded_joints: tuple[int, ...]


def _make_jaco() -> composer.Entity:
    return jaco_arm.JacoArm(name="jaco")


@functools.lru_cache(maxsize=None)
def robot_urdf(name: str) -> Urdf:
    """The parsed URDF of a URDF-built arm (``configs/robots/<name>.yaml`` names the file)."""
    return read_urdf(robot_file(load_robot_config(name).urdf))


def _make_urdf_arm(name: str) -> Callable[[], composer.Entity]:
    def make() -> composer.Entity:
        return UrdfArm(robot_urdf(name), load_robot_config(name), name)
    return make


# joint_6 only spins the symmetric pusher (spec §1), so the policy commands joints 1-5.
ARMS: dict[str, _ArmSpec] = {
    "jaco": _ArmSpec(make_entity=_make_jaco, commanded_joints=(0, 1, 2, 3, 4)),
    "j2s6s200": _ArmSpec(make_entity=_make_urdf_arm("j2s6s200"), commanded_joints=(0, 1, 2, 3, 4)),
}


def make_arm(name: str) -> composer.Entity:
    """A fresh composer entity of the named arm."""
    if name not in ARMS:
        raise ValueError(f"unknown robot {name!r}; choose one of {sorted(ARMS)}")
    return ARMS[name].make_entity()


def describe(name: str, arm: composer.Entity) -> RobotDescription:
    """Read the joint facts of ``arm`` from its compiled MJCF."""
    physics = mjcf.Physics.from_mjcf_model(arm.mjcf_model)
    joints = physics.bind(arm.joints)
    limited = joints.limited.astype(bool)
    ranges = np.array(joints.range, dtype=float).reshape(-1, 2)
    lower = np.where(limited, ranges[:, 0], -np.inf)
    upper = np.where(limited, ranges[:, 1], np.inf)
    ctrl = np.array(physics.bind(arm.actuators).ctrlrange, dtype=float).reshape(-1, 2)
    if not np.allclose(ctrl[:, 0], -ctrl[:, 1]):
        raise ValueError(f"{name}: velocity actuator ranges must be symmetric, got {ctrl.tolist()}")
    return RobotDescription(
        name=name,
        joint_names=tuple(j.name for j in arm.joints),
        position_lower=lower,
        position_upper=upper,
        velocity_limit=ctrl[:, 1].copy(),
        commanded_joints=ARMS[name].commanded_joints,
        link_bodies=tuple(j.parent.name for j in arm.joints),
        base_body=arm.joints[0].parent.parent.name,
        attachment_site=arm.wrist_site.name,
        urdf=arm.urdf.path if isinstance(arm, UrdfArm) else None,
        min_velocity_margin=load_robot_config(name).min_velocity_margin if isinstance(arm, UrdfArm) else 0.0,
    )
