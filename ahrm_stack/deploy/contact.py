"""The contact stop: an external torque estimated from the arm's feedback, over a joint's threshold,
stops the arm (issue 58, item 4).

The estimate is the generalised-momentum residual of De Luca and Mattone, in the discrete form of
Haddadin, De Luca and Albu-Schäffer ("Robot collisions: a survey on detection, isolation, and
identification", IEEE T-RO 33(6), 2017), computed from what the deploy loop reads once per control
period (joint position, velocity and torque) on a private copy of the arm's dynamics (the deploy
world's MuJoCo model: the arm, its tool and their armature). Over one period from reading ``k-1``
to ``k`` (joint frame, model signs),

    p_k - p_{k-1} = ∫ (τ + τ_ext - b(q, q̇) + Ṁ q̇) dt,     p = M(q) q̇

with ``τ`` the measured joint torque, ``b`` MuJoCo's bias force (Coriolis, centrifugal, gravity)
minus its passive force and ``M`` the joint-space inertia. Averaging the integrand's samples at
both ends, the period's mean external torque is ``e_k = M̄ (q̇_k - q̇_{k-1}) / Δt + (b̄ - τ̄)``,
low-passed as ``r_k = r_{k-1} + K Δt (e_k - r_{k-1})``.

What it can sense, measured (docs/contact-residual/, ``studies/contact_residual.py``): at 20 Hz,
with the simulator's own model (an exact model), the estimate errs by ~10 N·m (95th percentile) on
the JACO's three large joints in normal runs, about the torque of a light contact, and pushing the
cube loads the arm that much too. The thresholds (each arm's ``contact_threshold_nm``,
configs/robots/) sit above every normal run's estimate, at or above the actuators' limits, so this
stops a load that back-drives the arm, not a light contact: it is no skin.
"""

from __future__ import annotations

import logging
from typing import Sequence

import mujoco
import numpy as np


def arm_dofs(model: mujoco.MjModel, qpos: Sequence[int]) -> np.ndarray:
    """The degrees of freedom (indices into ``qvel``) of the joints whose positions sit at ``qpos``
    (indices into ``qpos``), in that order."""
    by_address = {int(model.jnt_qposadr[j]): j for j in range(model.njnt)}
    missing = [int(a) for a in qpos if int(a) not in by_address]
    if missing:
        raise ValueError(f"qpos addresses {missing} start no joint of the model")
    return np.array([model.jnt_dofadr[by_address[int(a)]] for a in qpos], dtype=int)


