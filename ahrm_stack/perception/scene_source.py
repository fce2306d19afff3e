"""Scene sources: what the deploy loop's perception stage reads each tick.

A :class:`SceneSource` returns :class:`~hardware.protocol.ObjectPoses` (world frame: positions m,
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

import math
from pathlib import Path
from typing import Protocol

import numpy as np
import yaml

from ahrm_stack.perception.apriltag import CubePoseSource
from ahrm_stack.perception.settings import PerceptionConfigError
from hardware.protocol import ObjectPoses


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


class LayoutFileObstacles:
    """Static obstacle poses read from a measured layout file (format: the module docstring).

    Raises :class:`~ahrm_stack.perception.settings.PerceptionConfigError`, one line naming the
    file and the key, for a missing/unreadable file, bad YAML, an unknown or missing key, a
    non-finite number, or (with ``count``) the wrong number of obstacles."""

    def __init__(self, path: Path | str, count: int | None = None) -> None:
        self.path = Path(path)
        where = str(self.path)
        try:
            data = yaml.safe_load(self.path.read_text())
        except OSError as error:
            raise PerceptionConfigError(f"layout file {where}: cannot read it "
                                        f"({error.strerror or error})") from None
        except yaml.YAMLError as error:
            first = (str(error).splitlines() or [""])[0]
            raise PerceptionConfigError(f"layout file {where} is not valid YAML ({first})") from None
        if not isinstance(data, dict) or set(data) != {"obstacles"}:
            keys = sorted(data) if isinstance(data, dict) else data
            raise PerceptionConfigError(f"layout file {where}: expected exactly the key "
                                        f"'obstacles', got {keys!r:.80}")
        entries = data["obstacles"]
        if not isinstance(entries, list) or not entries:
            raise PerceptionConfigError(f"layout file {where}: obstacles must be a non-empty list, "
                                        f"got {entries!r:.80}")
        if count is not None and len(entries) != count:
            raise PerceptionConfigError(f"layout file {where}: {len(entries)} obstacles; the task "
                                        f"has {count}")
        positions, yaws = [], []
        for i, entry in enumerate(entries):
            key = f"obstacles[{i}]"
            if not isinstance(entry, dict) or set(entry) != {"position", "yaw_deg"}:
                raise PerceptionConfigError(f"layout file {where}: {key} must have exactly the keys "
                                            f"['position', 'yaw_deg'], got {entry!r:.80}")
            position, yaw = entry["position"], entry["yaw_deg"]
            if (not isinstance(position, list) or len(position) != 3
                    or any(isinstance(v, bool) or not isinstance(v, (int, float))
                           or not math.isfinite(v) for v in position)):
                raise PerceptionConfigError(f"layout file {where}: {key}.position must be 3 finite "
                                            f"numbers (m), got {position!r}")
            if isinstance(yaw, bool) or not isinstance(yaw, (int, float)) or not math.isfinite(yaw):
                raise PerceptionConfigError(f"layout file {where}: {key}.yaw_deg must be a finite "
                                            f"number (degrees), got {yaw!r}")
            positions.append([float(v) for v in position])
            yaws.append(math.radians(float(yaw)))
        self.positions = np.asarray(positions)
        self.quaternions = np.stack([_yaw_quaternion(y) for y in yaws])
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
    :class:`~hardware.protocol.ObjectPoses` per :meth:`poses` (stamped with the cube's frame)."""

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

    def close(self) -> None:
        """Release the cube source's camera (its offscreen context), if it has one."""
        close = getattr(self.cube_source, "close", None)
        if close is not None:
            close()
