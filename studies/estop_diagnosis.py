"""Why a robustness run's joint-limit e-stops happen: each one replayed with the physics watched.

    MUJOCO_GL=egl python studies/estop_diagnosis.py RUN_DIR [--robustness DIR] [--out DIR]

Reads ``DIR/robustness.json`` (default ``RUN_DIR/robustness``: ``python -m ahrm_stack.robustness``'s
records), and replays every policy episode that ended in a joint-limit e-stop ("limit violation:
joint i at ...") through the same deploy loop on the sim backend, the same condition and seed (the
sim is deterministic: the replay must end with the same stop, which is checked). At every control
tick it records, for the joint that was stopped: its true position and speed, the filtered command
the arm was sent, the actuator's force against its force range (the URDF effort), and the
generalised torque of the contacts on the arm's bodies (MuJoCo's J^T f, each contact force from
``mj_contactForce``) with the bodies in contact. ``OUT/estops.csv`` (one row per e-stop) and
``OUT/estops.md`` (generated from it) say, from the moment the joint passed the filter's bound
(its limit minus ``safety.position_margin``): how long until the stop, the largest command and
speed, the share of ticks with the actuator at its force limit, the largest contact torque, and
what the arm touched. A second table, ``OUT/actuators.md``, gives per arm and joint the
acceleration the model's actuator can give at the arm's home posture, (effort - |gravity|) / M_ii
(rad/s^2), beside the filter's ``acceleration_limit``.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import re
import sys
from pathlib import Path

import numpy as np
from sim_contacts import ArmContacts

LIMIT = re.compile(r"limit violation: joint (\d+) at ")


def replay(run: Path, condition: str, seed: int, duration: float, profile: str) -> dict:
    """One episode replayed; a row of the table."""
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.deploy.settings import load_deploy_settings
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.robustness import conditions
    from ahrm_stack.sim_arm import SimArm

    realism = {c.name: c.realism for c in conditions(profile, dose=False)}[condition]
    config, actor = load_controller_config(run)
    settings = load_deploy_settings(realtime=False, telemetry="", duration=duration)
    arm = SimArm(config.task, seed=seed, clock=FastClock(), realism=realism)
    session = DeploySession.open(arm, config, actor, settings, world_seed=0)
    model, data = arm.physics.model.ptr, arm.physics.data.ptr
    qpos, actuators = arm._arm_qpos, arm._actuators
    contacts = ArmContacts(model, qpos)
    dofs = contacts.dofs
    effort = model.actuator_forcerange[actuators, 1]
    ticks: list[tuple] = []
    send = arm._send

    def recording(command):
        torque, touching = contacts.torque(data)
        ticks.append((float(data.time), np.array(command, dtype=float), data.qpos[qpos].copy(),
                      data.qvel[dofs].copy(), data.actuator_force[actuators].copy(), torque, touching))
        return send(command)

    arm._send = recording
    logging.disable(logging.WARNING)
    session.reset_sim(seed)
    summary, _ = session.run(settings.duration)
    arm.disconnect()
    match = LIMIT.match(summary.stop_reason)
    row: dict = {"condition": condition, "seed": seed, "stop_reason": summary.stop_reason}
    if match is None:
        return row
    joint = int(match.group(1))
    limit_low, limit_high = arm._lower[joint], arm._upper[joint]
    margin = float(config.safety.position_margin)
    position = np.array([t[2][joint] for t in ticks])
    side = 1.0 if abs(position[-1] - limit_high) < abs(position[-1] - limit_low) else -1.0
    bound = (limit_high - margin) if side > 0 else (limit_low + margin)
    past = np.flatnonzero(side * (position - bound) > 0)
    first = int(past[0]) if past.size else len(ticks) - 1
    window = ticks[first:]
    command = np.array([t[1][joint] for t in window])
    speed = np.array([t[3][joint] for t in window])
    actuator = np.array([t[4][joint] for t in window])
    contact = np.array([t[5][joint] for t in window])
    touched = sorted(set().union(*(t[6] for t in window)) - {"world"})
    row.update({
        "joint": joint, "limit_rad": round(float(side * max(abs(limit_low), abs(limit_high))), 4),
        "filter_bound_rad": round(float(bound), 4),
        "ticks_past_bound": len(window),
        "max_command_toward_limit_rad_s": round(float(max(0.0, (side * command).max())), 3),
        "max_speed_toward_limit_rad_s": round(float((side * speed).max()), 3),
        "actuator_at_limit_share": round(float(np.mean(np.abs(actuator) >= 0.99 * effort[joint])), 3),
        "actuator_against_motion_share": round(float(np.mean(side * actuator < 0)), 3),
        "max_contact_torque_toward_limit_nm": round(float((side * contact).max()), 2),
        "effort_nm": round(float(effort[joint]), 2),
        "touching": " ".join(touched),
    })
    return row


def actuator_rows() -> list[dict]:
    """Per arm and commanded joint: the model actuator's acceleration at home against the filter's."""
    import mujoco

    from ahrm_stack.config import arm_names, load_config
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    rows = []
    for name in arm_names():
        config = load_config(overrides=[f"task.robot={name}"])
        arm = SimArm(config.task, seed=0, clock=FastClock())
        model, data = arm.physics.model.ptr, arm.physics.data.ptr
        mujoco.mj_forward(model, data)
        inertia = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, inertia)
        qpos = arm._arm_qpos
        dofs = [int(model.jnt_dofadr[j]) for j in range(model.njnt) if model.jnt_qposadr[j] in set(qpos.tolist())]
        effort = model.actuator_forcerange[arm._actuators, 1]
        gravity = data.qfrc_bias[dofs]
        limit = config.safety.acceleration_limit
        for i, dof in enumerate(dofs):
            capable = (effort[i] - abs(gravity[i])) / inertia[dof, dof]
            rows.append({"arm": name, "joint": i, "effort_nm": round(float(effort[i]), 2),
                         "inertia_kg_m2": round(float(inertia[dof, dof]), 3),
                         "gravity_at_home_nm": round(float(gravity[i]), 2),
                         "actuator_acceleration_rad_s2": round(float(capable), 2),
                         "filter_acceleration_limit_rad_s2": float(limit[i])})
        arm.disconnect() if arm.is_connected else None
    return rows


COLUMNS = ["condition", "seed", "joint", "limit_rad", "filter_bound_rad", "ticks_past_bound",
           "max_command_toward_limit_rad_s", "max_speed_toward_limit_rad_s", "actuator_at_limit_share",
           "actuator_against_motion_share", "max_contact_torque_toward_limit_nm", "effort_nm", "touching",
           "replayed_same_stop"]


def write_tables(out: Path, run: Path | str) -> str:
    """``out/estops.md`` from ``out/estops.csv`` and ``out/actuators.csv`` (nothing typed)."""
    with open(out / "estops.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    with open(out / "actuators.csv", newline="") as handle:
        actuators = list(csv.DictReader(handle))
    note = ("<!-- generated by `python studies/estop_diagnosis.py`; do not edit -->\n"
            f"Joint-limit e-stops of `{run}`'s robustness records replayed (sim backend, same condition and "
            "seed); from the tick the joint passed the filter's bound (limit - safety.position_margin) to the "
            "stop. Speeds and commands toward the limit (rad/s), torques toward it (N m; contact torque: MuJoCo's "
            "J^T f of the contacts on the arm's bodies).")
    text = _markdown(rows, COLUMNS, note) + "\n" + _markdown(
        actuators, list(actuators[0]),
        "Per arm and joint: the acceleration the model's actuator can give at the home posture, "
        "(effort - |gravity|) / M_ii, beside the safety filter's acceleration limit.")
    (out / "estops.md").write_text(text)
    return text


def _markdown(rows: list[dict], columns: list[str], header: str) -> str:
    lines = [header, "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python studies/estop_diagnosis.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--robustness", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    folder = args.robustness or args.run / "robustness"
    source = folder / "robustness.json"
    if not source.is_file():
        print(f"{source}: no robustness records (run python -m ahrm_stack.robustness {args.run} first)",
              file=sys.stderr)
        return 2
    data = json.loads(source.read_text())
    out = args.out or folder
    stops = [r for r in data["records"] if r["controller"] == "policy" and LIMIT.match(r["stop_reason"] or "")]
    rows = []
    for record in stops:
        row = replay(args.run, record["condition"], int(record["seed"]), float(data["duration"]), data["profile"])
        row["replayed_same_stop"] = row["stop_reason"] == record["stop_reason"]
        rows.append(row)
        print(row, flush=True)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "estops.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS + ["stop_reason"], lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    actuators = actuator_rows()
    with open(out / "actuators.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(actuators[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(actuators)
    write_tables(out, args.run)
    print((out / "estops.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
