"""The deploy loop's camera scene source for any backend: which frame source, checked before a
run, and built after the arm connected.

``perception.source.kind``: ``sim`` renders the sim backend's physics inside the control tick
(:func:`~ahrm_stack.perception.sim_camera.sim_camera_scene`; deterministic on the sim's clock,
the sim backend only); ``video``, ``uvc`` and ``realsense`` are real frame sources
(:mod:`~ahrm_stack.perception.frames`) captured and detected in their own process
(:mod:`~ahrm_stack.perception.detection_process`, ``source.isolation: process``) or thread
(:mod:`~ahrm_stack.perception.detection_thread`), on the wall clock, for every backend. The
obstacles come from a measured layout file; only the sim backend can survey one at the start.
With a :class:`~ahrm_stack.perception.frame_record.FrameRecording` (``deploy.record_frames``) each
source's frames are also encoded for the run's record where they are captured.
"""

from __future__ import annotations

from pathlib import Path

from ahrm_stack.config import TaskConfig
from ahrm_stack.perception.frame_record import FrameRecording, TappedFrames
from ahrm_stack.perception.scene_source import LayoutFileObstacles, MeasuredScene
from ahrm_stack.perception.settings import PerceptionConfigError, PerceptionSettings


def check_camera_scene(settings: PerceptionSettings, backend: str, task_config: TaskConfig,
                       layout_file: Path | str | None, realtime: bool) -> None:
    """One-line :class:`PerceptionConfigError` (before anything is opened or written) where
    ``settings`` cannot give ``backend`` a camera scene: the sim render off the sim backend, a
    missing video file, a real camera off the wall clock, no layout file for a real arm, or a bad
    one."""
    from ahrm_stack.perception.frames import check_source
    from ahrm_stack.perception.sim_camera import check_sim_camera

    check_source(settings, backend)
    if settings.source.kind == "sim":
        check_sim_camera(settings, task_config.cube.size)
    elif not realtime:
        raise PerceptionConfigError(f"perception.source.kind {settings.source.kind} is a real camera: "
                                    "it runs on the wall clock (deploy.realtime true, --realtime)")
    if layout_file:
        LayoutFileObstacles(layout_file, count=len(task_config.obstacles.fixed_layout))
    elif backend != "sim":
        raise PerceptionConfigError(f"--scene camera with --backend {backend} needs the measured obstacle "
                                    "layout: --layout-file or perception.layout_file")


def camera_scene(arm, task_config: TaskConfig, settings: PerceptionSettings,
                 layout_file: Path | str, recording: FrameRecording | None = None) -> MeasuredScene:
    """The camera scene on the connected ``arm`` (its clock stamps the frames); a real frame
    source's thread is started and has measured its first frame when this returns. ``recording``:
    where the frames to record go (None: none are)."""
    if settings.source.kind == "sim":
        from ahrm_stack.perception.sim_camera import sim_camera_scene

        return sim_camera_scene(arm, task_config, settings, layout_file, recording=recording)
    from ahrm_stack.perception.apriltag import TagDetector
    from ahrm_stack.perception.calibration import undistorter
    from ahrm_stack.perception.detection_process import DetectionProcess
    from ahrm_stack.perception.detection_thread import DetectionRunner, DetectionThread, ThreadedCubeSource
    from ahrm_stack.perception.frames import open_frame_source
    from ahrm_stack.perception.tracker import CubeTracker

    obstacles = LayoutFileObstacles(layout_file, count=len(task_config.obstacles.fixed_layout))
    label = f"tag {settings.tag.family} id {settings.tag.id}"
    runner: DetectionRunner
    if settings.source.isolation == "process":
        runner = DetectionProcess(settings, task_config.cube.size, label, recording=recording)
    else:
        frames = open_frame_source(settings, arm.clock)
        if recording is not None:
            frames = TappedFrames(frames, recording.encoder())
        runner = DetectionThread(frames, TagDetector(settings, task_config.cube.size), arm.clock,
                                 undistorter(settings))
    cube = ThreadedCubeSource(runner, CubeTracker(settings.tracker, label), arm.clock)
    try:
        cube.start()
    except BaseException:
        cube.close()
        raise
    return MeasuredScene(obstacles, cube)
