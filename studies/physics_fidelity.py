"""A physics configuration against the reference physics on the same commands (issue 55).

    python studies/physics_fidelity.py run NAME [--episodes 40] [--out docs/physics-fidelity/data]
    python studies/physics_fidelity.py report [--data docs/physics-fidelity/data] [--write docs/physics-fidelity.md]

``run NAME`` measures one variant of :data:`VARIANTS` (a list of config overrides on ``configs/``),
in four parts, every one on validation or study seeds (never the test split):

1. **the scripted controller on every suite family** (``configs/layouts.yaml``, ``suite: true``):
   ``--episodes`` validation episodes per family, closed loop through the safety filter, as
   ``python -m ahrm_stack.evaluate --policy scripted --suite`` drives it; per episode its success,
   touching, time, and the cube's path (its centre, m, world frame, once per control step);
2. **obstacles at rest**: the random layouts of the validation ``random`` family with the arm
   holding still (zero joint-velocity requests through the filter) for ``REST_SECONDS``: each
   obstacle's largest displacement from its position after the reset's settling, and the largest
   obstacle speed, against the touch test's threshold (``task.rewards.obstacle_speed_threshold``);
3. **touch detection**: the pusher driven at ``PROBE_SPEED`` toward an obstacle's side (a Cartesian
   request through the filter, whose obstacle rows are off in training), until the task reports a
   touch: the control step of the first touch and the tip's distance to the obstacle's face then;
4. the wall time of each part (a noisy figure: ``benchmarks/`` measures speed).

Writes ``OUT/NAME.json.gz``. ``report`` reads every variant's file and writes the comparison with
:data:`REFERENCE` (per family: successes, touching, mean time and the time ratio on episodes both
won; the cube's path: the largest distance between the two paths of an episode both won, and the
cube's exit point; obstacles at rest; touch steps) and the fidelity goal of issue 55 (per family
successes within one episode per 40 of the reference's, touching no higher, time within 5 %).
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

REFERENCE = "reference"
CONTROL = "2ms-implicitfast"
VARIANTS: dict[str, list[str]] = {
    # the physics of every run before 2026-12-06 (schema_version 1's defaults)
    REFERENCE: ["task.episode.physics_timestep=0.002", "task.episode.noslip_iterations=5",
                "task.episode.integrator=euler", "task.episode.sleep=false"],
    "5ms-euler": ["task.episode.physics_timestep=0.005", "task.episode.noslip_iterations=0",
                  "task.episode.integrator=euler", "task.episode.sleep=false"],
    "5ms-implicitfast": ["task.episode.physics_timestep=0.005", "task.episode.noslip_iterations=0",
                         "task.episode.integrator=implicitfast", "task.episode.sleep=false"],
    "5ms-implicitfast-noslip5": ["task.episode.physics_timestep=0.005", "task.episode.noslip_iterations=5",
                                 "task.episode.integrator=implicitfast", "task.episode.sleep=false"],
    # a control: the reference's timestep and noslip with the other integrator, to see how many
    # episodes a family flips under a change that should not matter
    "2ms-implicitfast": ["task.episode.physics_timestep=0.002", "task.episode.noslip_iterations=5",
                         "task.episode.integrator=implicitfast", "task.episode.sleep=false"],
    "2.5ms-implicitfast": ["task.episode.physics_timestep=0.0025", "task.episode.noslip_iterations=0",
                           "task.episode.integrator=implicitfast", "task.episode.sleep=false"],
    "5ms-implicitfast-impratio10": ["task.episode.physics_timestep=0.005", "task.episode.noslip_iterations=0",
                                    "task.episode.integrator=implicitfast", "task.episode.sleep=false",
                                    "task.episode.impratio=10"],
    "5ms-implicitfast-sleep": ["task.episode.physics_timestep=0.005", "task.episode.noslip_iterations=0",
                               "task.episode.integrator=implicitfast", "task.episode.sleep=true"],
}
REST_LAYOUTS = 40  # random layouts held at rest
REST_SECONDS = 5.0  # s of simulated time per layout
PROBE_LAYOUTS = 40  # touch probes
PROBE_SPEED = 0.1  # m/s, the pusher tip toward the obstacle
PROBE_SECONDS = 6.0
PATH_STRIDE = 1  # control steps between recorded cube positions


def _suite(overrides: list[str], episodes: int) -> dict:
    from ahrm_stack.env.episode_loop import scripted_episode
    from ahrm_stack.env.layout_catalog import suite_names
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.evaluation import evaluation_configs
    from ahrm_stack.seeds import evaluation_range

    out = {}
    for family in suite_names():
        config, _, _ = evaluation_configs(None, overrides, family)
        start = evaluation_range(family, "validation").start
        task = PushOffTask(config.task)
        runner = TaskRunner(task, seed=start, safety=config.safety)
        controller = ScriptedPusher(task, config.scripted)
        rows = []
        t0 = time.perf_counter()
        for i in range(episodes):
            path, touched, steps, success = [], False, 0, False
            for step in scripted_episode(runner, controller, start + i):
                if step.sent is not None:
                    steps += 1
                    touched |= bool(step.info.touched)
                    success = bool(step.terminated)
                if steps % PATH_STRIDE == 0:
                    path.append([round(float(v), 5) for v in step.info.target[:2]])
            rows.append({"seed": start + i, "success": success, "touched": touched, "steps": steps,
                         "time": steps * config.task.episode.control_period if success else None,
                         "path": path})
        out[family] = {"episodes": rows, "wall_s": time.perf_counter() - t0}
        print(f"{family}: {sum(r['success'] for r in rows)}/{episodes} won, "
              f"{sum(r['touched'] for r in rows)} touching, {out[family]['wall_s']:.1f} s", flush=True)
    return out


def _obstacle_positions(task, physics) -> np.ndarray:
    return np.array([physics.bind(o.geom).xpos.copy() for o in task.obstacles])


def _rest(overrides: list[str]) -> dict:
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.evaluation import evaluation_configs
    from ahrm_stack.seeds import evaluation_range

    config, _, _ = evaluation_configs(None, overrides, "random")
    start = evaluation_range("random", "validation").start
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=start, safety=config.safety)
    steps = int(round(REST_SECONDS / config.task.episode.control_period))
    rows = []
    for i in range(REST_LAYOUTS):
        runner.seed(start + i)
        runner.reset()
        physics = runner.physics
        first = _obstacle_positions(task, physics)
        largest_move, largest_speed, touched_steps = 0.0, 0.0, 0
        zero = np.zeros(task.robot.num_joints)
        for _ in range(steps):
            info, _, _ = runner.step_only(zero)
            now = _obstacle_positions(task, physics)
            largest_move = max(largest_move, float(np.linalg.norm(now - first, axis=1).max()))
            speeds = [float(np.linalg.norm(o.get_velocity(physics)[0])) for o in task.obstacles]
            largest_speed = max(largest_speed, max(speeds))
            touched_steps += bool(info.touched)
        rows.append({"seed": start + i, "largest_move_m": largest_move, "largest_speed_mps": largest_speed,
                     "touched_steps": touched_steps})
    return {"rows": rows, "threshold_mps": config.task.rewards.obstacle_speed_threshold}


def _probe(overrides: list[str]) -> dict:
    """The pusher's tip driven horizontally at the side of the obstacle nearest to its start."""
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.evaluation import evaluation_configs
    from ahrm_stack.seeds import evaluation_range

    config, _, _ = evaluation_configs(None, [*overrides, "task.arm.start=home"], "random")
    start = evaluation_range("random", "validation").start
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=start, safety=config.safety)
    steps = int(round(PROBE_SECONDS / config.task.episode.control_period))
    top = config.task.table.height
    half = np.asarray(config.task.obstacles.size) / 2
    rows = []
    for i in range(PROBE_LAYOUTS):
        runner.seed(start + i)
        transition = runner.reset()
        physics = runner.physics
        obstacles = _obstacle_positions(task, physics)
        tip = transition.info.tip
        target_index = int(np.argmin(np.linalg.norm(obstacles[:, :2] - tip[:2], axis=1)))
        centre = obstacles[target_index]
        first, distance = None, None
        for k in range(steps):
            tip = task.step_info.tip
            aim = np.array([centre[0], centre[1], top + 0.6 * config.task.obstacles.size[2]])
            if np.linalg.norm(tip[:2] - centre[:2]) > 0.15:  # first above the obstacle's height
                aim[:2] = tip[:2] + 0.5 * (centre[:2] - tip[:2])
                aim[2] = top + 0.2
            direction = aim - tip
            request = PROBE_SPEED * direction / max(float(np.linalg.norm(direction)), 1e-9)
            info, _, _ = runner.step_cartesian(request)
            if info.touched:
                first = k + 1
                local = np.abs(info.tip - _obstacle_positions(task, physics)[target_index])
                distance = float(np.max(local - half))
                break
        rows.append({"seed": start + i, "first_touch_step": first, "tip_gap_at_touch_m": distance})
    return {"rows": rows}


