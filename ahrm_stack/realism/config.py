"""One set of a real arm's imperfections (:class:`RealismConfig`), the named sets of
``configs/realism.yaml`` and the groups the robustness evaluation applies one at a time.

The schema sits here, below ``config/`` (which reads ``task.realism`` with it) and beside the
imperfections that act on it (:mod:`ahrm_stack.realism`): training's runner and the sim backend
compose the same objects from one of these."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any

from ahrm_stack.paths import CONFIG_DIR
from ahrm_stack.schema import ConfigError, Float, Section, ge, gt, read_yaml

REALISM_FILE = CONFIG_DIR / "realism.yaml"

NonNeg = Annotated[Float, ge(0)]
Scale = tuple[Annotated[Float, gt(0)], Annotated[Float, gt(0)]]


@dataclasses.dataclass(frozen=True)
class RealismConfig(Section):
    """One set of a real arm's imperfections. Angles in degrees, times in s, lengths in m,
    world frame; a scale is a factor range ``[low, high]`` drawn uniformly per episode."""

    command_latency: NonNeg  # s from a command leaving the controller to the actuators taking it
    actuator_lag: NonNeg  # s, time constant of the actuators' first-order response to a command
    angle_noise_deg: NonNeg  # deg, std of white Gaussian noise on each measured joint angle
    angle_resolution_deg: NonNeg  # deg, a measured angle is rounded to a multiple of this (0: not)
    velocity_noise_deg_s: NonNeg  # deg/s, std of white Gaussian noise on each measured joint velocity
    velocity_resolution_deg_s: NonNeg  # deg/s, measured velocities are rounded to this (0: not)
    perception_noise: NonNeg  # m, std of white noise on each coordinate of a perceived object position
    perception_velocity_noise: NonNeg  # m/s, std of noise on each perceived object velocity coordinate
    perception_latency: NonNeg  # s, the perceived object poses are this old
    cube_mass_scale: Scale  # factor on the cube's mass
    cube_friction_scale: Scale  # factor on the cube's sliding friction coefficient
    obstacle_mass_scale: Scale  # factor on each obstacle's mass (drawn per obstacle)
    obstacle_friction_scale: Scale  # factor on each obstacle's sliding friction coefficient

    def check(self, key: str) -> None:
        for name in SCALES:
            low, high = getattr(self, name)
            if low > high:
                raise ConfigError(f"{key}.{name} must be [low, high] with low <= high, got {[low, high]}")

    @classmethod
    def ideal(cls) -> "RealismConfig":
        """No imperfection: the simulation as it is."""
        values: dict[str, Any] = {f.name: (1.0, 1.0) if f.name in SCALES else 0.0
                                  for f in dataclasses.fields(cls)}
        return cls(**values)

    @property
    def is_ideal(self) -> bool:
        return self == RealismConfig.ideal()

    @property
    def senses(self) -> bool:
        """Whether measurements (feedback or perception) differ from the simulator's state."""
        return any(getattr(self, name) > 0 for name in GROUPS["feedback noise"] + GROUPS["perception"])

    @property
    def actuates(self) -> bool:
        """Whether commands reach the actuators late or lagged."""
        return self.command_latency > 0 or self.actuator_lag > 0

    @property
    def varies_dynamics(self) -> bool:
        return any(tuple(getattr(self, name)) != (1.0, 1.0) for name in SCALES)

    def only(self, group: str) -> "RealismConfig":
        """This set's values of ``group`` (a key of :data:`GROUPS`), the rest ideal."""
        ideal = RealismConfig.ideal()
        return dataclasses.replace(ideal, **{name: getattr(self, name) for name in GROUPS[group]})


SCALES = ("cube_mass_scale", "cube_friction_scale", "obstacle_mass_scale", "obstacle_friction_scale")

#: The imperfections the robustness evaluation applies one at a time (then all together).
GROUPS: dict[str, tuple[str, ...]] = {
    "command latency": ("command_latency",),
    "actuator lag": ("actuator_lag",),
    "feedback noise": ("angle_noise_deg", "angle_resolution_deg", "velocity_noise_deg_s",
                       "velocity_resolution_deg_s"),
    "perception": ("perception_noise", "perception_velocity_noise", "perception_latency"),
    "dynamics": SCALES,
}


def nominal(task_config):
    """``task_config`` (a :class:`~ahrm_stack.config.TaskConfig`) without imperfections: the task
    evaluations measure (the robustness evaluation measures the imperfections, through deploy)."""
    return dataclasses.replace(task_config, realism=RealismConfig.ideal())


def realism_profiles(path: Path | str = REALISM_FILE) -> dict[str, RealismConfig]:
    """The named sets of ``configs/realism.yaml`` (``profiles``), validated."""
    data = read_yaml(path)
    profiles = data.get("profiles") if isinstance(data, dict) else None
    if not isinstance(profiles, dict) or not profiles:
        raise ConfigError(f"{path}: expected a mapping 'profiles' of named sets")
    return {name: RealismConfig.from_dict(value, f"profiles.{name}", str(path))
            for name, value in profiles.items()}


def resolve_realism(value: Any, key: str, path: Path | str = REALISM_FILE) -> Any:
    """A realism value as read from YAML: a profile name becomes that profile's mapping (a
    mapping is returned as it is, for the schema to check)."""
    if not isinstance(value, str):
        return value
    data = read_yaml(path)
    profiles = data.get("profiles", {}) if isinstance(data, dict) else {}
    if value not in profiles:
        raise ConfigError(f"{key}: no realism profile {value!r} in {path}; choose one of {sorted(profiles)}")
    return dict(profiles[value])
