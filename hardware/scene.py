"""A minimal scene source for a real arm: fixed cube and obstacle poses from a YAML layout file.

A perception module is what a real deployment needs (another one, AprilTag based, can replace
this); until then :class:`StaticScene` returns the same :class:`~hardware.protocol.ObjectPoses`
every tick, with zero velocities, stamped on the arm's clock. :class:`PerceivedArm` gives an adapter
the ``perception()`` method the deploy loop calls.

Layout file (world frame, m; unit quaternions w, x, y, z; ``quaternion`` optional,
default upright)::

    cube: {position: [0.0, 0.0, 0.425]}
    obstacles:
      - {position: [0.16, 0.05, 0.45], quaternion: [1, 0, 0, 0]}
      - ...

Every error is one line naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hardware.protocol import ArmAdapter, Feedback, ObjectPoses, ServoingMode, WallClock


#: how far from 1 a layout quaternion's norm may be (it is then normalised): rounding in a
#: hand-written file, never a wrong rotation
UNIT_TOLERANCE = 1e-3


class SceneError(ValueError):
    """The layout file is missing or invalid; one line naming the file and the key."""


def _vector(value: Any, size: int, where: str) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != size
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
        raise SceneError(f"{where} must be a list of {size} numbers, got {value!r}")
    vector = np.asarray(value, dtype=float)
    if not np.isfinite(vector).all():
        raise SceneError(f"{where} must be finite, got {value!r}")
    return vector


def _pose(entry: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(entry, dict):
        raise SceneError(f"{where} must be a mapping with position (and quaternion), got {entry!r}")
    unknown = sorted(set(entry) - {"position", "quaternion"})
    if unknown:
        raise SceneError(f"unknown key {where}.{unknown[0]}; allowed: ['position', 'quaternion']")
    if "position" not in entry:
        raise SceneError(f"missing key {where}.position")
    position = _vector(entry["position"], 3, f"{where}.position")
    quaternion = _vector(entry.get("quaternion", [1.0, 0.0, 0.0, 0.0]), 4, f"{where}.quaternion")
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise SceneError(f"{where}.quaternion must be a unit quaternion (w, x, y, z), got "
                         f"{entry['quaternion']!r} (norm {norm:.6g})")
    return position, quaternion / norm


class StaticScene:
    """Fixed object poses from a layout file (see the module docstring).

    Args:
        path: the YAML layout file.
        num_obstacles: the task's obstacle count, which the layout must match (None: any).
    """

    def __init__(self, path: Path | str, num_obstacles: int | None = None) -> None:
        self.path = Path(path)
        where = str(self.path)
        try:
            data = yaml.safe_load(self.path.read_text())
        except OSError as error:
            raise SceneError(f"cannot read the scene layout {where}: {error.strerror}") from None
        except yaml.YAMLError as error:
            raise SceneError(f"{where} is not valid YAML ({str(error).splitlines()[0]})") from None
        if not isinstance(data, dict):
            raise SceneError(f"{where} must be a mapping with cube and obstacles, got {data!r:.80}")
        unknown = sorted(set(data) - {"cube", "obstacles"})
        if unknown:
            raise SceneError(f"{where}: unknown key {unknown[0]}; allowed: ['cube', 'obstacles']")
        for key in ("cube", "obstacles"):
            if key not in data:
                raise SceneError(f"{where}: missing key {key}")
        self.cube_position, self.cube_quaternion = _pose(data["cube"], f"{where}: cube")
        obstacles = data["obstacles"]
        if not isinstance(obstacles, list):
            raise SceneError(f"{where}: obstacles must be a list of poses, got {obstacles!r:.80}")
        if num_obstacles is not None and len(obstacles) != num_obstacles:
            raise SceneError(f"{where}: obstacles has {len(obstacles)} entries; the task has "
                             f"{num_obstacles}")
        poses = [_pose(o, f"{where}: obstacles[{i}]") for i, o in enumerate(obstacles)]
        self.obstacle_positions = np.array([p for p, _ in poses], dtype=float).reshape(-1, 3)
        self.obstacle_quaternions = np.array([q for _, q in poses], dtype=float).reshape(-1, 4)

    def poses(self, timestamp: float) -> ObjectPoses:
        """The layout's poses, zero velocities, stamped ``timestamp`` (s, the arm's clock)."""
        k = len(self.obstacle_positions)
        return ObjectPoses(timestamp=float(timestamp), cube_position=self.cube_position.copy(),
                           cube_quaternion=self.cube_quaternion.copy(), cube_velocity=np.zeros(3),
                           obstacle_positions=self.obstacle_positions.copy(),
                           obstacle_quaternions=self.obstacle_quaternions.copy(),
                           obstacle_velocities=np.zeros((k, 3)))


class PerceivedArm(ArmAdapter):
    """``arm`` with a scene source: every protocol call goes to ``arm``; :meth:`perception` asks
    ``scene`` (anything with ``poses(timestamp) -> ObjectPoses``) on the arm's clock."""

    def __init__(self, arm: ArmAdapter, scene) -> None:
        self.arm, self.scene = arm, scene

    def perception(self) -> ObjectPoses:
        return self.scene.poses(self.arm.clock.now())

    def __getattr__(self, name: str):  # inspection attributes of the wrapped backend
        if name == "arm":
            raise AttributeError(name)
        return getattr(self.arm, name)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.arm.joint_names

    @property
    def velocity_limit(self) -> np.ndarray:
        return self.arm.velocity_limit

    @property
    def clock(self) -> WallClock:
        return self.arm.clock

    @property
    def is_connected(self) -> bool:
        return self.arm.is_connected

    def connect(self) -> None:
        self.arm.connect()

    def disconnect(self) -> None:
        self.arm.disconnect()

    def refresh_feedback(self) -> Feedback:
        return self.arm.refresh_feedback()

    def send_joint_speeds(self, speeds: np.ndarray) -> np.ndarray:
        return self.arm.send_joint_speeds(speeds)

    def stop(self) -> None:
        self.arm.stop()

    def apply_emergency_stop(self) -> None:
        self.arm.apply_emergency_stop()

    def clear_faults(self) -> None:
        self.arm.clear_faults()

    @property
    def servoing_mode(self) -> ServoingMode:
        return self.arm.servoing_mode

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self.arm.set_servoing_mode(mode)
