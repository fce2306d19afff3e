"""The measurement path of a real arm and camera: noise and quantisation on every measured value
(:func:`measure`), the joint sensors (:class:`JointSensing`: angles and velocities) and the
perception (:class:`ObjectSensing`: noise on positions and velocities; :class:`PerceptionDelay`:
the latency, the newest snapshot at least that old). Training's observation
(:class:`~ahrm_stack.env.realism.ObservationSensing`) and the sim backend's feedback and perception
use the same objects."""

from __future__ import annotations

import collections
import math
from typing import Generic, TypeVar

import numpy as np

from ahrm_stack.realism.config import RealismConfig

T = TypeVar("T")


def measure(values: np.ndarray, noise: float, resolution: float, rng: np.random.Generator | None) -> np.ndarray:
    """``values`` plus N(0, noise²) each, rounded to multiples of ``resolution`` (0: not); a new
    array. Units are the caller's (rad, rad/s, m)."""
    out = np.array(values, dtype=float)
    if noise > 0 and rng is not None:
        out += rng.normal(0.0, noise, out.shape)
    if resolution > 0:
        out = np.round(out / resolution) * resolution
    return out


class JointSensing:
    """Joint angles (rad) and velocities (rad/s) as the arm's sensors give them: ``realism``'s
    angle and velocity noise (white, Gaussian) and resolution, drawn from the caller's generator."""

    def __init__(self, realism: RealismConfig) -> None:
        self.angle = (math.radians(realism.angle_noise_deg), math.radians(realism.angle_resolution_deg))
        self.speed = (math.radians(realism.velocity_noise_deg_s), math.radians(realism.velocity_resolution_deg_s))

    def angles(self, q: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        return measure(q, *self.angle, rng)

    def velocities(self, dq: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        return measure(dq, *self.speed, rng)


class ObjectSensing:
    """Object positions (m) and linear velocities (m/s, world frame) as a perception module gives
    them: ``realism``'s perception noise (white, Gaussian, per coordinate), from the caller's
    generator. Its latency is :class:`PerceptionDelay`'s."""

    def __init__(self, realism: RealismConfig) -> None:
        self.position_noise = realism.perception_noise
        self.velocity_noise = realism.perception_velocity_noise

    def positions(self, positions: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        return measure(positions, self.position_noise, 0.0, rng)

    def velocities(self, velocities: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        return measure(velocities, self.velocity_noise, 0.0, rng)


class PerceptionDelay(Generic[T]):
    """What a perception ``latency`` s old sees: snapshots pushed with their time (s, any clock);
    :meth:`seen` is the newest pushed at least ``latency`` before ``now`` (the oldest kept while
    none is that old yet). Older ones are dropped as they can no longer be seen."""

    def __init__(self, latency: float, keep: int = 10_000) -> None:
        self.latency = float(latency)
        self._kept: collections.deque[tuple[float, T]] = collections.deque(maxlen=keep)

    def clear(self) -> None:
        self._kept.clear()

    def push(self, time: float, snapshot: T) -> None:
        self._kept.append((float(time), snapshot))

    def __bool__(self) -> bool:
        return bool(self._kept)

    def seen(self, now: float) -> T:
        wanted = now - self.latency
        while len(self._kept) > 1 and self._kept[1][0] <= wanted + 1e-9:
            self._kept.popleft()
        return self._kept[0][1]
