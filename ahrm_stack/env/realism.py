"""A real arm's imperfections: what separates the simulated task from a JACO2 on a table.

:class:`RealismConfig` is one set of imperfections, each with its unit; ``configs/realism.yaml``
names the sets (``ideal``: none; ``jaco2``: a JACO2 with a camera, each value justified there).
The same section serves two places:

* ``task.realism`` (training's domain randomisation, :class:`~ahrm_stack.env.runner.TaskRunner`):
  the observation the policy sees is measured with the noise and the perception latency
  (:class:`ObservationSensing`), commands reach the actuators late and through a first-order lag
  (:class:`ActuatorModel`), and each episode draws the cube's and the obstacles' mass and friction
  (:func:`draw_dynamics`);
* ``deploy.sim.realism`` (the sim backend, :class:`ahrm_stack.hardware.sim.SimArm`): the same imperfections
  on the adapter's feedback and perception, as a real arm and camera would give them.

All of it is off (bit for bit the ideal simulation, no random draw made) when a set is
:meth:`RealismConfig.ideal`; :data:`GROUPS` names the imperfections the robustness evaluation
applies one at a time (``python -m ahrm_stack.robustness``).
"""

from __future__ import annotations

import collections
import dataclasses
import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np

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


def measure(values: np.ndarray, noise: float, resolution: float, rng: np.random.Generator | None) -> np.ndarray:
    """``values`` plus N(0, noise²) each, rounded to multiples of ``resolution`` (0: not); a new
    array. Units are the caller's (rad, rad/s, m)."""
    out = np.array(values, dtype=float)
    if noise > 0 and rng is not None:
        out += rng.normal(0.0, noise, out.shape)
    if resolution > 0:
        out = np.round(out / resolution) * resolution
    return out


def draw_dynamics(realism: RealismConfig, rng: np.random.RandomState, obstacles: int) -> dict[str, np.ndarray]:
    """One episode's factors: ``cube_mass``, ``cube_friction`` (shape (1,)), ``obstacle_mass``,
    ``obstacle_friction`` (shape (obstacles,)), uniform in the configured ranges."""
    def draw(scale: tuple[float, float], n: int) -> np.ndarray:
        return rng.uniform(scale[0], scale[1], n) if scale[0] < scale[1] else np.full(n, scale[0])
    return {"cube_mass": draw(realism.cube_mass_scale, 1),
            "cube_friction": draw(realism.cube_friction_scale, 1),
            "obstacle_mass": draw(realism.obstacle_mass_scale, obstacles),
            "obstacle_friction": draw(realism.obstacle_friction_scale, obstacles)}


class DynamicsVariation:
    """Scales the cube's and the obstacles' mass (and inertia) and sliding friction of one physics,
    from the nominal values it found there (so repeated draws never compound)."""

    def __init__(self, physics, cube_body: int, obstacle_bodies: np.ndarray, cube_geom: int,
                 obstacle_geoms: np.ndarray) -> None:
        model = physics.model
        self.physics = physics
        self._model = model
        self._bodies = np.array([cube_body, *obstacle_bodies], dtype=int)
        self._geoms = np.array([cube_geom, *obstacle_geoms], dtype=int)
        self._mass = np.array(model.body_mass[self._bodies], dtype=float)
        self._inertia = np.array(model.body_inertia[self._bodies], dtype=float)
        self._friction = np.array(model.geom_friction[self._geoms, 0], dtype=float)
        # MuJoCo combines two geoms' friction by the maximum unless their priorities differ: the
        # cube's and obstacles' own coefficients decide their contacts (with the table, the pusher)
        # only at a higher priority. Every geom here has the same nominal coefficient, so at
        # factor 1 the contacts are unchanged.
        model.geom_priority[self._geoms] = int(model.geom_priority.max()) + 1
        self.factors: dict[str, np.ndarray] = {}

    def apply(self, factors: dict[str, np.ndarray]) -> None:
        """Set mass (and inertia, same factor) and sliding friction to nominal x the factors."""
        mass = np.concatenate([factors["cube_mass"], factors["obstacle_mass"]])
        friction = np.concatenate([factors["cube_friction"], factors["obstacle_friction"]])
        self._model.body_mass[self._bodies] = self._mass * mass
        self._model.body_inertia[self._bodies] = self._inertia * mass[:, None]
        self._model.geom_friction[self._geoms, 0] = self._friction * friction
        self.factors = factors


