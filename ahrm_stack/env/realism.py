"""The training observation under a real arm's imperfections: :class:`ObservationSensing` (the
observation vector as a real arm and camera would measure it) and :class:`VelocityEstimator`
(joint velocities from measured angles, shared with the deploy loop's world model). The
imperfections themselves, and their schema, are :mod:`ahrm_stack.realism`'s, composed here and by
the sim backend alike.
"""

from __future__ import annotations

import numpy as np

from ahrm_stack.realism import JointSensing, ObjectSensing, PerceptionDelay, RealismConfig


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
        self.joints = JointSensing(realism)
        self.objects = ObjectSensing(realism)
        self.delay = int(round(realism.perception_latency / control_period))  # whole control periods
        self._perceived: PerceptionDelay[np.ndarray] = PerceptionDelay(self.delay * control_period)
        self._calls = 0
        self._props = [layout["cube"]] + [layout[f"obstacle_{i}"] for i in range(obstacles)]
        self._lane_clearance = lane_clearance

    def reset(self) -> None:
        self._perceived.clear()
        self._calls = 0
        if self.velocity is not None:
            self.velocity.reset()

    def __call__(self, observation: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        at = self.layout
        out = np.array(observation, dtype=float)
        trig = out[at["joints_pos"]]
        q = self.joints.angles(np.arctan2(trig[0::2], trig[1::2]), rng)
        trig[0::2], trig[1::2] = np.sin(q), np.cos(q)
        if self.velocity is not None:
            out[at["joints_vel"]] = self.velocity(q, self.period)
        else:
            out[at["joints_vel"]] = self.joints.velocities(out[at["joints_vel"]], rng)
        props = np.stack([out[s] for s in self._props])  # (k, 6): position, velocity
        now = self._calls * self.period  # one call per control period
        self._calls += 1
        self._perceived.push(now, props)
        seen = self._perceived.seen(now).copy()  # ``delay`` periods ago (or the first)
        seen[:, :3] = self.objects.positions(seen[:, :3], rng)
        seen[:, 3:] = self.objects.velocities(seen[:, 3:], rng)
        for s, row in zip(self._props, seen):
            out[s] = row
        cube, obstacles_xy = seen[0, :3], seen[1:, :2]
        if "relative_to_cube" in at:
            tip = out[at["pusher_tip"]]
            out[at["relative_to_cube"]] = np.concatenate([tip - cube, (obstacles_xy - cube[:2]).ravel()])
        if "lane_clearance" in at and self._lane_clearance is not None:
            out[at["lane_clearance"]] = self._lane_clearance(cube[:2], obstacles_xy)
        return out


__all__ = ["ObservationSensing", "VelocityEstimator"]
