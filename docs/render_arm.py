"""Render the j2s6s200 arm in the push-off task: ``docs/arm-j2s6s200.png``.

    MUJOCO_GL=egl python docs/render_arm.py [key=value ...]

Two views side by side, at the home posture and while the scripted controller pushes the cube
(after ``PUSH_STEPS`` control steps of the default fixed layout, seed 0), seen by a free camera.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np
from PIL import Image

from ahrm_stack.config import load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask

PUSH_STEPS = 70  # control steps into the episode for the second view
SIZE = (480, 640)  # height, width, pixels
LOOKAT, DISTANCE, AZIMUTH, ELEVATION = (0.0, 0.2, 0.6), 1.5, 210.0, -25.0  # m, m, deg, deg


def render(physics, renderer: mujoco.Renderer) -> np.ndarray:
    camera = mujoco.MjvCamera()
    camera.lookat[:], camera.distance = LOOKAT, DISTANCE
    camera.azimuth, camera.elevation = AZIMUTH, ELEVATION
    renderer.update_scene(physics.data.ptr, camera)
    return renderer.render()


def main(overrides: list[str]) -> Path:
    config = load_config(["task.robot=j2s6s200", *overrides])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    pusher = ScriptedPusher(task, config.scripted)
    pusher.reset(runner.physics)
    model = runner.physics.model.ptr
    renderer = mujoco.Renderer(model, *SIZE)
    frames = [render(runner.physics, renderer)]
    for _ in range(PUSH_STEPS):
        runner.step_only(pusher(runner.physics))
    frames.append(render(runner.physics, renderer))
    out = Path(__file__).resolve().parent / "arm-j2s6s200.png"
    Image.fromarray(np.concatenate(frames, axis=1)).save(out)
    return out


if __name__ == "__main__":
    print(main(sys.argv[1:]))
