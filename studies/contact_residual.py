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

Per episode (the ``robustness`` seed family) and joint, ``OUT/rows.csv.gz`` has the largest filtered
contact torque (the truth), and the 95th percentile and the largest error of the residual against
it; ``OUT/table.md`` is rendered from it (``--render``).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import gzip
import logging
from pathlib import Path
from typing import Sequence

import numpy as np
from sim_contacts import ArmContacts

from ahrm_stack.deploy.contact import ExternalTorqueEstimator

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "contact-residual"
ROWS = "rows.csv.gz"


def measure(run: str, realism_name: str, episodes: int, overrides: Sequence[str] = (), realism=None) -> list[dict]:
    """The residual against the contact torques on ``episodes`` episodes; one row per episode and joint.
    ``realism``: the imperfections (a RealismConfig; default the named set ``realism_name``)."""
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
    config, actor = load_controller_config(checkpoint, overrides)
    settings = load_deploy_settings(realtime=False, telemetry="", duration=30.0)
    gain = settings.contact.observer_gain  # 1/s, K: deploy's (configs/deploy.yaml)
    # the loop's own contact stop off: these rows measure the estimate over whole runs
    settings = dataclasses.replace(settings, contact=dataclasses.replace(settings.contact, enabled=False))
    seeds = [seed_table()["robustness"].seed(i) for i in range(episodes)]
    sim = SimArm(config.task, seed=seeds[0], clock=FastClock(), realism=realism or realism_profiles()[realism_name])
    model, data = sim.physics.model.ptr, sim.physics.data.ptr
    qpos = sim._arm_qpos
    contacts = ArmContacts(model, qpos)
    dofs = contacts.dofs
    estimator = ExternalTorqueEstimator(model, dofs, qpos, gain, settings.period)
    effort = model.actuator_forcerange[sim._actuators, 1]  # N·m, each joint's actuator force limit

    class Watched(ArmWrapper):
        def refresh_feedback(self):
            frame = self.arm.refresh_feedback()
            estimates.append(estimator.update(frame.position, frame.velocity, frame.torque).copy())
            torques.append(np.array(frame.torque, dtype=float))
            truth, touching = contacts.torque(data)
            truths.append(truth)
            touched_by_arm.update(touching)
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
        touched_by_arm: set[str] = set()
        session.run(settings.duration)
        estimate, truth = np.array(estimates), np.array(truths)
        filtered = np.zeros_like(truth)
        alpha = gain * settings.period
        for k in range(1, len(truth)):
            filtered[k] = filtered[k - 1] + alpha * (0.5 * (truth[k] + truth[k - 1]) - filtered[k - 1])
        error = np.abs(estimate - filtered)
        # the measured torque's share of the actuator's force limit, held over 3 consecutive
        # readings (the smallest of each 3): a stall rule's statistic
        share = np.abs(np.array(torques)) / effort
        held = np.min([share[:-2], share[1:-1], share[2:]], axis=0) if len(share) > 2 else share
        magnitude = np.abs(estimate)
        held2 = np.minimum(magnitude[1:], magnitude[:-1]) if len(magnitude) > 1 else magnitude
        for joint in range(len(dofs)):
            name = Path(run).name + "".join(f" {o}" for o in overrides)
            rows.append({"run": name, "robot": config.task.robot, "realism": realism_name, "seed": seed,
                         "success": bool(sim.truth.success), "touched": bool(sim.truth.touched),
                         "ticks": len(truth), "joint": joint,
                         "contact_torque_peak_nm": round(float(np.abs(filtered[:, joint]).max()), 2),
                         "error_p95_nm": round(float(np.percentile(error[:, joint], 95)), 2),
                         "error_max_nm": round(float(error[:, joint].max()), 2),
                         # the estimate itself (what a threshold sees) and what the arm touched
                         "estimate_max_nm": round(float(np.abs(estimate[:, joint]).max()), 2),
                         # ... held on 2 consecutive readings (the smaller of each pair): what deploy's
                         # contact stop with contact.readings = 2 compares with a threshold
                         "estimate_held2_max_nm": round(float(held2[:, joint].max()), 2),
                         "arm_touched": " ".join(sorted(touched_by_arm)),
                         "effort_share_held_3_max": round(float(held[:, joint].max()), 3)})
    arm.disconnect()
    return rows


