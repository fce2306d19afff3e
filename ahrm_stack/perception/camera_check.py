"""Bring-up check of the configured real camera: frames, tag detection, range, latency.

    python -m ahrm_stack.perception.camera_check [--seconds 20]

Opens ``perception.source`` (uvc, realsense or video; with ``camera.calibration_file`` applied),
runs the detection thread of the deploy loop and prints, once a second: frames/s, the share of
frames with the cube's tag, the tag's edge in the image (px), its distance from the camera (m),
the cube's measured centre in the world (m, through the extrinsics) and the thread's latency
(capture -> pose, ms). Move the cube away from the camera until the detected share drops: that is
the detection range of this camera, lens and tag (docs/camera.md). Exit status: 0 the tag was
seen, 1 never seen, 2 bad settings or no camera (one line).
"""

from __future__ import annotations

import sys
import time
from typing import Sequence

import numpy as np

from ahrm_stack.cli import Parser

PROG = "python -m ahrm_stack.perception.camera_check"


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to watch (default 20)")
    args = parser.parse_args(argv)
    from ahrm_stack.config import ConfigError, load_config
    from ahrm_stack.perception.apriltag import TagDetector
    from ahrm_stack.perception.calibration import undistorter
    from ahrm_stack.perception.detection_thread import CameraThreadError, DetectionThread
    from ahrm_stack.perception.frames import FrameError, open_frame_source
    from ahrm_stack.perception.calibration import load_calibrated_settings
    from ahrm_stack.hardware.protocol import WallClock

    try:
        settings = load_calibrated_settings()
        if settings.source.kind == "sim":
            raise ConfigError("perception.source.kind is sim: choose uvc, realsense or video to check "
                              "a real camera (the sim's range: python -m ahrm_stack.perception.detection_range)")
        cube_size = load_config().task.cube.size
        clock = WallClock()
        frames = open_frame_source(settings, clock)
    except (ConfigError, FrameError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    detector = TagDetector(settings, cube_size)
    thread = DetectionThread(frames, detector, clock, undistorter(settings), history=1000)
    seen_any = False
    print("  t_s  frames/s  detected  tag_px  distance_m  cube_world_m               latency_p50/p99_ms")
    try:
        thread.start()
        start = last = time.monotonic()
        index = 0
        while time.monotonic() - start < args.seconds:
            time.sleep(max(0.0, last + 1.0 - time.monotonic()))
            last = time.monotonic()
            if thread.error:
                raise CameraThreadError(thread.error)
            results = thread.since(index)
            if not results:
                print(f"{last - start:5.1f}  no frame")
                continue
            index = results[-1].index + 1
            found = [r.measurement for r in results if r.measurement is not None]
            seen_any = seen_any or bool(found)
            latency = np.array([r.latency for r in results]) * 1e3
            line = (f"{last - start:5.1f}  {len(results):8d}  {len(found) / len(results):8.0%}  ")
            if found:
                m = found[-1]
                edge = float(np.mean(np.linalg.norm(m.corners - np.roll(m.corners, 1, axis=0), axis=1)))
                distance = float(np.linalg.norm(m.position - detector.camera.position))
                line += f"{edge:6.1f}  {distance:10.3f}  {np.round(m.position, 3).tolist()!s:25s}  "
            else:
                line += f"{'-':>6}  {'-':>10}  {'-':25s}  "
            print(line + f"{np.percentile(latency, 50):.1f}/{np.percentile(latency, 99):.1f}")
    except CameraThreadError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    finally:
        thread.stop()
        if not thread.alive:
            frames.close()
            detector.detector.close()
    return 0 if seen_any else 1


if __name__ == "__main__":
    sys.exit(main())
