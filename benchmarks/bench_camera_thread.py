"""The control tick with the camera thread (or process) running on a video against the tick without a camera.

The scripted controller drives the sim backend through the deploy loop on the wall clock
(``DeployLoop``, safety filter with obstacle rows) at the deploy rate (configs/deploy.yaml), in
rounds that alternate two scene sources, same seed and duration:

* ``none``: the simulator's exact poses (``--scene sim``): the tick without any camera work;
* ``thread``: the cube from a video (MuJoCo frames of the perception camera of
  configs/perception.yaml, 1920 x 1080, written as MJPG and read back by ``cv2.VideoCapture`` at
  30 frames/s, looped) captured and detected in the detection thread
  (``ahrm_stack.perception.detection_thread``), the obstacles from a surveyed layout file: the
  tick only reads the newest pose (``--scene camera`` with ``source.kind video``,
  ``source.isolation thread``);
* ``process``: the same in a child process (``ahrm_stack.perception.detection_process``,
  ``source.isolation process``, the default).

The tick is the loop's latency window (feedback received -> command sent, wall clock). Printed per
scene: tick p50 / p99 / max (ms) and missed deadlines; for the thread its frames/s and its
latency (capture -> pose, ms); and, once, the old in-tick path's cost (render + detection of one
frame inside the tick, as ``source.kind sim`` still does) for comparison. The last line is the
ratio of the tick p99s (thread / none; the line before it process / none).

    MUJOCO_GL=egl python benchmarks/bench_camera_thread.py [--duration 10] [--rounds 2] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402


def render_video(path: Path, task_config, settings, frames: int) -> None:
    """``frames`` MuJoCo frames of the start scene, the cube moved 2 mm per frame along -x."""
    import cv2

    from ahrm_stack.perception.sim_camera import SimCamera
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    arm = SimArm(task_config, seed=0, clock=FastClock())
    arm.connect()
    camera = SimCamera(task_config, settings)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0,
                             (settings.camera.width, settings.camera.height))
    try:
        qpos, cube = arm.physics.data.qpos, arm.task.addresses.cube_qpos[:3]
        start = qpos[cube].copy()
        for i in range(frames):
            qpos[cube] = start + [-0.002 * i, 0.0, 0.0]
            writer.write(cv2.cvtColor(camera.render_rgb(arm.physics), cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
        camera.close()
        arm.disconnect()


def in_tick_cost(task_config, settings, frames: int) -> np.ndarray:
    """s per frame of the old in-tick path: render + detect (``source.kind sim``)."""
    from ahrm_stack.perception.apriltag import TagDetector
    from ahrm_stack.perception.sim_camera import SimCamera
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    arm = SimArm(task_config, seed=0, clock=FastClock())
    arm.connect()
    camera = SimCamera(task_config, settings)
    detector = TagDetector(settings, task_config.cube.size)
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        detector.measure(camera.render_gray(arm.physics))
        times.append(time.perf_counter() - start)
    detector.detector.close()
    camera.close()
    arm.disconnect()
    return np.asarray(times)


def run_scene(kind: str, duration: float, config, deploy_settings, perception, layout: Path) -> dict:
    """One round of ``duration`` s with scene ``kind``: none (``perception`` None), or the camera
    of ``perception`` (its ``source.isolation``: thread or process)."""
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.perception.camera_scene import camera_scene
    from ahrm_stack.hardware.protocol import WallClock
    from ahrm_stack.sim_arm import SimArm

    arm = SimArm(config.task, seed=0, clock=WallClock())
    session = DeploySession.open(arm, config, None, deploy_settings, world_seed=0)
    arm.connect()
    scene = camera_scene(arm, config.task, perception, layout) if perception is not None else None
    latencies, misses, left = [], 0, duration
    try:
        while left > 1e-9:
            loop = session.loop(None, scene)
            summary = loop.run(left)
            latencies += loop.latencies
            misses += loop.deadline_misses
            left -= max(summary.duration, loop.period)
            if summary.fault:
                raise RuntimeError(f"{kind}: {summary.fault}")
            arm.reset_scene(seed=0)
        thread = None if scene is None else scene.cube_source.thread
        if thread is not None:
            thread.since(0)  # the results that arrived
        return dict(latencies=latencies, misses=misses,
                    frames=0 if thread is None else thread.frames_done,
                    detection=[] if thread is None else list(thread.latencies))
    finally:
        if scene is not None:
            scene.close()
        arm.disconnect()


def _ms(values) -> str:
    v = np.asarray(values) * 1e3
    return f"{np.percentile(v, 50):7.3f} {np.percentile(v, 99):7.3f} {v.max():7.3f}" if v.size else "   n/a"


def main() -> None:
    from ahrm_stack import cli

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--duration", type=float, default=10.0, help="s per round and scene (default 10)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of (none, thread) (default 2)")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 s, one round): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.duration, args.rounds = 1.0, 1
    logging.basicConfig(level=logging.ERROR)
    for logger in ("ahrm_stack.deploy", "ahrm_stack.env.runner"):
        logging.getLogger(logger).setLevel(logging.ERROR)
    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.perception.settings import load_perception_settings
    from ahrm_stack.perception.scene_source import write_layout_file
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    config = load_config()
    deploy_settings = load_deploy_settings(realtime=True, telemetry="")
    deploy_settings = dataclasses.replace(deploy_settings, watchdog=dataclasses.replace(
        deploy_settings.watchdog, max_deadline_misses=10**9))
    settings = load_perception_settings()
    scratch = tempfile.TemporaryDirectory(prefix="bench-camera-")  # removed at exit
    folder = Path(scratch.name)
    video = folder / "rendered.avi"
    render_video(video, config.task, settings, 30 if args.quick else 60)
    perception = {isolation: dataclasses.replace(settings, source=dataclasses.replace(
        settings.source, kind="video", video_file=str(video), loop=True, isolation=isolation))
        for isolation in ("thread", "process")}
    arm = SimArm(config.task, seed=0, clock=FastClock())
    arm.connect()
    poses = arm.perception()
    layout = write_layout_file(folder / "layout.yaml", poses.obstacle_positions, poses.obstacle_quaternions)
    arm.disconnect()
    in_tick = in_tick_cost(config.task, settings, 3 if args.quick else 10)

    print(f"deploy loop at {deploy_settings.rate_hz:g} Hz, sim backend, scripted controller, wall clock; "
          f"{args.rounds} round(s) of {args.duration:g} s per scene; camera {settings.camera.width} x "
          f"{settings.camera.height}, {os.cpu_count()} CPUs")
    kinds = ("none", "thread", "process")
    results: dict[str, dict] = {kind: dict(latencies=[], misses=0, frames=0, detection=[]) for kind in kinds}
    for _ in range(args.rounds):
        for kind in kinds:
            r = run_scene(kind, args.duration, config, deploy_settings, perception.get(kind), layout)
            for key in ("latencies", "detection"):
                results[kind][key] += r[key]
            results[kind]["misses"] += r["misses"]
            results[kind]["frames"] += r["frames"]
    print(f"{'scene':>7} {'ticks':>6} {'missed':>6} | {'tick p50 / p99 / max ms':>23} | "
          f"{'frames/s':>8} | {'capture->pose p50 / p99 / max ms':>32}")
    for kind, r in results.items():
        fps = r["frames"] / (args.rounds * args.duration)
        print(f"{kind:>7} {len(r['latencies']):6d} {r['misses']:6d} | {_ms(r['latencies']):>23} | "
              f"{fps:8.1f} | {_ms(r['detection']):>32}")
    print(f"the old in-tick path (render + detect one frame inside the tick): {_ms(in_tick)} ms "
          f"(p50 / p99 / max over {len(in_tick)})")
    p99 = {kind: float(np.percentile(r["latencies"], 99)) for kind, r in results.items()}
    print(f"ratio process/none tick p99: {p99['process'] / p99['none']:.2f}")
    print(f"ratio thread/none tick p99: {p99['thread'] / p99['none']:.2f}")


if __name__ == "__main__":
    main()
