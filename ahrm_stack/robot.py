"""The one robot description: everything that reads the arm reads it from here.

Each arm is an entry of the registry, ``configs/robots/<name>.yaml``
(:mod:`ahrm_stack.config.robots`), built as a dm_control composer entity from its ``source``
(:data:`SOURCES`). ``jaco`` is dm_control's curved-wrist JACO2, whose MJCF is its source of truth;
``j2s6s200`` is the spherical-wrist JACO2 of ``example-robot-data`` and ``gen3`` the Kinova Gen3
(7 DoF) vendored in ``ahrm_stack/arms/vendor/kinova_gen3``, whose URDFs are (the entity and the
Pinocchio model are both built from them, :mod:`ahrm_stack.arms`). Joint limits and velocity
limits are read from the *compiled* MJCF (MuJoCo's ``jnt_range`` and the velocity actuators'
``ctrlrange``), never restated in code; the simulator, the Pinocchio model, the safety filter and
the hardware adapter all take them from a :class:`RobotDescription`.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Callable

import numpy as np
from dm_control import composer, mjcf
from dm_control.entities.manipulators.kinova import jaco_arm

from ahrm_stack.arms.assets import urdf_file
from ahrm_stack.arms.entity import UrdfArm
from ahrm_stack.arms.urdf import Urdf, read_urdf
from ahrm_stack.config import arm_names, load_arm


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


def _make_jaco(name: str) -> composer.Entity:
    return jaco_arm.JacoArm(name=name)


@functools.lru_cache(maxsize=None)
def robot_urdf(name: str) -> Urdf:
    """The parsed URDF of a URDF-built arm (``configs/robots/<name>.yaml``'s ``urdf.file``)."""
    settings = load_arm(name).urdf
    if settings is None:
        raise ValueError(f"robots/{name}: not built from a URDF (source: {load_arm(name).source})")
    return read_urdf(urdf_file(settings.file))


def _make_urdf_arm(name: str) -> composer.Entity:
    settings = load_arm(name).urdf
    assert settings is not None  # ArmEntry.check: source urdf has a urdf block
    return UrdfArm(robot_urdf(name), settings, name)


#: How each ``source`` of the arm registry (``configs/robots/<name>.yaml``) is built.
SOURCES: dict[str, Callable[[str], composer.Entity]] = {
    "dm_control_jaco": _make_jaco,
    "urdf": _make_urdf_arm,
}


def make_arm(name: str) -> composer.Entity:
    """A fresh composer entity of the registered arm ``name`` (``configs/robots/<name>.yaml``)."""
    if name not in arm_names():
        raise ValueError(f"unknown robot {name!r}; registered (configs/robots/): {list(arm_names())}")
    return SOURCES[load_arm(name).source](name)


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
    entry = load_arm(name)
    return RobotDescription(
        name=name,
        joint_names=tuple(j.name for j in arm.joints),
        position_lower=lower,
        position_upper=upper,
        velocity_limit=ctrl[:, 1].copy(),
        commanded_joints=entry.commanded_joints,
        link_bodies=tuple(j.parent.name for j in arm.joints),
        base_body=arm.joints[0].parent.parent.name,
        attachment_site=arm.wrist_site.name,
        urdf=arm.urdf.path if isinstance(arm, UrdfArm) else None,
        min_velocity_margin=entry.min_velocity_margin,
    )