def run(name: str, episodes: int, out: Path) -> None:
    from ahrm_stack.config import load_config

    if name not in VARIANTS:
        sys.exit(f"unknown variant {name!r}; variants: {list(VARIANTS)}")
    overrides = VARIANTS[name]
    load_config(overrides)  # a bad override fails here, before anything runs
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = {"variant": name, "overrides": overrides, "episodes": episodes}
    data["suite"] = _suite(overrides, episodes)
    data["rest"] = _rest(overrides)
    data["probe"] = _probe(overrides)
    data["wall_s"] = time.perf_counter() - t0
    with gzip.open(out / f"{name}.json.gz", "wt") as handle:
        json.dump(data, handle)
    print(f"written: {out / f'{name}.json.gz'} ({data['wall_s']:.0f} s)")


def _path_gap(a: list, b: list) -> float:
    """The largest distance (m) from a point of one path to the nearest point of the other (the
    symmetric Hausdorff distance of the two polylines' vertices)."""
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    d = np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=2)
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


def _time_ratio(pairs: list) -> float:
    """Mean time of the variant over mean time of the reference, on the (reference, variant) pairs."""
    return float(np.mean([y["time"] for _, y in pairs]) / np.mean([x["time"] for x, _ in pairs]))


def _sign_p(a: int, b: int) -> float:
    """Two-sided exact sign test of ``a`` against ``b`` discordant episodes (1 when there are none)."""
    from scipy.stats import binomtest

    return float(binomtest(int(a), int(a + b)).pvalue) if a + b else 1.0


