"""The arm registry: one file per arm, ``configs/robots/<name>.yaml``, holds everything about that
arm (:class:`ArmEntry`): where its model comes from, the joints the policy commands, its home
posture, its self-collision pairs, its joint acceleration limits, the safety filter's servo headroom,
and how a real arm of that model is driven (the Kinova Gen2 joint convention and the arm types it may be; the Kortex model it
is). A new arm is one such file plus its model files; its name is the file's name.

Joint limits and velocity limits are not here: they are read from the compiled model
(:mod:`ahrm_stack.robot`). The per-arm values the task, the safety filter and deploy read from their
own sections (``task.arm.home_deg``, ``safety.self_collision_pairs``,
``safety.acceleration_limit``, deploy's
``kinova_gen2.joints`` and ``kortex.models``) are composed from the entries when the configuration
is loaded (:func:`compose_task`, :func:`compose_deploy`), so a run's ``config.yaml`` still records
them and a profile or an override still changes them.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from ahrm_stack.config.fields import Frozen, NonNeg, NonNegInt, Pos
from ahrm_stack.config.files import ROBOTS_DIR
from ahrm_stack.schema import ConfigError, Float, Section, Str, count, fail, load_file, within

PARTS = "base, link1 ... link9 or pusher"  # the arm parts a self-collision pair names
PART = re.compile(r"^(base|pusher|link[1-9])$")


@Frozen
class UrdfArmConfig(Section):
    """How to build a simulated arm from a URDF of the ``example-robot-data`` package or one vendored
    in this package. Joint limits, velocity limits, efforts, inertias and meshes come from the URDF;
    this holds only the simulation parameters a URDF does not carry, and which links to use."""

    file: Str  # path under example-robot-data's share folder, e.g. robots/.../kinova.urdf, or
    # package://ahrm_stack/<path> for a vendored URDF (ahrm_stack/arms/assets.py)
    root_link: Str  # the link placed at the arm's base frame
    flange_link: Str  # the last link kept: the hand mounts here and the pusher replaces it
    end_effector_link: Str  # a link below the flange: the pusher points from the flange toward it
    # (along its z axis where it sits on the flange's origin)
    hand_meshes: tuple[Str, ...]  # mesh file names of the hand on the flange link (not built)
    velocity_gain: Pos  # kv of the velocity actuators, N m s/rad
    joint_damping: NonNeg  # N m s/rad, every actuated joint
    armature: tuple[NonNeg, ...]  # kg m^2, per actuated joint (rotor inertia)
    frictionloss: tuple[NonNeg, ...]  # N m, per actuated joint

    def check(self, key: str) -> None:
        if len(self.armature) != len(self.frictionloss):
            raise ConfigError(f"{key}: armature ({len(self.armature)} values) and frictionloss "
                              f"({len(self.frictionloss)} values) must both give one value per joint")


def pair_problem(pairs: Any) -> str | None:
    """What is wrong with a list of self-collision pairs, as ``[i]: reason`` (to follow its key), or
    None: each pair must name two different arm parts (``base``, ``link1`` ... ``link9``, ``pusher``)."""
    for i, pair in enumerate(pairs):
        for name in pair:
            if not PART.match(name):
                return f"[{i}]: {name!r} is not an arm part; use {PARTS}"
        if pair[0] == pair[1]:
            return f"[{i}]: a part cannot be paired with itself ({list(pair)})"
    return None


@Frozen
class ArmEntry(Section):
    """One arm of the registry (``configs/robots/<name>.yaml``)."""

    source: Literal["dm_control_jaco", "urdf"]  # dm_control_jaco: dm_control's JacoArm MJCF (the
    # j2n6s300); urdf: built from ``urdf`` below
    commanded_joints: Annotated[tuple[NonNegInt, ...], count(1)]  # joint indices the policy drives;
    # the others hold zero velocity
    home_deg: Annotated[tuple[Float, ...], count(1)]  # deg per joint: the start posture
    # (``task.arm.home_deg.<name>``)
    self_collision_pairs: tuple[tuple[Str, Str], ...]  # arm parts that keep the safety filter's
    # safe distance (``safety.self_collision_pairs.<name>``)
    acceleration_limit: tuple[Pos, ...]  # rad/s^2 per joint (one per home_deg entry): the safety
    # filter's |u - u_prev| <= a_max dt (``safety.acceleration_limit.<name>``)
    contact_threshold_nm: tuple[Pos, ...]  # N·m per joint (one per home_deg entry): the deploy loop's
    # contact stop e-stops the arm when its external-torque estimate passes this (deploy's
    # ``contact.threshold_nm.<name>``; ahrm_stack/deploy/contact.py)
    min_velocity_margin: Annotated[Float, within(0, 1, "[)")]  # lower bound on
    # safety.velocity_margin for this arm (fraction of each velocity limit): servo headroom
    kinova_gen2: Optional[dict[Str, Any]]  # the Kinova Gen2 joint convention (sign, offset_deg,
    # robot_types; deploy's ``kinova_gen2.joints.<name>``, whose schema checks it); null: not a Gen2 arm
    kortex: Optional[dict[Str, Any]]  # the Kortex arm it is (model, dof; deploy's
    # ``kortex.models.<name>``); null: not a Kortex arm
    urdf: Optional[UrdfArmConfig] = None  # source: urdf only

    def check(self, key: str) -> None:
        if (self.source == "urdf") != (self.urdf is not None):
            raise ConfigError(f"{key}.urdf: give it exactly when source is urdf (source: {self.source})")
        if len(self.acceleration_limit) != len(self.home_deg):
            raise ConfigError(f"{key}.acceleration_limit has {len(self.acceleration_limit)} values, home_deg "
                              f"{len(self.home_deg)}: both give one value per joint")
        if len(self.contact_threshold_nm) != len(self.home_deg):
            raise ConfigError(f"{key}.contact_threshold_nm has {len(self.contact_threshold_nm)} values, home_deg "
                              f"{len(self.home_deg)}: both give one value per joint")
        if len(set(self.commanded_joints)) != len(self.commanded_joints):
            raise ConfigError(f"{key}.commanded_joints: {list(self.commanded_joints)} repeats a joint")
        problem = pair_problem(self.self_collision_pairs)
        if problem:
            raise ConfigError(f"{key}.self_collision_pairs{problem}")


def arm_names(robots_dir: Path | str = ROBOTS_DIR) -> tuple[str, ...]:
    """The registered arms: the names of ``<robots_dir>/*.yaml``, sorted."""
    return tuple(sorted(path.stem for path in Path(robots_dir).glob("*.yaml")))


def load_arm(name: str, robots_dir: Path | str = ROBOTS_DIR) -> ArmEntry:
    """The validated entry ``<robots_dir>/<name>.yaml``; keys are named as ``robots/<name>.<key>``.
    A name that is not registered is a one-line :class:`ConfigError` listing those that are."""
    if name not in arm_names(robots_dir):
        raise ConfigError(f"no arm {name!r} in {robots_dir}; registered: {list(arm_names(robots_dir))}")
    path = Path(robots_dir).resolve() / f"{name}.yaml"
    stat = path.stat()
    return _load_arm(name, path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=64)
def _load_arm(name: str, path: Path, mtime_ns: int, size: int) -> ArmEntry:
    """The entry as of the file's modification time and size (an edited file is read again)."""
    return load_file(ArmEntry, path, f"robots/{name}")


def registered_arm(value: str) -> str:
    """``value`` if it names a registered arm (``task.robot``; the registry of the config folder in
    use, :data:`ROBOTS_DIR`), else a schema error listing them."""
    names = arm_names()
    if value not in names:
        fail(f": no arm {value!r}; registered (configs/robots/): {list(names)}")
    return value


def compose_task(data: dict, robots_dir: Path | str = ROBOTS_DIR) -> None:
    """``task.arm.home_deg``, ``safety.self_collision_pairs`` and ``safety.acceleration_limit`` of
    the raw sections ``data``, in place, from the registry: one entry per arm, in name order (a
    section that already has the key keeps its value: a file written before the registry, or one
    that gives its own)."""
    entries = {name: load_arm(name, robots_dir) for name in arm_names(robots_dir)}
    arm = data.get("task", {}).get("arm") if isinstance(data.get("task"), dict) else None
    if isinstance(arm, dict) and "home_deg" not in arm:
        arm["home_deg"] = {name: list(entry.home_deg) for name, entry in entries.items()}
    safety = data.get("safety")
    if isinstance(safety, dict) and "self_collision_pairs" not in safety:
        safety["self_collision_pairs"] = {name: [list(p) for p in entry.self_collision_pairs]
                                          for name, entry in entries.items()}
    if isinstance(safety, dict) and "acceleration_limit" not in safety:
        safety["acceleration_limit"] = {name: list(entry.acceleration_limit) for name, entry in entries.items()}


def compose_deploy(data: dict, robots_dir: Path | str = ROBOTS_DIR) -> None:
    """deploy's ``kinova_gen2.joints``, ``kortex.models`` and ``contact.threshold_nm`` of the raw
    ``deploy.yaml`` ``data``, in place, from the registry's arms that have them (a section that
    already has the key keeps it)."""
    entries = {name: load_arm(name, robots_dir) for name in arm_names(robots_dir)}
    contact = data.get("contact")
    if isinstance(contact, dict) and "threshold_nm" not in contact:
        contact["threshold_nm"] = {name: list(entry.contact_threshold_nm) for name, entry in entries.items()}
    for section, key, field in (("kinova_gen2", "joints", "kinova_gen2"), ("kortex", "models", "kortex")):
        target = data.get(section)
        if isinstance(target, dict) and key not in target:
            target[key] = {name: dict(getattr(entry, field)) for name, entry in entries.items()
                           if getattr(entry, field) is not None}


__all__ = ["ArmEntry", "UrdfArmConfig", "arm_names", "compose_deploy", "compose_task",
           "load_arm", "pair_problem", "registered_arm"]
