"""Could a dynamics residual at the control rate sense contact? Measured against MuJoCo's own contact torques.

    MUJOCO_GL=egl python studies/contact_residual.py [RUN_DIR] [--episodes N] [--realism NAME ...] [--out DIR]
    python studies/contact_residual.py --render DIR

Issue 58 item 4 asks for a contact stop; studies/contact_torques.py showed that a threshold on the
measured joint torques cannot tell contact from the arm's own motion, and docs/deployment.md named
what might: a residual against a dynamics model. This builds that residual as well as the project
can know it, with the simulator's own model (so the model is exact) and the feedback the deploy
loop has (one reading of position, velocity and torque per 50 ms tick), and compares it with the
truth: the generalised torque of the contacts on the arm's bodies, J^T f from MuJoCo's contact
forces at each tick, low-passed the same way.

The residual (De Luca and Mattone's generalised momentum, in the discrete form of Haddadin, De Luca
and Albu-Schäffer, "Robot collisions: a survey on detection, isolation, and identification", IEEE
T-RO 33(6), 2017): over one period from reading ``k-1`` to ``k`` (joint frame, model signs),

    p_k - p_{k-1} = ∫ (τ + τ_ext - b(q, q̇) + Ṁ q̇) dt,     p = M(q) q̇

with ``τ`` the measured joint torque, ``b`` MuJoCo's bias force (Coriolis, centrifugal, gravity)
minus its passive force, ``M`` the joint-space inertia (armature included). Averaging the
integrand's samples at both ends and folding ``Ṁ q̇`` in, the period's mean external torque is
``e_k = M̄ (q̇_k - q̇_{k-1}) / Δt + (b̄ - τ̄)``, low-passed as ``r_k = r_{k-1} + K Δt (e_k - r_{k-1})``.

Per episode (the ``robustness`` seed family) and joint, ``OUT/rows.csv`` has the largest filtered
contact torque (the truth), and the 95th percentile and the largest error of the residual against
it; ``OUT/table.md`` is rendered from it (``--render``).
"""

from __future__ import annotations

import argparse
import csv
import logging
from pathlib import Path
from typing import Sequence

import mujoco
import numpy as np
from sim_contacts import ArmContacts

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "contact-residual"
GAIN = 10.0  # 1/s, K


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
        n = len(self.dofs)
        self._full = np.zeros((model.nv, model.nv))
        self.estimate = np.zeros(n)
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


