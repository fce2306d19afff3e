"""A minimal scene source for a real arm: fixed cube and obstacle poses from a YAML layout file.

A perception module is what a real deployment needs (another one, AprilTag based, can replace
this); until then :class:`StaticScene` returns the same :class:`~ahrm_stack.hardware.protocol.ObjectPoses`
every tick, with zero velocities, stamped on the arm's clock. :class:`PerceivedArm` gives an adapter
the ``perception()`` method the deploy loop calls.

Layout file (world frame, m; unit quaternions w, x, y, z; ``quaternion`` optional,
default upright)::

    cube: {position: [0.0, 0.0, 0.425]}
    obstacles:
      - {position: [0.16, 0.05, 0.45], quaternion: [1, 0, 0, 0]}
      - ...

Every error is one line naming the file and the key (:class:`SceneLayout`, a section of
:mod:`ahrm_stack.schema`). :func:`read_layout` reads any layout file this way: this one and the
camera scene's measured obstacle layout (:mod:`ahrm_stack.perception.scene_source`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Any, Protocol, Sequence, TypeVar

import numpy as np

from ahrm_stack.schema import Float, Section, read_yaml, unit_quaternion, validate
from ahrm_stack.hardware.protocol import ArmAdapter, ObjectPoses
from ahrm_stack.hardware.wrapper import ArmWrapper


#: how far from 1 a layout quaternion's norm may be (it is then normalised): rounding in a
#: hand-written file, never a wrong rotation
UNIT_TOLERANCE = 1e-3


class SceneError(ValueError):
    """The layout file is missing or invalid; one line naming the file and the key."""


@dataclasses.dataclass(frozen=True)
class Pose(Section):
    position: tuple[Float, Float, Float]  # m, world frame
    # (w, x, y, z), normalised when read; default upright
    quaternion: Annotated[tuple[Float, Float, Float, Float], unit_quaternion(UNIT_TOLERANCE)] = (1.0, 0.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class SceneLayout(Section):
    """A static scene layout file (the module docstring)."""

    cube: Pose
    obstacles: tuple[Pose, ...]  # in the task's obstacle order


class HasObstacles(Protocol):
    """What :func:`read_layout` needs of a layout section: its ``obstacles``."""

    @property
    def obstacles(self) -> Sequence[Any]: ...


L = TypeVar("L", bound=HasObstacles)


def read_layout(cls: type[L], path: Path | str, what: str, count: int | None = None,
                error: type[Exception] = SceneError) -> L:
    """The layout file ``path`` validated as ``cls`` (a section with an ``obstacles`` list), with
    ``count`` obstacles when given (the task's). Errors are one line of class ``error`` that names
    the key and "``what`` ``path``" (e.g. "scene layout configs/scenes/default.yaml")."""
    path = Path(path)
    where = f"{what} {path}"
    if not path.is_file():
        raise error(f"cannot read the {where}: no such file")
    layout: L = validate(cls, read_yaml(path, error), source=lambda key: where, error=error)
    if count is not None and len(layout.obstacles) != count:
        raise error(f"{where}: {len(layout.obstacles)} obstacles; the task has {count}")
    return layout


class StaticScene:
    """Fixed object poses from a layout file (see the module docstring).

    Args:
        path: the YAML layout file.
        num_obstacles: the task's obstacle count, which the layout must match (None: any).
    """

    def __init__(self, path: Path | str, num_obstacles: int | None = None) -> None:
        self.path = Path(path)
        layout = read_layout(SceneLayout, self.path, "scene layout", num_obstacles)
        self.cube_position = np.asarray(layout.cube.position, dtype=float)
        self.cube_quaternion = np.asarray(layout.cube.quaternion, dtype=float)
        self.obstacle_positions = np.array([o.position for o in layout.obstacles], dtype=float).reshape(-1, 3)
        self.obstacle_quaternions = np.array([o.quaternion for o in layout.obstacles],
                                             dtype=float).reshape(-1, 4)

    def poses(self, timestamp: float) -> ObjectPoses:
        """The layout's poses, zero velocities, stamped ``timestamp`` (s, the arm's clock)."""
        k = len(self.obstacle_positions)
        return ObjectPoses(timestamp=float(timestamp), cube_position=self.cube_position.copy(),
                           cube_quaternion=self.cube_quaternion.copy(), cube_velocity=np.zeros(3),
                           obstacle_positions=self.obstacle_positions.copy(),
                           obstacle_quaternions=self.obstacle_quaternions.copy(),
                           obstacle_velocities=np.zeros((k, 3)))


def scene_unset(key: str) -> str:
    """Why a real arm's run has no scene source: its layout setting ``key`` (e.g.
    ``deploy.kortex.scene``) is not set; one line."""
    return (f"{key} is not set: give a layout file of the cube and obstacle poses "
            "(e.g. configs/scenes/default.yaml)")


def static_scene(path: Path | str | None, task_config, key: str) -> StaticScene:
    """A real arm's static scene source: the layout file ``path`` (the setting ``key``) holding
    ``task_config``'s obstacle count; a one-line :class:`SceneError` when it is unset or bad. The
    Gen2 and Kortex backends both build theirs here, and wrap the adapter in :class:`PerceivedArm`."""
    if path is None:
        raise SceneError(scene_unset(key))
    return StaticScene(path, num_obstacles=len(task_config.obstacles.fixed_layout))


class PerceivedArm(ArmWrapper):
    """``arm`` with a scene source: every protocol call goes to ``arm``; :meth:`perception` asks
    ``scene`` (anything with ``poses(timestamp) -> ObjectPoses``) on the arm's clock."""

    def __init__(self, arm: ArmAdapter, scene) -> None:
        super().__init__(arm)
        self.scene = scene

    def perception(self) -> ObjectPoses:
        return self.scene.poses(self.arm.clock.now())
