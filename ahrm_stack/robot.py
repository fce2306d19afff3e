"""The one robot description: everything that reads the arm reads it from here.

The arm is a dm_control composer entity whose MJCF is the single source of truth. Joint limits and
velocity limits are read from the *compiled* MJCF (MuJoCo's ``jnt_range`` and the velocity
actuators' ``ctrlrange``), never restated in code; the simulator, the Pinocchio model, the safety
filter and the hardware adapter all take them from a :class:`RobotDescription`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np
from dm_control import composer, mjcf
from dm_control.entities.manipulators.kinova import jaco_arm


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
    attachment_site: str  # arm-model name of the site the pusher is attached to

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


# joint_6 only spins the symmetric pusher (spec §1), so the policy commands joints 1-5.
ARMS: dict[str, _ArmSpec] = {
    "jaco": _ArmSpec(make_entity=_make_jaco, commanded_joints=(0, 1, 2, 3, 4)),
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
        attachment_site=arm.wrist_site.name,
    )
