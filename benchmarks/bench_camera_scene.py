"""The deploy loop with the camera scene source against the same loop with true poses.

The committed policy (``docs/policies/ahrm-default-seed0``) drives the sim backend through the whole
deploy loop (``ahrm_stack.deploy.DeployLoop``, safety filter with obstacle rows, FastClock) on N
episodes of a layout family of ``configs/layouts.yaml`` (default ``default``; episode i uses the
family's seed range start + i, ``configs/seeds.yaml``), twice on the same seeds:

* ``true``: the simulator's exact object poses (``SimArm.perception``, as ``deploy --scene sim``);
* ``camera``: the cube from the AprilTag on MuJoCo frames of the perception camera, tracked with
  the constant-velocity filter, and the obstacles from a layout file surveyed at the start (as
  ``deploy --scene camera``; ``configs/perception.yaml``).

Per scene it prints successes, episodes touching an obstacle (a contact of an obstacle with the arm
or the cube, or an obstacle moving, at a control tick, as training counts it), time to success
(mean ± std over successes) and faults; for the camera also the cube's position and velocity
errors against the simulator (the poses the world model was given, every tick) and the render and
detection cost. The last line is the ratio of the two success counts.

    MUJOCO_GL=egl python benchmarks/bench_camera_scene.py [--episodes 40] [--family default]
                                                           [--duration 20] [--quick] [--out FILE]

Time to success is the loop time at the tick whose perceived cube left the table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

DEFAULT_CHECKPOINT = ROOT / "docs" / "policies" / "ahrm-default-seed0"


@dataclasses.dataclass
class Episode:
    seed: int
    success: bool
    touched: bool
    time: float  # s of loop time at the end
    fault: str
    stop_reason: str
    wall: float  # s
    frames: int = 0
    measured: int = 0  # frames with the tag
    ambiguous: int = 0
    position_errors: list = dataclasses.field(default_factory=list)  # m, per tick
    velocity_errors: list = dataclasses.field(default_factory=list)  # m/s, per tick
    render_seconds: float = 0.0
    perceive_seconds: float = 0.0


def load_config(checkpoint: Path, family: str):
    """The checkpoint run's config (as deploy reads it) with the layout ``family`` applied, and the
    family's first seed."""
    from ahrm_stack.env.layout_catalog import run_config_in_layout

    config, entry = run_config_in_layout(checkpoint, family, runnable=False)
    return config, entry.seed_offset


def run_episode(config, checkpoint: Path, seed: int, duration: float, camera_scene: bool,
                shared: dict) -> Episode:
    from ahrm_stack.deploy import DeployFault, load_deploy_settings, merge_safety
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.config import load_config as load_repo_config
    from ahrm_stack.env.rewards import obstacle_touched
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    safety, _ = merge_safety(load_repo_config().safety, config.safety)
    config = dataclasses.replace(config, safety=safety)
    settings = load_deploy_settings(realtime=False, telemetry="", duration=duration)
    arm = SimArm(config.task, seed=seed, clock=FastClock())
    session = DeploySession.open(arm, config, shared["actor"], settings, world_seed=seed)
    arm.connect()
    task = arm.task
    threshold = config.task.rewards.obstacle_speed_threshold
    state = {"touched": False}
    refresh = arm.refresh_feedback

    def watched_refresh():  # the simulator's own contact test, once per control tick
        frame = refresh()
        data = arm.physics.data
        speeds = np.linalg.norm(data.qvel[task._obstacle_linear_dofs], axis=1)
        if obstacle_touched(data.ptr.contact.geom, task._is_obstacle, task._is_toucher, speeds,
                            threshold):
            state["touched"] = True
        return frame

    arm.refresh_feedback = watched_refresh
    episode = Episode(seed=seed, success=False, touched=False, time=0.0, fault="", stop_reason="",
                      wall=0.0)
    source = None
    if camera_scene:
        from ahrm_stack.perception.sim_camera import sim_camera_scene, survey_obstacles

        layout = survey_obstacles(arm, Path(shared["tmp"]) / f"layout-{seed}.yaml")
        source = sim_camera_scene(arm, config.task, shared["perception"], layout,
                                  camera=shared["camera"], detector=shared["detector"])
        inner = source.poses

        def compared_poses():  # the poses the world model gets, against the simulator's
            start = time.perf_counter()
            poses = inner()
            episode.perceive_seconds += time.perf_counter() - start
            truth = arm.perception()
            episode.position_errors.append(float(np.linalg.norm(poses.cube_position
                                                                - truth.cube_position)))
            episode.velocity_errors.append(float(np.linalg.norm(poses.cube_velocity
                                                                - truth.cube_velocity)))
            return poses

        source.poses = compared_poses
        render_before = shared["camera"].render_seconds
        frames_before = shared["camera"].frames
    loop = session.loop(None, source)
    start = time.perf_counter()
    try:
        summary = loop.run(duration)
    except DeployFault as fault:
        summary = fault.summary
    episode.wall = time.perf_counter() - start
    arm.disconnect()
    episode.success = bool(summary.success)
    episode.touched = state["touched"]
    episode.time = summary.duration
    episode.fault = summary.fault
    episode.stop_reason = summary.stop_reason
    if camera_scene:
        cube = source.cube_source
        episode.frames = shared["camera"].frames - frames_before
        episode.render_seconds = shared["camera"].render_seconds - render_before
        episode.measured = cube.measurements
        episode.ambiguous = cube.ambiguous
    return episode