class ExternalTorqueEstimator:
    """Per-joint external torque (N·m, joint frame, model signs) from measured joint position,
    velocity and torque, on a private copy of the arm's dynamics.

    Args:
        model: a compiled MuJoCo model holding the arm (other bodies may be present: the arm's
            block of the inertia matrix and its bias do not depend on them).
        dofs: the arm's degrees of freedom in ``model`` (indices into ``qvel``), one per joint.
        qpos: the arm's joint addresses in ``model`` (indices into ``qpos``).
        gain: K, 1/s, of the estimate's low-pass.
        period: Δt, s, between two readings (the control period).
    """

    def __init__(self, model: mujoco.MjModel, dofs: Sequence[int], qpos: Sequence[int], gain: float,
                 period: float) -> None:
        if not 0 < gain * period <= 1:
            raise ValueError(f"observer gain x period must be in (0, 1], got {gain} x {period}")
        self.model, self.data = model, mujoco.MjData(model)
        self.dofs, self.qpos = np.asarray(dofs, dtype=int), np.asarray(qpos, dtype=int)
        self.alpha, self.period = gain * period, period
        self._full = np.zeros((model.nv, model.nv))
        self.estimate = np.zeros(len(self.dofs))
        self._previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # M, q̇, b - τ

    def reset(self) -> None:
        """Forget the history (a new run, or after a stop): the next reading starts it again."""
        self.estimate[:] = 0.0
        self._previous = None

    def _dynamics(self, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """M (n, n) and bias minus passive force (n,) of the arm at (q, q̇)."""
        model, data = self.model, self.data
        data.qpos[self.qpos] = position
        data.qvel[:] = 0.0
        data.qvel[self.dofs] = velocity
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_makeM(model, data)  # composite rigid bodies, armature added
        mujoco.mj_comVel(model, data)
        mujoco.mj_passive(model, data)
        mujoco.mj_rne(model, data, 0, data.qfrc_bias)
        mujoco.mj_fullM(model, data, self._full)
        inertia = self._full[np.ix_(self.dofs, self.dofs)].copy()
        return inertia, data.qfrc_bias[self.dofs] - data.qfrc_passive[self.dofs]

    def update(self, position: np.ndarray, velocity: np.ndarray, torque: np.ndarray) -> np.ndarray:
        """Take one reading (rad, rad/s, N·m per joint) and return the estimate (a view: copy it
        to keep it). The first reading after :meth:`reset` returns zeros."""
        velocity = np.asarray(velocity, dtype=float)
        inertia, bias = self._dynamics(np.asarray(position, dtype=float), velocity)
        residual = bias - np.asarray(torque, dtype=float)
        if self._previous is not None:
            inertia_0, velocity_0, residual_0 = self._previous
            mean = 0.5 * (inertia + inertia_0) @ (velocity - velocity_0) / self.period
            mean += 0.5 * (residual + residual_0)
            self.estimate += self.alpha * (mean - self.estimate)
        self._previous = (inertia, velocity, residual)
        return self.estimate


class ContactStop:
    """The deploy loop's contact check: :class:`ExternalTorqueEstimator` on each feedback frame,
    and a stop reason once a joint's estimate exceeds its threshold on ``readings`` consecutive
    readings.

    Args:
        estimator: the estimator, on the arm's model.
        thresholds: N·m per joint (the arm's ``contact_threshold_nm``), compared with |estimate|.
        readings: consecutive readings over the threshold that make a contact (1: the first).
    """

    active = True

    def __init__(self, estimator: ExternalTorqueEstimator, thresholds: Sequence[float], readings: int) -> None:
        limits = np.asarray(thresholds, dtype=float)
        if limits.shape != estimator.estimate.shape:
            raise ValueError(f"{limits.size} contact thresholds for an arm of "
                             f"{estimator.estimate.size} joints")
        if readings < 1:
            raise ValueError(f"readings must be >= 1, got {readings}")
        self.estimator, self.thresholds, self.readings = estimator, limits, int(readings)
        self._over: np.ndarray = np.zeros(limits.size, dtype=int)
        self.peak = np.zeros(limits.size)  # N·m, the largest |estimate| per joint since reset

    @classmethod
    def on_model(cls, model: mujoco.MjModel, qpos: Sequence[int], thresholds: Sequence[float],
                 readings: int, gain: float, period: float) -> "ContactStop":
        """A stop on the arm whose joints sit at ``qpos`` of ``model`` (the deploy world's)."""
        return cls(ExternalTorqueEstimator(model, arm_dofs(model, qpos), qpos, gain, period),
                   thresholds, readings)

    @property
    def estimate(self) -> np.ndarray:
        """N·m per joint, the latest estimate (a view)."""
        return self.estimator.estimate

    def reset(self) -> None:
        """A new run, or a run resumed after a stop."""
        self.estimator.reset()
        self._over[:] = 0
        self.peak[:] = 0.0

    def observe(self, position: np.ndarray, velocity: np.ndarray, torque: np.ndarray) -> str | None:
        """Take one feedback frame; the stop reason when it makes a contact, else None."""
        estimate = np.abs(self.estimator.update(position, velocity, torque))
        self.peak = np.maximum(self.peak, estimate)
        over = estimate > self.thresholds
        self._over = np.where(over, self._over + 1, 0)
        hit = np.flatnonzero(self._over >= self.readings)
        if not hit.size:
            return None
        i = int(hit[np.argmax(estimate[hit] / self.thresholds[hit])])
        return (f"contact: joint {i} external torque {estimate[i]:.1f} N·m over its threshold "
                f"{self.thresholds[i]:g} N·m on {self._over[i]} consecutive readings")


class NoContactStop:
    """The contact stop off (``deploy.contact.enabled`` false, or an adapter whose torques are not
    measured with every frame): observes nothing."""

    active = False

    def reset(self) -> None:
        """Nothing to forget."""

    def observe(self, position: np.ndarray, velocity: np.ndarray, torque: np.ndarray) -> str | None:
        return None


def loop_contact_stop(arm, world, contact, robot: str, period: float) -> ContactStop | NoContactStop:
    """The deploy loop's contact stop for ``arm`` on ``world``'s model of ``robot`` (``contact``: the
    ``deploy.contact`` settings, ``period`` s): off when ``contact.enabled`` is false, or when the
    adapter's torques are not measured with every feedback frame (a WARNING says so: an estimate
    from stale torques is wrong as soon as the arm moves)."""
    if not contact.enabled:
        return NoContactStop()
    if not getattr(arm, "torque_every_frame", True):
        logging.getLogger("ahrm_stack.deploy").warning(
            "contact stop off: %s does not measure the torques with every feedback frame", type(arm).__name__)
        return NoContactStop()
    if robot not in contact.threshold_nm:
        raise ValueError(f"deploy.contact.threshold_nm has no entry for {robot!r}")
    return ContactStop.on_model(world.physics.model.ptr, world.arm_qpos, contact.threshold_nm[robot],
                                contact.readings, contact.observer_gain, period)


__all__ = ["ContactStop", "ExternalTorqueEstimator", "NoContactStop", "arm_dofs", "loop_contact_stop"]
