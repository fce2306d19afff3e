"""The real camera path on a rendered video: MuJoCo frames of the sim backend's scene (the
perception camera of ``configs/perception.yaml``, the cube moved 4 mm per frame, then out of
view) written by ``cv2.VideoWriter`` (MJPG), read back through ``cv2.VideoCapture``
(:class:`VideoFileFrames`), detected in the detection thread, and compared with the rendered
truth; the threaded cube source's staleness rule and end of video; ``--scene camera`` with a
video source through the deploy command."""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from ahrm_stack.perception.apriltag import TagDetector  # noqa: E402
from ahrm_stack.perception.detection_thread import (CameraThreadError, DetectionThread,  # noqa: E402
                                                    ThreadedCubeSource)
from ahrm_stack.perception.frames import FrameError, VideoFileFrames  # noqa: E402
from ahrm_stack.perception.settings import PerceptionConfigError, load_perception_settings  # noqa: E402
from ahrm_stack.perception.tracker import CubeTracker, TagLostError  # noqa: E402
from ahrm_stack.hardware.protocol import FastClock, WallClock  # noqa: E402

SEEN, HIDDEN = 18, 12  # frames with the cube in view, then without it
STEP = 0.004  # m per frame along world -x


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """(video path, true cube centres per frame (None: hidden), settings, task config)."""
    from ahrm_stack.config import load_config
    from ahrm_stack.perception.sim_camera import SimCamera
    from ahrm_stack.sim_arm import SimArm

    config = load_config()
    settings = load_perception_settings()
    arm = SimArm(config.task, seed=0, clock=FastClock())
    arm.connect()
    camera = SimCamera(config.task, settings)
    path = tmp_path_factory.mktemp("video") / "rendered.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0,
                             (settings.camera.width, settings.camera.height))
    try:
        qpos = arm.physics.data.qpos
        cube = arm.task.addresses.cube_qpos[:3]
        start = qpos[cube].copy()
        truth = []
        for i in range(SEEN + HIDDEN):
            qpos[cube] = start + [-STEP * i, 0.0, 0.0] if i < SEEN else start + [0.0, 0.0, -2.0]
            truth.append(qpos[cube].copy() if i < SEEN else None)
            writer.write(cv2.cvtColor(camera.render_rgb(arm.physics), cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
        camera.close()
        arm.disconnect()
    return path, truth, settings, config.task


@pytest.fixture(scope="module")
def seen_video(video):
    """The video's frames with the cube in view only (to be looped)."""
    path, _, settings, _ = video
    seen = path.with_name("seen.avi")
    capture = cv2.VideoCapture(str(path))
    writer = cv2.VideoWriter(str(seen), cv2.VideoWriter_fourcc(*"MJPG"), 30.0,
                             (settings.camera.width, settings.camera.height))
    for _ in range(SEEN):
        writer.write(capture.read()[1])
    writer.release()
    capture.release()
    return seen


def test_rendered_video_through_the_detection_thread_matches_the_truth(video):
    path, truth, settings, task = video
    camera = settings.camera
    frames = VideoFileFrames(path, camera.width, camera.height, WallClock(), fps=None)
    thread = DetectionThread(frames, TagDetector(settings, task.cube.size), WallClock())
    thread.start()  # runs to the video's end
    deadline = time.monotonic() + 60
    while not thread.error and time.monotonic() < deadline:
        time.sleep(0.01)
    assert thread.error == f"camera thread stopped: FrameError: video {path} ended after {SEEN + HIDDEN} frames"
    results = thread.since(0)
    assert [r.index for r in results] == list(range(SEEN + HIDDEN))
    errors = []
    for result, true in zip(results, truth):
        assert result.latency > 0 and (true is None) == (result.measurement is None)
        if true is not None:
            errors.append(np.linalg.norm(result.measurement.position - true))
    capture = [r.capture_time for r in results]
    assert np.all(np.diff(capture) > 0)
    # the cube's centre from an MJPG-compressed 1920 x 1080 frame 1.0 m away, its tag 36 px: a few
    # mm (docs/camera.md: median 1.4 mm, max 6.6 mm over the table's middle)
    assert np.median(errors) < 0.003 and max(errors) < 0.008, np.round(np.array(errors) * 1e3, 2)
    frames.close()
    thread.detector.detector.close()


def test_threaded_source_tracks_then_stops_on_a_lost_tag_and_the_video_end(video):
    """Played at 30 frames/s on the wall clock, read at 100 Hz: each read is the state at now
    (its latency and age stamped), the tracked velocity is the video's; after the cube left the
    view, the tracker's max_hold ends it (TagLostError), then the video's end (one line)."""
    path, truth, settings, task = video
    camera = settings.camera
    clock = WallClock()
    frames = VideoFileFrames(path, camera.width, camera.height, clock, fps=30.0)
    detector = TagDetector(settings, task.cube.size)
    source = ThreadedCubeSource(DetectionThread(frames, detector, clock),
                                CubeTracker(settings.tracker, detector.label), clock)
    source.start()
    states, lost = [], None
    deadline = time.monotonic() + 10
    try:
        while time.monotonic() < deadline:
            try:
                states.append(source.cube())
            except TagLostError as error:
                lost = str(error)
                break
            time.sleep(0.01)
        assert lost is not None and lost.startswith("tag tag36h11 id 0 not seen for")
        assert "> tracker.max_hold 0.25 s" in lost
        assert len(states) > 20
        for state in states:
            assert state.since_measured <= settings.tracker.max_hold and state.latency > 0
        moving = [s for s in states if s.since_measured < 0.1][-5:]
        speed = STEP * 30.0  # m/s along -x, as played
        for state in moving:
            assert state.velocity[0] == pytest.approx(-speed, rel=0.5), state.velocity
        time.sleep(0.6)  # the rest of the video
        with pytest.raises(CameraThreadError, match=r"^camera thread stopped: FrameError: video .* ended after"):
            source.cube()
    finally:
        source.close()


def test_frame_sources_refuse_bad_input_in_one_line(video, tmp_path):
    path, _, settings, task = video
    with pytest.raises(FrameError, match=r"gives 1920 x 1080 px frames; perception.camera is 1280 x 720"):
        VideoFileFrames(path, 1280, 720, WallClock(), fps=None).grab()
    with pytest.raises(FrameError, match=r"video_file .*missing.avi: no such file"):
        VideoFileFrames(tmp_path / "missing.avi", 1920, 1080, WallClock())
    (tmp_path / "text.avi").write_text("not a video")
    with pytest.raises(FrameError, match=r"OpenCV cannot open it"):
        VideoFileFrames(tmp_path / "text.avi", 1920, 1080, WallClock())


def _with_source(settings, **changes):
    return dataclasses.replace(settings, source=dataclasses.replace(settings.source, **changes))


def test_camera_scene_checks_name_the_key(video, tmp_path):
    from ahrm_stack.perception.camera_scene import check_camera_scene

    path, _, settings, task = video
    layout = tmp_path / "layout.yaml"
    layout.write_text("obstacles:\n" + "".join(f"- {{position: [{x}, 0.3, 0.45], yaw_deg: 0}}\n"
                                               for x in (-0.3, -0.1, 0.1, 0.3)))
    cases = [
        (settings, "kinova-gen2", layout, True, "perception.source.kind sim renders the simulator"),
        (_with_source(settings, kind="video", video_file=str(tmp_path / "no.avi")), "kortex", layout, True,
         "perception.source.video_file"),
        (_with_source(settings, kind="video", video_file=str(path)), "sim", None, False,
         "it runs on the wall clock"),
        (_with_source(settings, kind="uvc"), "kinova-gen2", None, True, "needs the measured obstacle layout"),
    ]
    for perception, backend, layout_file, realtime, message in cases:
        with pytest.raises(PerceptionConfigError, match=message) as error:
            check_camera_scene(perception, backend, task, layout_file, realtime)
        assert "\n" not in str(error.value)
    check_camera_scene(_with_source(settings, kind="uvc"), "kortex", task, layout, True)  # fine


def test_deploy_scene_camera_runs_on_a_video_source(video, seen_video, tmp_path, capsys, monkeypatch):
    """``deploy --scene camera --realtime`` with ``source.kind video``: the loop runs on poses
    from the detection thread (the sim backend here; the same path serves every backend) and ends
    on the duration, no fault; the thread is stopped at the end."""
    import threading

    import ahrm_stack.perception.settings as perception_settings
    from ahrm_stack.deploy import main

    _, _, settings, _ = video
    played = _with_source(settings, kind="video", video_file=str(seen_video), loop=True)
    monkeypatch.setattr(perception_settings, "load_perception_settings", lambda *a, **k: played)
    telemetry = tmp_path / "run" / "telemetry.jsonl"
    code = main(["--backend", "sim", "--realtime", "--scene", "camera", "--duration", "0.4",
                 "--telemetry", str(telemetry)])
    captured = capsys.readouterr()
    assert code == 1 and "stop: duration of 0.4 s reached" in captured.out, captured.out + captured.err
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    assert lines[-1]["summary"]["fault"] == ""
    assert not [t for t in threading.enumerate() if t.name == "camera-detection"]


@pytest.mark.parametrize("isolation", ["process", "thread"])
def test_a_real_sources_frames_go_into_the_record(video, seen_video, tmp_path, monkeypatch, isolation):
    """``deploy.record_frames`` with a real frame source (the video, played in real time): the
    child process (or the thread) encodes every 2nd frame where it captures it; the frames in the
    MCAP twin are the camera's size, in capture order, and each tick's frame that was recorded is
    there at the capture stamp the tick names (issue 58, item 6; tests/test_record_frames.py)."""
    import ahrm_stack.perception.settings as perception_settings
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.deploy.record import iter_frames, read_run
    from ahrm_stack.deploy.run import deploy_sim

    _, _, settings, _ = video
    played = _with_source(settings, kind="video", video_file=str(seen_video), loop=True, isolation=isolation)
    monkeypatch.setattr(perception_settings, "load_perception_settings", lambda *a, **k: played)
    telemetry = tmp_path / "telemetry.jsonl"
    deploy_sim(load_deploy_settings(realtime=True, telemetry=str(telemetry), duration=0.6, record_frames=True,
                                    record_frames_every=2), scene="camera")
    record = read_run(telemetry.with_suffix(".mcap"))
    assert record.summary is not None and record.summary["fault"] == "", record.summary
    frames = list(iter_frames(telemetry))
    assert len(frames) >= 2 and all(f.index % 2 == 0 for f in frames), [f.index for f in frames]
    assert [f.t for f in frames] == sorted(f.t for f in frames) and frames[0].t >= 0.0
    assert all(f.image.shape == (settings.camera.height, settings.camera.width) for f in frames)
    recorded = {f.index: f.t for f in frames}
    named = [t for t in record.ticks if t["frame"] in recorded]
    assert named, ([t["frame"] for t in record.ticks], list(recorded))
    for tick in named:
        assert recorded[tick["frame"]] == pytest.approx(tick["frame_t"], abs=1e-6)
        assert tick["frame_t"] <= tick["poses_t"]  # the pose is predicted to the tick from its frame


def test_camera_check_reports_the_tag_size_and_distance_of_the_video(video, seen_video, capsys, monkeypatch):
    """The bring-up check on the rendered video: every frame's tag seen, its edge and distance as
    the rendered camera's geometry gives them (f * size / distance)."""
    import ahrm_stack.perception.settings as perception_settings
    from ahrm_stack.perception.camera_check import main
    from ahrm_stack.perception.geometry import CameraPose, Intrinsics

    _, truth, settings, _ = video
    played = _with_source(settings, kind="video", video_file=str(seen_video), loop=True)
    monkeypatch.setattr(perception_settings, "load_perception_settings", lambda *a, **k: played)
    assert main(["--seconds", "1.2"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    seen = [row for row in rows if row[3] != "-"]
    assert seen, rows
    camera = CameraPose.from_settings(settings.camera)
    intrinsics = Intrinsics.from_settings(settings.camera)
    for row in seen:
        # the measured cube is one of the video's (its frames loop): nearest of the true centres
        distance = float(row[4])
        centre = min((t for t in truth if t is not None),
                     key=lambda t: abs(np.linalg.norm(t - camera.position) - distance))
        assert np.linalg.norm(centre - camera.position) == pytest.approx(distance, abs=0.008)  # as above
        s = settings.tag.size / 2  # the tag's true corners on the upright cube's top face
        corners = centre + np.array([[-s, -s, 0.025], [s, -s, 0.025], [s, s, 0.025], [-s, s, 0.025]])
        px = intrinsics.project(camera.to_camera(corners))
        edge = np.mean(np.linalg.norm(px - np.roll(px, 1, axis=0), axis=1))
        assert float(row[3]) == pytest.approx(edge, abs=1.0)


def test_camera_scene_feeds_the_deploy_loop_on_the_kortex_backend(video, seen_video, tmp_path):
    """A real backend (the Kortex adapter over the fake ``kortex_api``, wall clock): the camera
    scene of a video source (child process) is the loop's perception; the loop runs on the
    video's cube, every tick's cube pose stamped within max_hold of the tick, and ends on the
    duration with the arm stopped."""
    from fake_kortex_api.rig import make_for

    from ahrm_stack.config import load_config
    from ahrm_stack.deploy import DeployLoop, ScriptedController, WorldModel, load_deploy_settings
    from ahrm_stack.perception.camera_scene import camera_scene
    from ahrm_stack.perception.scene_source import write_layout_file

    _, truth, settings, _ = video
    config = load_config()
    world = WorldModel(config.task, seed=0)
    data, at = world.physics.data, world.task.addresses
    clock = WallClock()
    adapter, fake = make_for(world.robot, positions_deg=np.degrees(data.qpos[at.arm_qpos]), clock=clock)
    layout = write_layout_file(tmp_path / "layout.yaml", data.qpos[at.obstacle_qpos[:, :3]],
                               data.qpos[at.obstacle_qpos[:, 3:]])
    played = _with_source(settings, kind="video", video_file=str(seen_video), loop=True)
    deploy = load_deploy_settings(telemetry="")
    deploy = dataclasses.replace(deploy, watchdog=dataclasses.replace(deploy.watchdog, max_deadline_misses=10**6))
    adapter.connect()
    scene = camera_scene(adapter, config.task, played, layout)
    try:
        loop = DeployLoop(adapter, world, ScriptedController(world, config), config.safety, deploy, None, scene)
        seen = []
        loop.start()
        while loop.tick() and len(seen) < 8:
            poses = scene.poses()
            seen.append(poses.cube_position)
        assert len(seen) == 8, loop.stop_reason
        first = truth[0]
        for position in seen:  # the video's cube (moving along -x), not the fake arm's static one
            assert abs(position[1] - first[1]) < 0.005 and -0.08 < position[0] - first[0] < 0.005
        assert loop.fault == ""
    finally:
        adapter.disconnect()
        scene.close()


def test_the_camera_process_keeps_its_newest_pose_fresh_while_nobody_reads(video, seen_video):
    """The control process busy elsewhere (building the loop; 4 s here, more than the ~3 s of
    results a 64 KiB pipe holds at 30 frames/s): the child's results keep arriving, so the newest
    one is a frame of the last few hundred ms, not one the child waited to send on a full pipe
    (as it did before the receiver thread: 1.3 s old)."""
    from ahrm_stack.perception.detection_process import DetectionProcess

    _, _, settings, task = video
    played = _with_source(settings, kind="video", video_file=str(seen_video), loop=True)
    runner = DetectionProcess(played, task.cube.size, "tag tag36h11 id 0")
    runner.start(WallClock())
    try:
        runner.wait_first(20.0)
        time.sleep(4.0)
        newest = runner.since(0)[-1]
        assert time.perf_counter() - newest.capture_time < 0.3
        assert newest.measurement is not None and runner.error == ""
        assert runner.frames_done > 60  # frames went on meanwhile (30/s)
    finally:
        runner.stop()
    assert not runner.alive