def describe(name: str, episodes: list[Episode]) -> str:
    n = len(episodes)
    wins = [e for e in episodes if e.success]
    times = np.array([e.time for e in wins])
    touched = sum(e.touched for e in episodes)
    faults = sum(bool(e.fault) for e in episodes)
    timing = f"{times.mean():.2f} ± {times.std():.2f} s" if wins else "-"
    text = (f"{name:>6}: successes {len(wins)}/{n} | touching {touched} | time to success "
            f"{timing} | faults {faults} | wall {sum(e.wall for e in episodes):.1f} s")
    frames = sum(e.frames for e in episodes)
    if frames:
        pos = np.concatenate([e.position_errors for e in episodes]) * 1e3
        vel = np.concatenate([e.velocity_errors for e in episodes])
        measured = sum(e.measured for e in episodes)
        text += (f"\n        cube position error (tracked vs simulator, every tick): median "
                 f"{np.median(pos):.2f} mm, p95 {np.percentile(pos, 95):.2f} mm, max {pos.max():.2f} mm"
                 f"\n        cube velocity error: median {np.median(vel):.3f} m/s, p95 "
                 f"{np.percentile(vel, 95):.3f} m/s, RMS {math.sqrt((vel ** 2).mean()):.3f} m/s"
                 f"\n        frames {frames}, tag seen in {measured} ({100 * measured / frames:.1f} %), "
                 f"ambiguous poses {sum(e.ambiguous for e in episodes)}; render "
                 f"{1e3 * sum(e.render_seconds for e in episodes) / frames:.0f} ms/frame, "
                 f"perception {1e3 * sum(e.perceive_seconds for e in episodes) / frames:.0f} ms/frame")
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--family", default="default", help="a layout of configs/layouts.yaml")
    parser.add_argument("--duration", type=float, default=20.0, help="s per episode (loop time)")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--scenes", nargs="+", default=["true", "camera"], choices=["true", "camera"])
    parser.add_argument("--quick", action="store_true", help="CI: 1 episode of 0.5 s per scene")
    parser.add_argument("--out", type=Path, help="write the episodes as JSON here")
    args = parser.parse_args(argv)
    if args.quick:
        args.episodes, args.duration = 1, 0.5

    import logging

    import torch

    from ahrm_stack.learning.rollouts import load_policy
    from ahrm_stack.perception.settings import load_perception_settings
    from ahrm_stack.perception.sim_camera import SimCamera

    logging.basicConfig(level=logging.ERROR)
    torch.set_num_threads(1)
    config, offset = load_config(args.checkpoint, args.family)
    _, actor = load_policy(args.checkpoint, runnable=False)
    perception = load_perception_settings()
    scratch = tempfile.TemporaryDirectory(prefix="camera-scene-")  # removed at exit
    shared = {"actor": actor, "perception": perception, "tmp": scratch.name}
    if "camera" in args.scenes:
        from ahrm_stack.perception.apriltag import TagDetector

        task_config = config.task
        shared["camera"] = SimCamera(task_config, perception)
        shared["detector"] = TagDetector(perception, task_config.cube.size)
    print(f"policy {args.checkpoint.relative_to(ROOT) if args.checkpoint.is_relative_to(ROOT) else args.checkpoint}, "
          f"family {args.family!r} (seeds {offset}..{offset + args.episodes - 1}), "
          f"{args.episodes} episodes of at most {args.duration:g} s per scene; camera "
          f"{perception.camera.width}x{perception.camera.height}, fovy {perception.camera.fovy_deg:g}°, "
          f"tag {perception.tag.family} id {perception.tag.id}, {perception.tag.size * 1e3:g} mm", flush=True)
    results: dict[str, list[Episode]] = {}
    for scene in args.scenes:
        results[scene] = []
        for i in range(args.episodes):
            episode = run_episode(config, args.checkpoint, offset + i, args.duration, scene == "camera",
                                  shared)
            results[scene].append(episode)
            print(f"  {scene} seed {episode.seed}: success {episode.success} touched "
                  f"{episode.touched} t {episode.time:.2f} s wall {episode.wall:.1f} s"
                  + (f" | {episode.fault}" if episode.fault else ""), flush=True)
    for scene, episodes in results.items():
        print(describe(scene, episodes))
    if "camera" in shared:
        shared["camera"].close()
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({k: [dataclasses.asdict(e) for e in v]
                                        for k, v in results.items()}))
    if len(results) == 2:
        true, camera = (sum(e.success for e in results[k]) for k in ("true", "camera"))
        print(f"ratio camera/true successes: {camera}/{true} = "
              f"{camera / true if true else float('nan'):.3f} (difference {camera - true:+d} episodes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
