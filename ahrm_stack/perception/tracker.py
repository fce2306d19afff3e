"""The cube's position and linear velocity from noisy, possibly missing position measurements.

A constant-velocity Kalman filter, independently per world axis (state: position m, velocity
m/s, world frame): between frames the state moves at its velocity and the velocity takes white
acceleration noise of density ``acceleration_noise`` (m/s²/√Hz); each measured position has
standard deviation ``position_noise`` (m). The filter's posterior position and velocity are what
the deploy loop sees.

Missed detections: a frame without a measurement is a prediction (the last state moved on at its
velocity) for at most ``max_hold`` s after the last measurement; the next one raises
:class:`TagLostError`, a one-line perception fault (the deploy loop then stops the arm). The first
frame must have a measurement.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrm_stack.perception.settings import TrackerSettings


class TagLostError(RuntimeError):
    """The tag was not seen for longer than ``tracker.max_hold`` (or not at the start)."""


@dataclasses.dataclass(frozen=True)
class CubeState:
    """The cube as the tracker estimates it, world frame.

    ``timestamp`` s (the frame's, on the adapter's clock); ``position`` (3,) m; ``quaternion`` (4,)
    (w, x, y, z), the last measured orientation; ``velocity`` (3,) m/s; ``measured``: this frame
    had a detection (False: a prediction); ``since_measured``: s since the last detection's frame
    was captured; ``latency``: s from that capture to its pose (a detection thread's; 0 in the
    control tick)."""

    timestamp: float
    position: np.ndarray
    quaternion: np.ndarray
    velocity: np.ndarray
    measured: bool
    since_measured: float
    latency: float = 0.0  # s, the last measurement's frame capture to its pose (detection time)


class ConstantVelocityFilter:
    """A constant-velocity Kalman filter on 3 independent axes (one 2×2 covariance per axis)."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.r = settings.position_noise ** 2  # m²
        self.q = settings.acceleration_noise ** 2  # m²/s³
        self.v0 = settings.initial_velocity_noise ** 2  # m²/s²
        self.x = np.zeros((3, 2))  # per axis: position, velocity
        self.P = np.zeros((2, 2))  # the same for every axis (same model and noise)
        self.time: float | None = None

    @property
    def initialised(self) -> bool:
        return self.time is not None

    def reset(self, time: float, position: np.ndarray) -> None:
        """Start at a measured ``position`` (m) at rest, at ``time`` s."""
        self.x = np.stack([np.asarray(position, dtype=float), np.zeros(3)], axis=1)
        self.P = np.diag([self.r, self.v0])
        self.time = float(time)

    def predict(self, time: float) -> None:
        """Move the state on to ``time`` s (no-op for a time not after the current one)."""
        dt = float(time) - self.time
        if dt <= 0:
            return
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = self.q * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + Q
        self.time = float(time)

    def update(self, position: np.ndarray) -> None:
        """Fuse a measured position (m) at the current time."""
        S = self.P[0, 0] + self.r
        K = self.P[:, 0] / S  # (2,)
        innovation = np.asarray(position, dtype=float) - self.x[:, 0]  # (3,)
        self.x = self.x + innovation[:, None] * K[None, :]
        self.P = self.P - np.outer(K, self.P[0, :])

    @property
    def position(self) -> np.ndarray:
        return self.x[:, 0].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.x[:, 1].copy()


class CubeTracker:
    """Frames in, :class:`CubeState` out; see the module docstring. ``label`` names the tag in
    error messages (e.g. ``tag36h11 id 0``)."""

    def __init__(self, settings: TrackerSettings, label: str = "the cube's tag") -> None:
        self.settings = settings
        self.label = label
        self.filter = ConstantVelocityFilter(settings)
        self.quaternion = np.array([1.0, 0.0, 0.0, 0.0])
        self.last_measured: float | None = None
        self.frames = 0
        self.misses = 0

    def update(self, time: float, position: np.ndarray | None,
               quaternion: np.ndarray | None = None) -> CubeState:
        """One frame at ``time`` s: ``position`` (m, world) and ``quaternion`` of the cube when the
        tag was seen, None when not. Raises :class:`TagLostError` when the tag was not seen at the
        first frame or for more than ``max_hold`` s."""
        self.frames += 1
        if position is None:
            self.misses += 1
            self._check_held(time)
            self.filter.predict(time)
        else:
            if not self.filter.initialised:
                self.filter.reset(time, position)
            else:
                self.filter.predict(time)
                self.filter.update(position)
            self.last_measured = float(time)
            if quaternion is not None:
                self.quaternion = np.asarray(quaternion, dtype=float).copy()
        return CubeState(timestamp=float(time), position=self.filter.position,
                         quaternion=self.quaternion.copy(), velocity=self.filter.velocity,
                         measured=position is not None,
                         since_measured=float(time) - self.last_measured)

    def _check_held(self, time: float) -> float:
        """The time (s) since the last measurement at ``time`` (s); :class:`TagLostError` when
        there was none yet, or it is over ``tracker.max_hold``."""
        if self.last_measured is None:
            raise TagLostError(f"{self.label} is not in the camera image at the start")
        gap = float(time) - self.last_measured
        if gap > self.settings.max_hold + 1e-9:
            raise TagLostError(f"{self.label} not seen for {gap:.3f} s > tracker.max_hold "
                               f"{self.settings.max_hold:g} s")
        return gap

    def at(self, time: float, latency: float = 0.0) -> CubeState:
        """The state predicted to ``time`` s (not after a measurement: the filter is left as it
        is), ``latency`` s recorded with it. The staleness rule of :meth:`update`:
        :class:`TagLostError` when the last measurement's frame is more than ``max_hold`` s older
        than ``time`` (or there was none)."""
        gap = self._check_held(time)
        ahead = max(0.0, float(time) - float(self.filter.time))
        return CubeState(timestamp=float(time), position=self.filter.position + ahead * self.filter.velocity,
                         quaternion=self.quaternion.copy(), velocity=self.filter.velocity,
                         measured=gap <= 0.0, since_measured=gap, latency=float(latency))