def report(data_dir: Path, write: Path | None) -> str:
    files = {p.name.removesuffix(".json.gz"): json.loads(gzip.open(p, "rt").read())
             for p in sorted(data_dir.glob("*.json.gz"))}
    if REFERENCE not in files:
        sys.exit(f"{data_dir}/{REFERENCE}.json.gz not found: run `physics_fidelity.py run {REFERENCE}` first")
    ref = files[REFERENCE]
    lines = [
        "<!-- generated by studies/physics_fidelity.py report; do not edit -->",
        "# Physics fidelity: each candidate against the reference physics (issue 55)",
        "",
        f"Generated from `{data_dir}` by `python studies/physics_fidelity.py report`. The reference is "
        "the physics of every run before 2026-12-06: " + ", ".join(f"`{o}`" for o in ref["overrides"]) +
        ". The scripted controller, closed loop through the safety filter, on the first "
        f"{ref['episodes']} **validation** episodes of every suite family (the test split is not read); "
        "the same seeds under each physics. Goal per family (issue 55): successes within one of the "
        "reference's, touching no higher, mean time within 5 % (on the episodes both won).",
        ""]
    verdicts: dict[str, bool] = {}
    for name, var in files.items():
        if name == REFERENCE:
            continue
        lines += [f"## {name}", "", "Overrides: " + ", ".join(f"`{o}`" for o in var["overrides"]) + ".", "",
                  "| family | successes: reference / this | touching | time, s (both won) | ratio | "
                  "cube path gap, median / max (m) | goal |", "|---|---|---|---|---|---|---|"]
        met_all, missed = True, 0
        totals, only = np.zeros(4, int), np.zeros(4, int)
        times_both: list = []
        gaps_all = []
        for family, rows in ref["suite"].items():
            a, b = rows["episodes"], var["suite"][family]["episodes"]
            sa, sb = sum(r["success"] for r in a), sum(r["success"] for r in b)
            ta, tb = sum(r["touched"] for r in a), sum(r["touched"] for r in b)
            both = [(x, y) for x, y in zip(a, b) if x["success"] and y["success"]]
            time_a = float(np.mean([x["time"] for x, _ in both])) if both else math.nan
            time_b = float(np.mean([y["time"] for _, y in both])) if both else math.nan
            ratio = time_b / time_a if both else math.nan
            gaps = [_path_gap(x["path"], y["path"]) for x, y in both]
            gaps_all += gaps
            times_both += both
            met = sb >= sa - 1 and tb <= ta and abs(ratio - 1) <= 0.05
            met_all &= met
            missed += not met
            totals += [sa, sb, ta, tb]
            only += [sum(x["success"] and not y["success"] for x, y in zip(a, b)),
                     sum(y["success"] and not x["success"] for x, y in zip(a, b)),
                     sum(x["touched"] and not y["touched"] for x, y in zip(a, b)),
                     sum(y["touched"] and not x["touched"] for x, y in zip(a, b))]
            gap = f"{np.median(gaps):.3f} / {np.max(gaps):.3f}" if gaps else "-"
            lines.append(f"| {family} | {sa} / {sb} | {ta} / {tb} | {time_a:.2f} / {time_b:.2f} | {ratio:.3f} | "
                         f"{gap} | {'met' if met else '**missed**'} |")
        verdicts[name] = met_all
        lines += ["", f"All families: successes {totals[0]} / {totals[1]}, touching {totals[2]} / {totals[3]}; "
                  f"episodes won by one physics only: reference {only[0]} / this {only[1]} (exact sign test "
                  f"p = {_sign_p(*only[:2]):.2g}); touching by one only: {only[2]} / {only[3]} (p = "
                  f"{_sign_p(*only[2:]):.2g}); time on the {len(times_both)} episodes both won, this / "
                  f"reference {_time_ratio(times_both):.3f}; "
                  f"cube path gap on episodes both won, median {np.median(gaps_all):.3f} m, 90th percentile "
                  f"{np.percentile(gaps_all, 90):.3f} m. **Fidelity goal "
                  + ("met on every family.**" if met_all else f"missed on {missed} of {len(ref['suite'])} families.**"),
                  ""]
        rest_a, rest_b = ref["rest"]["rows"], var["rest"]["rows"]
        threshold = var["rest"]["threshold_mps"]
        lines += ["Obstacles at rest (arm holding still, "
                  f"{len(rest_b)} random validation layouts, {REST_SECONDS:g} s each; touch speed threshold "
                  f"{threshold} m/s): largest displacement reference {max(r['largest_move_m'] for r in rest_a):.2e} m, "
                  f"this {max(r['largest_move_m'] for r in rest_b):.2e} m; largest obstacle speed "
                  f"{max(r['largest_speed_mps'] for r in rest_a):.2e} / "
                  f"{max(r['largest_speed_mps'] for r in rest_b):.2e} "
                  f"m/s; steps counted as touching {sum(r['touched_steps'] for r in rest_a)} / "
                  f"{sum(r['touched_steps'] for r in rest_b)}.", ""]
        pa, pb = ref["probe"]["rows"], var["probe"]["rows"]
        paired = [(x, y) for x, y in zip(pa, pb) if x["first_touch_step"] and y["first_touch_step"]]
        diffs = [y["first_touch_step"] - x["first_touch_step"] for x, y in paired]
        lines += [f"Touch detection (the tip driven at {PROBE_SPEED} m/s into the nearest obstacle, "
                  f"{len(pb)} layouts): touches detected reference {sum(bool(r['first_touch_step']) for r in pa)}, "
                  f"this {sum(bool(r['first_touch_step']) for r in pb)}; first touch step, this minus "
                  f"reference on {len(paired)} probes both detected: "
                  + (f"median {np.median(diffs):+.0f}, range [{min(diffs):+d}, {max(diffs):+d}] control steps; "
                     if diffs else "none; ")
                  + "the tip's largest axis distance outside the obstacle's box at the detected touch, median "
                  + (f"{np.median([x['tip_gap_at_touch_m'] for x, _ in paired]) * 1e3:.1f} / "
                     f"{np.median([y['tip_gap_at_touch_m'] for _, y in paired]) * 1e3:.1f} mm." if paired else "-"),
                  ""]
        lines += [f"Wall time of the whole measurement (noisy; two variants shared the machine): reference "
                  f"{ref['wall_s']:.0f} s, this {var['wall_s']:.0f} s.", ""]
    met = [name for name, ok in verdicts.items() if ok]
    lines[5:5] = [f"**Meeting the goal on every family: {', '.join(met) if met else 'none'}** of "
                  f"{len(verdicts)} variants ({', '.join(name for name in verdicts if name not in met)} miss "
                  "it). A speed candidate becomes the default only if it meets it (issue 55); "
                  f"`{CONTROL}` is a control, not a candidate: it keeps the reference's step and noslip "
                  "passes and changes only the integrator, to show how many episodes a family flips under "
                  "a change that should not matter.", ""]
    text = "\n".join(lines)
    if write:
        write.parent.mkdir(parents=True, exist_ok=True)
        write.write_text(text)
        print(f"written: {write}")
    return text


def main() -> None:
    from ahrm_stack import cli

    cli.quiet_argv()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("name")
    r.add_argument("--episodes", type=int, default=40)
    r.add_argument("--out", type=Path, default=Path("docs/physics-fidelity/data"))
    p = sub.add_parser("report")
    p.add_argument("--data", type=Path, default=Path("docs/physics-fidelity/data"))
    p.add_argument("--write", type=Path, default=None)
    args = parser.parse_args()
    if args.command == "run":
        run(args.name, args.episodes, args.out)
    else:
        print(report(args.data, args.write))


if __name__ == "__main__":
    main()