def _read_rows(out: Path) -> list[dict]:
    with gzip.open(out / ROWS, "rt", newline="") as handle:
        return list(csv.DictReader(handle))


def render(out: Path) -> str:
    """``out/table.md`` from ``out/rows.csv.gz``: per run and joint, over every episode of every
    condition, the median and largest contact-torque peak, p95 error and estimate held on 2
    readings (N m), and the condition of the largest estimate."""
    rows = _read_rows(out)
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["run"], row["robot"], int(row["joint"])), []).append(row)
    lines = ["<!-- generated by `python studies/contact_residual.py --render`; do not edit -->",
             "The dynamics residual at the deploy loop's rate (one reading per 50 ms tick, the simulator's own "
             "model) against MuJoCo's contact torques on the arm (J^T f, low-passed alike), N m, over each "
             "group's episodes: every condition of the robustness evaluation (ideal, each jaco2 imperfection "
             "alone, all of jaco2, the dose rows), 12 robustness episodes each (median / largest). 'estimate "
             "held 2': the largest |estimate| held on 2 consecutive readings, what deploy's contact stop compares "
             "with each arm's contact_threshold_nm (configs/robots/: 1.25 x the largest of these over the arm's "
             "rows, rounded up); last column: episodes in which the joint's measured torque stayed at its "
             "actuator's force limit (>= 99 %) on 3 consecutive readings.", "",
             "| run | robot | joint | episodes | contact torque peak | residual error p95 | estimate held 2 "
             "| its largest under | torque at its limit on 3 readings |",
             "|---|---|---|---|---|---|---|---|---|"]
    for (run, robot, joint), group in groups.items():
        peak = [float(r["contact_torque_peak_nm"]) for r in group]
        p95 = [float(r["error_p95_nm"]) for r in group]
        estimate = [float(r["estimate_held2_max_nm"]) for r in group]
        worst = group[int(np.argmax(estimate))]["realism"]
        held = [float(r["effort_share_held_3_max"]) >= 0.99 for r in group]
        lines.append(f"| {run} | {robot} | {joint} | {len(group)} | {np.median(peak):.1f} / {max(peak):.1f} | "
                     f"{np.median(p95):.1f} / {max(p95):.1f} | {np.median(estimate):.1f} / {max(estimate):.1f} | "
                     f"{worst} | {sum(held)} of {len(group)} |")
    text = "\n".join(lines) + "\n"
    (out / "table.md").write_text(text)
    return text


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python studies/contact_residual.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", nargs="?", default=str(ROOT / "docs" / "policies" / "ahrm-default-seed0"))
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--realism", nargs="+", default=["ideal", "jaco2"])
    parser.add_argument("--conditions", default=None, metavar="PROFILE",
                        help="instead of --realism: every condition of the robustness evaluation of PROFILE "
                             "(ideal, each imperfection alone, all, the dose rows)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--override", nargs="*", default=[],
                        help="KEY=VALUE for the scripted run (e.g. task.robot=j2s6s200)")
    parser.add_argument("--render", type=Path, default=None, help="only render DIR/table.md from DIR/rows.csv.gz")
    args = parser.parse_args(argv)
    if args.render is not None:
        print(render(args.render), end="")
        return 0
    if args.conditions:
        from ahrm_stack.robustness import conditions

        chosen = [(c.name, c.realism) for c in conditions(args.conditions, dose=True)]
    else:
        chosen = [(name, None) for name in args.realism]
    rows = [row for name, realism in chosen
            for row in measure(args.run, name, args.episodes, args.override, realism)]
    args.out.mkdir(parents=True, exist_ok=True)
    with gzip.open(args.out / ROWS, "wt", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    print(render(args.out), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