def measure(run: str, realism_name: str, episodes: int) -> list[dict]:
    """The residual against the contact torques on ``episodes`` episodes; one row per episode and joint."""
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.deploy.settings import load_deploy_settings
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.hardware.wrapper import ArmWrapper
    from ahrm_stack.realism import realism_profiles
    from ahrm_stack.seeds import seed_table
    from ahrm_stack.sim_arm import SimArm

    logging.disable(logging.WARNING)
    checkpoint = None if run == "scripted" else Path(run)
    config, actor = load_controller_config(checkpoint)
    settings = load_deploy_settings(realtime=False, telemetry="", duration=30.0)
    seeds = [seed_table()["robustness"].seed(i) for i in range(episodes)]
    sim = SimArm(config.task, seed=seeds[0], clock=FastClock(), realism=realism_profiles()[realism_name])
    model, data = sim.physics.model.ptr, sim.physics.data.ptr
    qpos = sim._arm_qpos
    contacts = ArmContacts(model, qpos)
    dofs = contacts.dofs
    estimator = ExternalTorqueEstimator(model, dofs, qpos, GAIN, settings.period)
    effort = model.actuator_forcerange[sim._actuators, 1]  # N·m, each joint's actuator force limit

    class Watched(ArmWrapper):
        def refresh_feedback(self):
            frame = self.arm.refresh_feedback()
            estimates.append(estimator.update(frame.position, frame.velocity, frame.torque).copy())
            torques.append(np.array(frame.torque, dtype=float))
            truths.append(contacts.torque(data)[0])
            return frame

    arm = Watched(sim)
    session = DeploySession.open(arm, config, actor, settings, world_seed=0)
    rows: list[dict] = []
    for seed in seeds:
        session.reset_sim(seed, sim)
        estimator.reset()
        estimates: list[np.ndarray] = []
        truths: list[np.ndarray] = []
        torques: list[np.ndarray] = []
        session.run(settings.duration)
        estimate, truth = np.array(estimates), np.array(truths)
        filtered = np.zeros_like(truth)
        alpha = GAIN * settings.period
        for k in range(1, len(truth)):
            filtered[k] = filtered[k - 1] + alpha * (0.5 * (truth[k] + truth[k - 1]) - filtered[k - 1])
        error = np.abs(estimate - filtered)
        # the measured torque's share of the actuator's force limit, held over 3 consecutive
        # readings (the smallest of each 3): a stall rule's statistic
        share = np.abs(np.array(torques)) / effort
        held = np.min([share[:-2], share[1:-1], share[2:]], axis=0) if len(share) > 2 else share
        for joint in range(len(dofs)):
            rows.append({"run": Path(run).name, "realism": realism_name, "seed": seed,
                         "success": bool(sim.truth.success), "touched": bool(sim.truth.touched),
                         "ticks": len(truth), "joint": joint,
                         "contact_torque_peak_nm": round(float(np.abs(filtered[:, joint]).max()), 2),
                         "error_p95_nm": round(float(np.percentile(error[:, joint], 95)), 2),
                         "error_max_nm": round(float(error[:, joint].max()), 2),
                         "effort_share_held_3_max": round(float(held[:, joint].max()), 3)})
    arm.disconnect()
    return rows


def render(out: Path) -> str:
    """``out/table.md`` from ``out/rows.csv``: per run, realism and joint, over the episodes, the
    median and largest contact-torque peak and the median and largest p95 error (N m)."""
    with open(out / "rows.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["run"], row["realism"], int(row["joint"])), []).append(row)
    lines = ["<!-- generated by `python studies/contact_residual.py --render`; do not edit -->",
             "The dynamics residual at the deploy loop's rate (one reading per 50 ms tick, the simulator's own "
             "model) against MuJoCo's contact torques on the arm (J^T f, low-passed alike), N m, over each "
             "group's episodes (median / largest); last column: episodes in which the joint's measured torque "
             "stayed at its actuator's force limit (>= 99 %) on 3 consecutive readings.", "",
             "| run | realism | joint | episodes | contact torque peak | residual error p95 | residual error max "
             "| torque at its limit on 3 readings |",
             "|---|---|---|---|---|---|---|---|"]
    for (run, realism, joint), group in groups.items():
        peak = [float(r["contact_torque_peak_nm"]) for r in group]
        p95 = [float(r["error_p95_nm"]) for r in group]
        worst = [float(r["error_max_nm"]) for r in group]
        held = [float(r["effort_share_held_3_max"]) >= 0.99 for r in group]
        lines.append(f"| {run} | {realism} | {joint} | {len(group)} | {np.median(peak):.1f} / {max(peak):.1f} | "
                     f"{np.median(p95):.1f} / {max(p95):.1f} | {np.median(worst):.1f} / {max(worst):.1f} | "
                     f"{sum(held)} of {len(group)} |")
    text = "\n".join(lines) + "\n"
    (out / "table.md").write_text(text)
    return text


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python studies/contact_residual.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", nargs="?", default=str(ROOT / "docs" / "policies" / "ahrm-default-seed0"))
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--realism", nargs="+", default=["ideal", "jaco2"])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--render", type=Path, default=None, help="only render DIR/table.md from DIR/rows.csv")
    args = parser.parse_args(argv)
    if args.render is not None:
        print(render(args.render), end="")
        return 0
    rows = [row for name in args.realism for row in measure(args.run, name, args.episodes)]
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "rows.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    print(render(args.out), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
