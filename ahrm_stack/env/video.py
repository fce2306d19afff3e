"""Offscreen rendering of the task's physics and MP4 encoding, on machines without a display.

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is first imported, so
:func:`select_gl_backend` must run before that: it keeps ``MUJOCO_GL`` if set, else tries the
configured backends (``video.gl_backends``, EGL then OSMesa) in a short subprocess each and sets the
first that opens a context. Rendering only reads the simulation state (``mjv_updateScene`` +
``mjr_render``); it never steps or changes the physics, so an episode is the same with or without
video. Frames are encoded to H.264 MP4 with the ffmpeg binary of the ``imageio-ffmpeg`` wheel.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ahrm_stack.config import ConfigError, VideoConfig

# What each backend needs from the system (Debian/Ubuntu package names).
GL_PACKAGES = {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6",
               "glfw": "libglfw3 and a display (DISPLAY)"}
_PROBE = """
import mujoco
from mujoco.rendering.classic import gl_context
context = gl_context.GLContext(16, 16)
context.make_current()
context.free()
"""
_PROBE_TIMEOUT_S = 120


class RenderError(RuntimeError):
    """Offscreen rendering is impossible here; the message says which backend failed and what
    the system needs."""


def _missing_message(tried: dict[str, str]) -> str:
    details = "; ".join(f"MUJOCO_GL={b}: {why}" for b, why in tried.items())
    needs = ", ".join(f"{b} needs {GL_PACKAGES.get(b, '?')}" for b in tried)
    return (f"offscreen rendering is not available ({details}). Set MUJOCO_GL to a working backend "
            f"(egl, osmesa, or glfw with a display) or install the system packages: {needs} "
            "(on Debian/Ubuntu: sudo apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri, or "
            "libosmesa6 for MUJOCO_GL=osmesa; `make setup` installs the EGL ones)")


def probe_gl_backend(backend: str) -> str | None:
    """None if an offscreen context opens with ``MUJOCO_GL=backend`` (tried in a subprocess),
    else the reason (the last line of its error)."""
    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        result = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                                text=True, timeout=_PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return f"no context within {_PROBE_TIMEOUT_S} s"
    if result.returncode == 0:
        return None
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {result.returncode}"


def select_gl_backend(candidates: Sequence[str]) -> str:
    """The OpenGL backend for offscreen rendering: ``MUJOCO_GL`` when set (respected, and checked),
    else the first of ``candidates`` that works, which is then written to ``MUJOCO_GL``.

    Must run before ``mujoco`` is imported for a choice to take effect; raises
    :class:`RenderError` naming MUJOCO_GL and the packages needed when none works.
    """
    current = os.environ.get("MUJOCO_GL")
    if current:
        reason = probe_gl_backend(current)
        if reason is not None:
            raise RenderError(_missing_message({current: reason}))
        return current
    if "mujoco" in sys.modules:
        raise RenderError("MUJOCO_GL is not set and mujoco is already imported, so its OpenGL "
                          "backend can no longer be chosen; set MUJOCO_GL (e.g. MUJOCO_GL=egl) "
                          "before starting Python")
    tried = {}
    for backend in candidates:
        reason = probe_gl_backend(backend)
        if reason is None:
            os.environ["MUJOCO_GL"] = backend
            return backend
        tried[backend] = reason
    raise RenderError(_missing_message(tried))


class FrameRenderer:
    """Renders RGB frames (height × width × 3, uint8) of a physics from the named camera."""

    def __init__(self, physics, video: VideoConfig) -> None:
        import mujoco

        model = physics.model.ptr
        cameras = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        matches = [c for c in cameras if c == video.camera or (c or "").endswith("/" + video.camera)]
        if not matches:
            raise ConfigError(f"video.camera: {video.camera!r} is not a camera of the model; "
                              f"cameras: {cameras}")
        self.camera = matches[0]
        # The offscreen buffer must hold the frame; a visual setting, not a physical one.
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, video.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, video.height)
        self._data = physics.data.ptr
        try:
            self._renderer = mujoco.Renderer(model, height=video.height, width=video.width)
        except Exception as error:  # the GL libraries raise many types; all mean "cannot render"
            backend = os.environ.get("MUJOCO_GL", "") or "(unset: glfw)"
            raise RenderError(_missing_message({backend: f"{type(error).__name__}: {error}"})) from None
        self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(video.shadows)

    def __call__(self) -> np.ndarray:
        self._renderer.update_scene(self._data, camera=self.camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        self._renderer.close()


def write_mp4(path: Path | str, frames: Sequence[np.ndarray], fps: float, quality: int) -> Path:
    """Encode ``frames`` (equal-size RGB uint8) to an H.264 MP4 at ``fps`` frames/s."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError(f"{path}: no frames to write")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            quality=quality, macro_block_size=1, pixelformat="yuv420p") as writer:
        for frame in frames:
            writer.append_data(np.asarray(frame, dtype=np.uint8))
    return path


def read_mp4(path: Path | str) -> tuple[int, tuple[int, int], float]:
    """Decode an MP4 completely: (frame count, (height, width), fps)."""
    import imageio.v2 as imageio

    with imageio.get_reader(Path(path), format="FFMPEG") as reader:
        fps = float(reader.get_meta_data()["fps"])
        count, shape = 0, (0, 0)
        for frame in reader:
            count += 1
            shape = frame.shape[:2]
    return count, shape, fps


class EpisodeFilm:
    """Collects frames of one physics every ``video.frame_every`` control steps of the filmed
    episodes (an evaluation's video): :meth:`start_episode`, then :meth:`capture` in every state."""

    def __init__(self, physics, video: VideoConfig) -> None:
        self.renderer = FrameRenderer(physics, video)
        self.frame_every = video.frame_every
        self.frames: list = []
        self.render_seconds = 0.0
        self._step = 0

    def start_episode(self) -> None:
        self._step = 0

    def capture(self, final: bool = False) -> None:
        """Render the current state (at every ``frame_every``-th call, and always when ``final``)."""
        if final or self._step % self.frame_every == 0:
            started = time.perf_counter()
            self.frames.append(self.renderer())
            self.render_seconds += time.perf_counter() - started
        self._step += 1
