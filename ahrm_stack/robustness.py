"""The robustness evaluation: a run's policy and the scripted controller through the deploy loop
on the sim backend with a real arm's imperfections, one at a time and all together.

    python -m ahrm_stack.robustness RUN_DIR [--episodes 30] [--profile jaco2] [--no-dose]
                                    [--workers 2] [--out DIR]
    python -m ahrm_stack.robustness --render DIR     # robustness.md again from DIR/robustness.json

Each condition is a :class:`~ahrm_stack.realism.RealismConfig`: ``ideal``; each group of
:data:`~ahrm_stack.realism.GROUPS` alone at the profile's values (``configs/realism.yaml``,
default ``jaco2``); the whole profile (``all``); and the dose-response rows of the file's ``dose``
(one level of joint-velocity or joint-angle noise alone). Every condition runs the same episodes
(``configs/seeds.yaml`` range ``robustness``: layout, start and the imperfections' noise are
seeded by the episode) for both controllers, through the same :class:`~ahrm_stack.deploy.loop.
DeployLoop` that drives a real arm (the checkpoint's safety settings merged as deploy merges
them, ``configs/deploy.yaml``'s loop and watchdogs).

An episode counts by what happened in the simulator (:attr:`ahrm_stack.sim_arm.SimArm.truth`): success
when the cube left the table, touching when the arm or the cube touched an obstacle, time from the
loop's start to the success. The loop's own judgement (from perception) is recorded beside it, so
that a judged success the simulator contradicts shows. Writes ``robustness.json`` (every episode)
and ``robustness.md`` (the table, generated from the json) to ``--out`` (default
``RUN_DIR/robustness``) and prints the table.
"""

from __future__ import annotations

import dataclasses
import json
import math
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from ahrm_stack.cli import Parser
from ahrm_stack.realism import GROUPS, REALISM_FILE, RealismConfig, realism_profiles
from ahrm_stack.schema import ConfigError, read_yaml

CONTROLLERS = ("policy", "scripted")


@dataclasses.dataclass(frozen=True)
class Condition:
    name: str
    realism: RealismConfig
    kind: str  # "single" (a group alone, ideal, all) or "dose"


def conditions(profile: str = "jaco2", dose: bool = True, path: Path | str = REALISM_FILE) -> list[Condition]:
    """The evaluation's rows: ideal, each group of ``profile`` alone, all of it, then (``dose``) the
    file's dose-response levels."""
    profiles = realism_profiles(path)
    if profile not in profiles:
        raise ConfigError(f"--profile {profile!r}: no such set in {path}; choose one of {sorted(profiles)}")
    chosen = profiles[profile]
    rows = [Condition("ideal", RealismConfig.ideal(), "single")]
    rows += [Condition(group, chosen.only(group), "single") for group in GROUPS]
    rows.append(Condition(f"all ({profile})", chosen, "single"))
    if dose:
        levels = read_yaml(path).get("dose", {}) or {}
        units = {"velocity_noise_deg_s": "°/s", "angle_noise_deg": "°"}
        for key, values in levels.items():
            if key not in units:
                raise ConfigError(f"{path}: dose.{key}: not a dose-response quantity; choose one of {sorted(units)}")
            for value in values:
                changes: dict[str, Any] = {key: float(value)}
                realism = dataclasses.replace(RealismConfig.ideal(), **changes)
                RealismConfig.from_dict(realism.to_dict(), f"dose.{key}", str(path))  # its rules
                label = "velocity noise" if key.startswith("velocity") else "angle noise"
                rows.append(Condition(f"{label} {value:g}{units[key]}", realism, "dose"))
    return rows