class ActuatorModel:
    """Commands reaching the velocity actuators late (``command_latency``) and through a first-order
    lag (``actuator_lag``), advanced one physics step at a time. ``latency`` is rounded to whole
    physics steps (``timestep`` s)."""

    def __init__(self, realism: RealismConfig, timestep: float, num_joints: int) -> None:
        self.delay_steps = int(round(realism.command_latency / timestep))
        tau = realism.actuator_lag
        self.alpha = 1.0 if tau <= 0 else 1.0 - math.exp(-timestep / tau)
        self._pending: collections.deque[tuple[int, np.ndarray]] = collections.deque()
        self._target = np.zeros(num_joints)  # the command the actuators are converging to, rad/s
        self.output = np.zeros(num_joints)  # what the actuators apply now, rad/s
        self._step = 0

    def reset(self, command: np.ndarray | None = None) -> None:
        """At rest (or holding ``command`` already), nothing in flight."""
        self._pending.clear()
        value = np.zeros_like(self.output) if command is None else np.asarray(command, float)
        self._target = value.copy()
        self.output = value.copy()

    def command(self, command: np.ndarray) -> None:
        """A command sent now: it takes effect ``delay_steps`` physics steps later."""
        self._pending.append((self._step + self.delay_steps, np.asarray(command, float).copy()))

    def stop_now(self) -> None:
        """Everything in flight dropped and the actuators at zero (the arm's own stop)."""
        self.reset()

    def step(self) -> np.ndarray:
        """The actuators' command for the next physics step (rad/s); call once per step."""
        while self._pending and self._pending[0][0] <= self._step:
            self._target = self._pending.popleft()[1]
        self.output = self.output + self.alpha * (self._target - self.output)
        self._step += 1
        return self.output


class VelocityEstimator:
    """Joint velocities (rad/s) from measured joint angles (rad): each update's difference
    quotient over the time since the last (angles wrapped to (-pi, pi]), exponentially smoothed
    (``smoothing`` of the previous estimate kept). What a real controller uses when the velocity
    feedback is poor; training (``task.observation.joint_velocity: position_difference``) and the
    deploy loop's world model run the same estimator. Zero at the first update (the arm starts at
    rest)."""

    def __init__(self, smoothing: float) -> None:
        self.smoothing = float(smoothing)
        self._q: np.ndarray | None = None
        self.velocity: np.ndarray | None = None

    def reset(self) -> None:
        self._q = self.velocity = None

    def __call__(self, q: np.ndarray, dt: float) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if self._q is None or self.velocity is None or not dt > 0:
            self._q, self.velocity = q.copy(), np.zeros_like(q)
            return self.velocity.copy()
        change = np.remainder(q - self._q + np.pi, 2 * np.pi) - np.pi
        quotient = change / dt
        self.velocity = self.smoothing * self.velocity + (1.0 - self.smoothing) * quotient
        self._q = q.copy()
        return self.velocity.copy()


class ObservationSensing:
    """The training observation as a real arm and camera would measure it: joint angles and
    velocities with noise and quantisation, object positions and velocities with noise and
    ``perception_latency`` (whole control periods), and the entries computed from them
    (the tip and the obstacles relative to the cube, the lane clearances) recomputed from the
    measured positions. The phase, x, the tip, the previous action and the lane plan stay exact.

    ``layout``: :func:`~ahrm_stack.env.observation_layout.observation_layout` of the task;
    ``lane_clearance``: (cube_xy, obstacle_xy) -> the clipped clearances, or None."""

    def __init__(self, realism: RealismConfig, layout: dict[str, slice], control_period: float,
                 obstacles: int, lane_clearance=None, velocity: "VelocityEstimator | None" = None) -> None:
        self.realism = realism
        self.layout = layout
        self.period = control_period
        self.velocity = velocity  # joint velocities from the measured angles (None: as measured)
        self.delay = int(round(realism.perception_latency / control_period))
        self._history: collections.deque[np.ndarray] = collections.deque(maxlen=self.delay + 1)
        self._props = [layout["cube"]] + [layout[f"obstacle_{i}"] for i in range(obstacles)]
        self._lane_clearance = lane_clearance

    def reset(self) -> None:
        self._history.clear()
        if self.velocity is not None:
            self.velocity.reset()

    def __call__(self, observation: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        r, at = self.realism, self.layout
        out = np.array(observation, dtype=float)
        trig = out[at["joints_pos"]]
        q = np.arctan2(trig[0::2], trig[1::2])
        q = measure(q, math.radians(r.angle_noise_deg), math.radians(r.angle_resolution_deg), rng)
        trig[0::2], trig[1::2] = np.sin(q), np.cos(q)
        if self.velocity is not None:
            out[at["joints_vel"]] = self.velocity(q, self.period)
        else:
            out[at["joints_vel"]] = measure(out[at["joints_vel"]], math.radians(r.velocity_noise_deg_s),
                                            math.radians(r.velocity_resolution_deg_s), rng)
        props = np.stack([out[s] for s in self._props])  # (k, 6): position, velocity
        self._history.append(props)
        seen = self._history[0].copy()  # the oldest kept: ``delay`` periods ago (or the first)
        seen[:, :3] = measure(seen[:, :3], r.perception_noise, 0.0, rng)
        seen[:, 3:] = measure(seen[:, 3:], r.perception_velocity_noise, 0.0, rng)
        for s, row in zip(self._props, seen):
            out[s] = row
        cube, obstacles_xy = seen[0, :3], seen[1:, :2]
        if "relative_to_cube" in at:
            tip = out[at["pusher_tip"]]
            out[at["relative_to_cube"]] = np.concatenate([tip - cube, (obstacles_xy - cube[:2]).ravel()])
        if "lane_clearance" in at and self._lane_clearance is not None:
            out[at["lane_clearance"]] = self._lane_clearance(cube[:2], obstacles_xy)
        return out


__all__ = ["ActuatorModel", "DynamicsVariation", "GROUPS", "ObservationSensing", "RealismConfig",
           "VelocityEstimator", "draw_dynamics", "measure", "nominal", "realism_profiles", "resolve_realism"]
