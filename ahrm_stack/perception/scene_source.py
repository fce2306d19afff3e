"""Scene sources: what the deploy loop's perception stage reads each tick.

A :class:`SceneSource` returns :class:`~ahrm_stack.hardware.protocol.ObjectPoses` (world frame: positions m,
quaternions (w, x, y, z), linear velocities m/s) or raises a one-line error, which the deploy
loop treats as a perception fault (it stops the arm and records why).

* :class:`AdapterScene`: the adapter's own ``perception()`` (the sim backend's exact poses).
* :class:`MeasuredScene`: the obstacles from a measured layout file (:class:`LayoutFileObstacles`,
  static, zero velocity) and the cube from a
  :class:`~ahrm_stack.perception.apriltag.CubePoseSource` (e.g. the AprilTag camera).

The layout file (YAML; world frame, m)::

    obstacles:                       # one entry per obstacle, in the task's obstacle order
      - position: [0.16, 0.05, 0.45] # box centre
        yaw_deg: 0.0                 # rotation about world z
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Protocol

import numpy as np
import yaml

from ahrm_stack.perception.apriltag import CubePoseSource
from ahrm_stack.perception.settings import PerceptionConfigError
from ahrm_stack.schema import Float, Section
from ahrm_stack.schema import count as entries
from ahrm_stack.hardware.protocol import ObjectPoses
from ahrm_stack.hardware.scene import read_layout


class SceneSource(Protocol):
    """The deploy loop's perception: :meth:`poses` once per tick."""

    def poses(self) -> ObjectPoses: ...


class AdapterScene:
    """The adapter's ``perception()`` as a scene source (the sim backend: exact poses)."""

    def __init__(self, arm) -> None:
        self.arm = arm

    def poses(self) -> ObjectPoses:
        return self.arm.perception()


def _yaw_quaternion(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


@dataclasses.dataclass(frozen=True)
class ObstacleEntry(Section):
    position: tuple[Float, Float, Float]  # m, box centre, world frame
    yaw_deg: Float  # degrees, rotation about world z


@dataclasses.dataclass(frozen=True)
class ObstacleLayoutFile(Section):
    """A measured layout file (the module docstring)."""

    obstacles: Annotated[tuple[ObstacleEntry, ...], entries(1)]  # in the task's obstacle order


class LayoutFileObstacles:
    """Static obstacle poses read from a measured layout file (format: the module docstring).

    Raises :class:`~ahrm_stack.perception.settings.PerceptionConfigError`, one line naming the
    file and the key, for a missing/unreadable file, bad YAML, an unknown or missing key, a
    non-finite number, or (with ``count``) the wrong number of obstacles (read by
    :func:`ahrm_stack.hardware.scene.read_layout`, as the static scene's layout)."""

    def __init__(self, path: Path | str, count: int | None = None) -> None:
        self.path = Path(path)
        layout = read_layout(ObstacleLayoutFile, self.path, "layout file", count, PerceptionConfigError)
        self.positions = np.asarray([o.position for o in layout.obstacles], dtype=float)
        self.quaternions = np.stack([_yaw_quaternion(math.radians(o.yaw_deg)) for o in layout.obstacles])
        self.velocities = np.zeros_like(self.positions)


def write_layout_file(path: Path | str, positions: np.ndarray, quaternions: np.ndarray,
                      comment: str = "") -> Path:
    """Write obstacle poses (world frame; positions m, quaternions (w, x, y, z)) as a layout file.
    Only the yaw (about world z) of each orientation is kept; the file is what a survey of the
    table would give."""
    path = Path(path)
    entries = []
    for p, q in zip(np.asarray(positions, float), np.asarray(quaternions, float)):
        w, x, y, z = q
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        entries.append({"position": [round(float(v), 6) for v in p],
                        "yaw_deg": round(math.degrees(yaw), 4)})
    path.parent.mkdir(parents=True, exist_ok=True)
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    path.write_text(head + yaml.safe_dump({"obstacles": entries}, sort_keys=False,
                                           default_flow_style=None))
    return path


class MeasuredScene:
    """Obstacles from a layout file, the cube from a :class:`CubePoseSource`; one
    :class:`~ahrm_stack.hardware.protocol.ObjectPoses` per :meth:`poses` (stamped with the cube's frame)."""

    def __init__(self, obstacles: LayoutFileObstacles, cube: CubePoseSource) -> None:
        self.obstacles = obstacles
        self.cube_source = cube

    def poses(self) -> ObjectPoses:
        cube = self.cube_source.cube()
        return ObjectPoses(timestamp=cube.timestamp, cube_position=cube.position,
                           cube_quaternion=cube.quaternion, cube_velocity=cube.velocity,
                           obstacle_positions=self.obstacles.positions.copy(),
                           obstacle_quaternions=self.obstacles.quaternions.copy(),
                           obstacle_velocities=self.obstacles.velocities.copy())

    @property
    def frame(self) -> tuple[int, float] | None:
        """The camera frame the last :meth:`poses` came from: (index since the source started,
        capture stamp s on the adapter's clock); None before the first or for a source without
        frames."""
        return getattr(self.cube_source, "frame", None)

    def close(self) -> None:
        """Release the cube source's camera (its offscreen context), if it has one."""
        close = getattr(self.cube_source, "close", None)
        if close is not None:
            close()