def _episodes(job: tuple[str | None, str, dict, list[int], float]) -> list[dict[str, Any]]:
    """Worker: one controller under one condition on the given seeds; one record per episode."""
    checkpoint, controller_name, realism_data, seeds, duration = job
    import logging

    import numpy as np

    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.deploy.settings import load_deploy_settings
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    logging.disable(logging.WARNING)  # thousands of stops: the records say how each run ended
    config, actor = load_controller_config(None if checkpoint is None else Path(checkpoint))
    settings = load_deploy_settings(realtime=False, telemetry="", duration=duration)
    realism = RealismConfig.from_dict(realism_data, "realism")
    arm = SimArm(config.task, seed=seeds[0], clock=FastClock(), realism=realism)
    session = DeploySession.open(arm, config, actor if controller_name == "policy" else None, settings,
                                 world_seed=0)
    records = []
    for seed in seeds:
        session.reset_sim(seed)
        start = float(arm.physics.data.time)
        summary, fault = session.run(settings.duration)
        truth = arm.truth
        records.append({
            "seed": seed, "controller": controller_name,
            "success": bool(truth.success), "touched": bool(truth.touched),
            "time": None if truth.success_time is None else round(truth.success_time - start, 4),
            "judged_success": bool(summary.success),
            "judged_touched": bool(getattr(summary, "touched", False)),
            "stop_reason": summary.stop_reason, "fault": fault,
            "emergency_stops": int(summary.emergency_stops), "ticks": int(summary.ticks),
            "cube_final": [round(float(v), 4) for v in np.asarray(truth.cube_position)],
        })
    arm.disconnect()
    return records


@dataclasses.dataclass
class Row:
    """One controller under one condition."""

    episodes: int
    successes: int
    touching: int
    mean_time: float  # s over the successful episodes (nan without one)
    judged_wrong: int  # episodes whose judged success the simulator contradicts
    emergency_stops: int

    @classmethod
    def of(cls, records: list[dict[str, Any]]) -> "Row":
        times = [r["time"] for r in records if r["success"] and r["time"] is not None]
        return cls(len(records), sum(r["success"] for r in records), sum(r["touched"] for r in records),
                   sum(times) / len(times) if times else math.nan,
                   sum(r["judged_success"] != r["success"] for r in records),
                   sum(r["emergency_stops"] > 0 for r in records))


def paired_times(policy: list[dict[str, Any]], scripted: list[dict[str, Any]]) -> tuple[float, float, int]:
    """(policy's, scripted controller's mean s to success, episodes) over the episodes (seeds)
    both controllers won: the time comparison on the same episodes (nan, nan, 0 without one)."""
    theirs = {r["seed"]: r["time"] for r in scripted if r["success"] and r["time"] is not None}
    pairs = [(r["time"], theirs[r["seed"]]) for r in policy
             if r["success"] and r["time"] is not None and r["seed"] in theirs]
    if not pairs:
        return math.nan, math.nan, 0
    return (sum(p for p, _ in pairs) / len(pairs), sum(s for _, s in pairs) / len(pairs), len(pairs))


def meets_goal(policy: list[dict[str, Any]], scripted: list[dict[str, Any]]) -> bool:
    """Issue 40's per-condition goal on one condition's records of both controllers: success >=
    the scripted controller's - 1 per 30 episodes, touching <= 1 per 30, and the mean time to
    success <= the scripted controller's on the episodes both won (:func:`paired_times`)."""
    mine, theirs = Row.of(policy), Row.of(scripted)
    slack = mine.episodes / 30.0
    p_time, s_time, common = paired_times(policy, scripted)
    time_ok = common == 0 or p_time <= s_time
    return mine.successes >= theirs.successes - slack and mine.touching <= slack and time_ok


