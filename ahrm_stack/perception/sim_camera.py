"""The perception camera in simulation: MuJoCo offscreen frames of the sim backend's scene.

The training task and the sim backend are left as they are: :class:`SimCamera` builds a
*render-only copy* of the task (the same :class:`~ahrm_stack.env.task.PushOffTask`) with two
decorations, the fixed camera of ``configs/perception.yaml`` in the arena
(:meth:`~ahrm_stack.env.arena.TableArena.add_fixed_camera`) and the tag texture on the cube's top
face (:meth:`~ahrm_stack.env.entities.BoxProp.set_face_images`). For each frame it copies the
simulator's joint positions (every ``qpos``: arm, cube, obstacles) into the copy, runs MuJoCo's
kinematics and renders (``mujoco.Renderer``, offscreen; set ``MUJOCO_GL=egl`` or osmesa before
``mujoco`` is imported). The copy is never stepped, so the camera cannot change the simulation.

The camera's intrinsics are the pinhole of its ``fovy`` (``f = height / 2 / tan(fovy / 2)``,
principal point at the centre): ``perception.camera.intrinsics`` must be null here.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ahrm_stack.config import TaskConfig
from ahrm_stack.perception.apriltag import AprilTagCubeSource, FrameSource, TagDetector
from ahrm_stack.perception.frame_record import FrameRecording, TappedFrames
from ahrm_stack.perception.geometry import CameraPose, Intrinsics
from ahrm_stack.perception.scene_source import LayoutFileObstacles, MeasuredScene, write_layout_file
from ahrm_stack.perception.settings import PerceptionConfigError, PerceptionSettings
from ahrm_stack.perception.tags import tag_face_image
from ahrm_stack.perception.tracker import CubeTracker

CAMERA_NAME = "perception"
#: ITU-R BT.601 luma weights (as OpenCV's RGB to grey).
LUMA = np.array([0.299, 0.587, 0.114])


def _png(image: np.ndarray) -> bytes:
    import imageio.v2 as imageio

    buffer = io.BytesIO()
    imageio.imwrite(buffer, np.asarray(image, dtype=np.uint8), format="png")
    return buffer.getvalue()


def cube_face_images(settings: PerceptionSettings, cube_size: float, rgba) -> dict[str, bytes]:
    """The cube map of the tagged cube: the tag on the top face (+z, MuJoCo's ``front``), the
    cube's colour ``rgba`` on the five others; PNG bytes per face name."""
    tag = tag_face_image(settings.tag, cube_size)
    size = tag.shape[0]
    plain = np.empty((size, size, 3), dtype=np.uint8)
    plain[...] = np.round(np.asarray(rgba[:3], dtype=float) * 255).astype(np.uint8)
    faces = {name: _png(plain) for name in ("right", "left", "up", "down", "back")}
    faces["front"] = _png(np.repeat(tag[:, :, None], 3, axis=2))
    return faces


def check_sim_camera(settings: PerceptionSettings, cube_size: float | None = None) -> None:
    """Raise :class:`PerceptionConfigError` (one line) where ``settings`` cannot drive the sim
    camera: intrinsics given (MuJoCo renders a centred pinhole from ``camera.fovy_deg``), and, with
    ``cube_size`` (m), a tag that cannot be drawn on the cube's face (family, id, size)."""
    if settings.camera.distortion is not None or settings.camera.calibration_file:
        raise PerceptionConfigError(
            "perception.camera.distortion and calibration_file must be null / '' for the sim "
            "camera: MuJoCo renders an exact pinhole (a calibration is a real camera's)")
    if settings.camera.intrinsics is not None:
        raise PerceptionConfigError(
            "perception.camera.intrinsics must be null for the sim camera: MuJoCo renders a "
            "centred pinhole from camera.fovy_deg")
    if cube_size is not None:
        tag_face_image(settings.tag, cube_size)


class SimCamera:
    """Grey frames of a simulated scene (the sim backend's ``physics``) from the perception
    camera; see the module docstring."""

    def __init__(self, task_config: TaskConfig, settings: PerceptionSettings) -> None:
        import mujoco
        from dm_control import mjcf

        from ahrm_stack.env.task import CUBE_RGBA, PushOffTask

        camera = settings.camera
        check_sim_camera(settings)
        self._mujoco = mujoco
        self.intrinsics = Intrinsics.from_settings(camera)
        self.pose = CameraPose.from_settings(camera)
        task = PushOffTask(task_config)
        task.root_entity.add_fixed_camera(CAMERA_NAME, self.pose.position,
                                          self.pose.mujoco_quaternion, camera.fovy_deg)
        task.cube.set_face_images(cube_face_images(settings, task_config.cube.size, CUBE_RGBA))
        self.task = task
        self.physics = mjcf.Physics.from_mjcf_model(task.root_entity.mjcf_model)
        model = self.physics.model.ptr
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, camera.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, camera.height)
        model.vis.quality.offsamples = settings.sim.offscreen_samples
        self.camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA,
                                           f"{task.root_entity.mjcf_model.model}/{CAMERA_NAME}")
        if self.camera_id < 0:
            self.camera_id = int(self.physics.bind(
                task.root_entity.mjcf_model.find("camera", CAMERA_NAME)).element_id)
        try:
            self.renderer = mujoco.Renderer(model, height=camera.height, width=camera.width)
        except Exception as error:  # the GL libraries raise many types; all mean "cannot render"
            from ahrm_stack.env.video import RenderError, _missing_message
            import os

            backend = os.environ.get("MUJOCO_GL", "") or "(unset: glfw)"
            raise RenderError(_missing_message({backend: f"{type(error).__name__}: {error}"})) from None
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        self.render_seconds = 0.0
        self.frames = 0

    def sync(self, source) -> None:
        """Copy the state of ``source`` (an ``mjcf.Physics`` of the same task) into the copy."""
        data, src = self.physics.data, source.data
        if src.qpos.shape != data.qpos.shape:
            raise ValueError(f"the sim camera's scene has {data.qpos.size} qpos, the simulator "
                             f"{src.qpos.size}: not the same task")
        data.qpos[:] = src.qpos
        data.time = src.time
        self._mujoco.mj_kinematics(self.physics.model.ptr, data.ptr)
        self._mujoco.mj_camlight(self.physics.model.ptr, data.ptr)

    def render_rgb(self, source=None) -> np.ndarray:
        """An RGB frame (height × width × 3, uint8) of ``source``'s state (or the copy's own)."""
        import time

        start = time.perf_counter()
        if source is not None:
            self.sync(source)
        self.renderer.update_scene(self.physics.data.ptr, camera=self.camera_id)
        rgb = self.renderer.render().copy()
        self.render_seconds += time.perf_counter() - start
        self.frames += 1
        return rgb

    def render_gray(self, source=None) -> np.ndarray:
        """A grey frame (height × width, uint8; BT.601 luma) of ``source``'s state."""
        rgb = self.render_rgb(source)
        return np.clip(np.rint(rgb @ LUMA), 0, 255).astype(np.uint8)

    def close(self) -> None:
        self.renderer.close()


