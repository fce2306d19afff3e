"""The dynamics a real table varies: the cube's and the obstacles' mass and sliding friction, drawn
per episode (:func:`draw_dynamics`) and bound to one physics (:class:`DynamicsVariation`), in the
manner of dm_control's variators. Used by the task's episode initialisation, which the sim backend
runs too."""

from __future__ import annotations

import numpy as np

from ahrm_stack.realism.config import RealismConfig


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
