"""Arms built from a URDF: :class:`UrdfArmConfig`, what ``configs/robots/<name>.yaml`` adds to a
URDF of the ``example-robot-data`` package, read by :func:`load_robot_config`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from ahrm_stack.config.fields import Frozen, NonNeg, Pos
from ahrm_stack.config.files import ROBOTS_DIR
from ahrm_stack.schema import ConfigError, Float, Section, Str, load_file, within


@Frozen
class UrdfArmConfig(Section):
    """How to build a simulated arm from a URDF of the ``example-robot-data`` package. Joint
    limits, velocity limits, efforts, inertias and meshes come from the URDF; this file holds only
    the simulation parameters a URDF does not carry, and which links to use."""

    urdf: Str  # path under example-robot-data's share folder, e.g. robots/.../kinova.urdf
    root_link: Str  # the link placed at the arm's base frame
    flange_link: Str  # the last link kept: the hand mounts here and the pusher replaces it
    end_effector_link: Str  # a link below the flange: the pusher points from the flange toward it
    hand_meshes: tuple[Str, ...]  # mesh file names of the hand on the flange link (not built)
    velocity_gain: Pos  # kv of the velocity actuators, N m s/rad
    min_velocity_margin: Annotated[Float, within(0, 1, "[)")]  # lower bound on safety.velocity_margin
    # for this arm (fraction of each velocity limit): the filter keeps max(safety.velocity_margin,
    # this) as servo headroom
    joint_damping: NonNeg  # N m s/rad, every actuated joint
    armature: tuple[NonNeg, ...]  # kg m^2, per actuated joint (rotor inertia)
    frictionloss: tuple[NonNeg, ...]  # N m, per actuated joint

    def check(self, key: str) -> None:
        if len(self.armature) != len(self.frictionloss):
            raise ConfigError(f"{key}: armature ({len(self.armature)} values) and frictionloss "
                              f"({len(self.frictionloss)} values) must both give one value per joint")


def load_robot_config(name: str, robots_dir: Path | str = ROBOTS_DIR) -> UrdfArmConfig:
    """The validated ``<robots_dir>/<name>.yaml``; keys are named as ``robots/<name>.<key>``."""
    return load_file(UrdfArmConfig, Path(robots_dir) / f"{name}.yaml", f"robots/{name}")