def table(data: dict[str, Any]) -> str:
    """The markdown table of a ``robustness.json``'s records."""
    lines = [f"Robustness of `{data['run']}` through the deploy loop (sim backend, `{data['profile']}` "
             f"imperfections; {data['episodes']} episodes per cell, seeds `robustness` "
             f"{data['seeds'][0]}–{data['seeds'][-1]}, the same for both controllers; counted in the "
             "simulator; time: mean s to success over each controller's successes; paired time: "
             "policy / scripted mean s over the episodes both won (n), which the goal compares; judged "
             "wrong: the loop's own success verdict contradicted by the simulator; goal: success ≥ "
             "the scripted controller's − 1, touching ≤ 1 (per 30), paired time ≤ the scripted "
             "controller's).",
             "",
             "| condition | policy: success | touching | time (s) | judged wrong | e-stops | scripted: success "
             "| touching | time (s) | judged wrong | paired time (s) | goal |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in data["conditions"]:
        records = {c: [r for r in data["records"] if r["condition"] == name and r["controller"] == c]
                   for c in CONTROLLERS}
        p, s = Row.of(records["policy"]), Row.of(records["scripted"])
        if not p.episodes:
            continue
        cells = [name]
        for row in (p, s):
            cells += [f"{row.successes}/{row.episodes}", str(row.touching),
                      "–" if math.isnan(row.mean_time) else f"{row.mean_time:.2f}", str(row.judged_wrong)]
            if row is p:
                cells.append(str(row.emergency_stops))
        p_time, s_time, common = paired_times(records["policy"], records["scripted"])
        cells.append("–" if not common else f"{p_time:.2f} / {s_time:.2f} ({common})")
        cells.append("met" if meets_goal(records["policy"], records["scripted"]) else "**missed**")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def evaluate(checkpoint: Path, episodes: int, profile: str, dose: bool, workers: int,
             duration: float, out: Path) -> dict[str, Any]:
    from ahrm_stack.seeds import seed_table

    rows = conditions(profile, dose)
    seeds = [seed_table()["robustness"].seed(i) for i in range(episodes)]
    jobs = [(str(checkpoint), controller, row.realism.to_dict(), seeds, duration)
            for row in rows for controller in CONTROLLERS]
    started = time.time()
    if workers > 1:
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            results = pool.map(_episodes, jobs, chunksize=1)
    else:
        results = [_episodes(job) for job in jobs]
    records = []
    for (row, _), result in zip([(r, c) for r in rows for c in CONTROLLERS], results):
        for record in result:
            records.append({"condition": row.name, "kind": row.kind, **record})
    data = {"run": str(checkpoint), "profile": profile, "episodes": episodes, "seeds": seeds,
            "duration": duration, "conditions": [r.name for r in rows],
            "realism": {r.name: r.realism.to_dict() for r in rows},
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "wall_s": round(time.time() - started, 1), "records": records}
    out.mkdir(parents=True, exist_ok=True)
    (out / "robustness.json").write_text(json.dumps(data, indent=1) + "\n")
    (out / "robustness.md").write_text(table(data))
    return data


def render(folder: Path, prog: str = "python -m ahrm_stack.robustness") -> int:
    """``folder/robustness.md`` from ``folder/robustness.json`` (the docs' tables are made so)."""
    source = folder / "robustness.json"
    try:
        data = json.loads(source.read_text())
        text = table(data)
    except (OSError, ValueError, KeyError, TypeError) as error:
        print(f"{prog}: error: {source}: {type(error).__name__}: {error}", file=sys.stderr)
        return 2
    (folder / "robustness.md").write_text(text)
    print(text)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m ahrm_stack.robustness", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, nargs="?", help="a training run folder (config.yaml, policy.pt)")
    parser.add_argument("--render", type=Path, metavar="DIR", help="write DIR/robustness.md from "
                        "DIR/robustness.json and print it (no episode is run)")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--profile", default="jaco2", help="a set of configs/realism.yaml")
    parser.add_argument("--no-dose", dest="dose", action="store_false", help="skip the dose-response rows")
    parser.add_argument("--workers", type=int, default=2, help="processes (each runs whole conditions)")
    parser.add_argument("--duration", type=float, default=30.0, help="s per episode (the loop stops then)")
    parser.add_argument("--out", type=Path, help="folder for robustness.json / .md (default RUN_DIR/robustness)")
    args = parser.parse_args(argv)
    prog = parser.prog
    if args.render is not None:
        return render(args.render, prog)
    if args.run_dir is None:
        print(f"{prog}: error: give a run folder (or --render DIR)", file=sys.stderr)
        return 2
    if args.episodes < 1 or args.workers < 1 or not args.duration > 0:
        print(f"{prog}: error: --episodes and --workers must be >= 1 and --duration > 0", file=sys.stderr)
        return 2
    for name in ("config.yaml", "policy.pt"):
        if not (args.run_dir / name).is_file():
            print(f"{prog}: error: {args.run_dir}: no {name} (a training run folder)", file=sys.stderr)
            return 2
    try:
        conditions(args.profile, args.dose)  # bad input: one line, nothing written
        from ahrm_stack.deploy.run import load_controller_config

        load_controller_config(args.run_dir)
        data = evaluate(args.run_dir, args.episodes, args.profile, args.dose, args.workers, args.duration,
                        args.out or args.run_dir / "robustness")
    except (ConfigError, ValueError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    print(table(data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