class SimFrames:
    """A :class:`~ahrm_stack.perception.apriltag.FrameSource` on the sim backend: each
    :meth:`grab` renders ``arm``'s physics now, stamped with ``arm.clock``'s time. It reads the
    physics as the adapter last advanced it (the loop refreshes feedback first)."""

    def __init__(self, arm, camera: SimCamera) -> None:
        self.arm = arm
        self.camera = camera

    def grab(self) -> tuple[float, np.ndarray]:
        return self.arm.clock.now(), self.camera.render_gray(self.arm.physics)

    def close(self) -> None:
        self.camera.close()


def survey_obstacles(arm, path: Path | str) -> Path:
    """Write the sim backend's obstacle poses as a measured layout file (what a person measuring
    the table would write down before a run)."""
    poses = arm.perception()
    return write_layout_file(path, poses.obstacle_positions, poses.obstacle_quaternions,
                             "obstacle layout surveyed from the simulator at the start of a run")


def sim_camera_scene(arm, task_config: TaskConfig, settings: PerceptionSettings,
                     layout_file: Path | str, camera: SimCamera | None = None,
                     detector: TagDetector | None = None,
                     recording: FrameRecording | None = None) -> MeasuredScene:
    """The camera scene source on the sim backend ``arm``: obstacles from ``layout_file``, the
    cube from the AprilTag on frames of a :class:`SimCamera` (``camera``, or a new one; a
    ``detector`` may be shared between runs too, the tracker is new). ``recording``: the frames to
    record are encoded into it in the control tick (None: none are)."""
    obstacles = LayoutFileObstacles(layout_file, count=len(task_config.obstacles.fixed_layout))
    camera = camera if camera is not None else SimCamera(task_config, settings)
    detector = detector if detector is not None else TagDetector(settings, task_config.cube.size)
    frames: FrameSource = SimFrames(arm, camera)
    if recording is not None:
        frames = TappedFrames(frames, recording.encoder())
    cube = AprilTagCubeSource(frames, detector, CubeTracker(settings.tracker, detector.label))
    return MeasuredScene(obstacles, cube)
