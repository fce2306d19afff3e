"""How far the configured camera detects the configured tag: rendered frames at increasing distance.

The perception camera of ``configs/perception.yaml`` (its field of view and image size) is moved
along its own line of sight to the cube's tag (from the cube's top centre towards the configured
camera position) and, at each distance, MuJoCo renders the sim backend's start scene
(:class:`~ahrm_stack.perception.sim_camera.SimCamera`); the detector of the deploy loop
(:class:`~ahrm_stack.perception.apriltag.TagDetector`, same settings) measures the cube there. Per
distance: the tag's edge in the image (px, from the true corners projected), whether it was
detected, and the error of the measured cube centre (mm) and of its up axis (degrees) against the
simulator's true pose.

    MUJOCO_GL=egl python -m ahrm_stack.perception.detection_range [--from 0.4] [--to 3.0] [--step 0.1]

A real camera: hold the cube (or the printed tag) at increasing distance and watch
``python -m ahrm_stack.perception.camera_check`` (docs/camera.md).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Sequence

import numpy as np

from ahrm_stack.cli import Parser
from ahrm_stack.perception.geometry import CameraPose, look_at_rotation, quaternion_to_matrix
from ahrm_stack.perception.settings import PerceptionSettings


@dataclasses.dataclass(frozen=True)
class RangeRow:
    """One distance: ``distance`` m (camera centre to tag centre), ``tag_px`` (mean edge of the
    projected tag, px), ``detected``, ``position_error_mm`` and ``tilt_error_deg`` (nan when not
    detected)."""

    distance: float
    tag_px: float
    detected: bool
    position_error_mm: float
    tilt_error_deg: float


def measure_range(task_config, settings: PerceptionSettings,
                  distances: Sequence[float], seed: int = 0) -> list[RangeRow]:
    """:class:`RangeRow` per distance (m); see the module docstring. Needs an offscreen GL
    (``MUJOCO_GL=egl``)."""
    from ahrm_stack.perception.apriltag import TagDetector
    from ahrm_stack.perception.sim_camera import SimCamera
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    arm = SimArm(task_config, seed=seed, clock=FastClock())
    arm.connect()
    camera = SimCamera(task_config, settings)
    detector = TagDetector(settings, task_config.cube.size)
    try:
        truth = arm.perception()
        R_cube = quaternion_to_matrix(truth.cube_quaternion)
        half, s = task_config.cube.size / 2, settings.tag.size / 2
        top = truth.cube_position + R_cube @ np.array([0.0, 0.0, half])
        corners = np.array([truth.cube_position + R_cube @ np.array([x, -y, half])
                            for x, y in [(-s, s), (s, s), (s, -s), (-s, -s)]])
        direction = np.asarray(settings.camera.position, dtype=float) - top
        direction /= np.linalg.norm(direction)
        model, data = camera.physics.model.ptr, camera.physics.data.ptr
        rows = []
        for distance in distances:
            position = top + distance * direction
            pose = CameraPose(position, look_at_rotation(position, top))
            model.cam_pos[camera.camera_id] = position
            model.cam_quat[camera.camera_id] = pose.mujoco_quaternion
            camera.sync(arm.physics)
            if not np.allclose(data.cam_xpos[camera.camera_id], position, atol=1e-9):
                raise RuntimeError("the perception camera is not in the world frame")
            detector.camera = pose
            gray = camera.render_gray()
            pixels = camera.intrinsics.project(pose.to_camera(corners))
            edge = float(np.mean(np.linalg.norm(pixels - np.roll(pixels, 1, axis=0), axis=1)))
            found = detector.measure(gray)
            if found is None:
                rows.append(RangeRow(float(distance), edge, False, math.nan, math.nan))
                continue
            error = float(np.linalg.norm(found.position - truth.cube_position)) * 1e3
            cosine = float(np.clip(found.rotation[:, 2] @ R_cube[:, 2], -1.0, 1.0))
            rows.append(RangeRow(float(distance), edge, True, error, math.degrees(math.acos(cosine))))
        return rows
    finally:
        detector.detector.close()
        camera.close()
        arm.disconnect()


def main(argv: Sequence[str] | None = None) -> int:
    import os

    parser = Parser(prog="python -m ahrm_stack.perception.detection_range",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="start", type=float, default=0.4, help="m (default 0.4)")
    parser.add_argument("--to", dest="stop", type=float, default=3.0, help="m (default 3.0)")
    parser.add_argument("--step", type=float, default=0.1, help="m (default 0.1)")
    args = parser.parse_args(argv)
    if not (0 < args.start <= args.stop) or args.step <= 0:
        print(f"{parser.prog}: error: need 0 < --from <= --to and --step > 0", file=sys.stderr)
        return 2
    os.environ.setdefault("MUJOCO_GL", "egl")
    from ahrm_stack.config import ConfigError, load_config
    from ahrm_stack.perception.settings import load_perception_settings

    try:
        settings = load_perception_settings()
        config = load_config()
    except ConfigError as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    camera = settings.camera
    print(f"camera {camera.width} x {camera.height} px, vertical fov {camera.fovy_deg:g} deg; tag "
          f"{settings.tag.family} {settings.tag.size * 100:g} cm; quad_decimate "
          f"{settings.detector.quad_decimate:g}")
    print("distance_m  tag_px  detected  position_error_mm  tilt_error_deg")
    distances = [float(d) for d in np.arange(args.start, args.stop + 1e-9, args.step)]
    rows = measure_range(config.task, settings, distances)
    for row in rows:
        print(f"{row.distance:10.2f}  {row.tag_px:6.1f}  {str(row.detected):8s}  "
              f"{row.position_error_mm:17.1f}  {row.tilt_error_deg:14.1f}")
    seen = [r for r in rows if r.detected]
    if seen:
        last = max(r.distance for r in seen)
        smallest = min(r.tag_px for r in seen)
        print(f"detected up to {last:.2f} m (tag {smallest:.1f} px); first miss beyond: "
              f"{next((f'{r.distance:.2f} m ({r.tag_px:.1f} px)' for r in rows if r.distance > last), 'none')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
