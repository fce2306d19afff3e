"""Obstacles placed exactly touching, or within 1e-12 .. 1e-6 m of, a robot part, through the
safety filter's public API: the process must survive every one, and the distance must be right.

Each placement: a random joint vector near the home posture; a random moving part of the arm (the
pusher's cylinder or a link capsule); a point on its surface (the pusher's side, rim or end face;
a capsule's side or cap); ``obstacle_0`` turned so that one of its faces faces that point, with
the face at a signed gap g in {0, +-1e-12, +-1e-10, +-1e-9, 1e-6} m from it (the other obstacles
far away); then the scene's objects are updated and the deployment filter (obstacle rows on) is
called. With python-fcl (before), such placements aborted the process (uncaught C++
``std::logic_error``, SIGABRT). Checked: the command is finite, the scene's signed distance of
that pair equals g to 1e-6 m (its sign too, beyond 1e-6), and no query needed the guard.

Usage: python benchmarks/near_touching.py [--placements N] [--robot NAME]
(NAME: an arm of configs/robots/; default: every arm)
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402

from ahrm_stack.config import arm_names, load_config  # noqa: E402
from ahrm_stack.env.control_step import make_task_filter  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402

GAPS = (0.0, 1e-12, -1e-12, 1e-10, -1e-10, 1e-9, -1e-9, 1e-6)  # m
ACCURACY = 1e-6  # m


@dataclasses.dataclass
class Outcome:
    placements: int = 0
    worst_error: float = 0.0  # m, |d - g|
    nonfinite_commands: int = 0
    statuses: collections.Counter = dataclasses.field(default_factory=collections.Counter)


def _frame(normal: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """A rotation whose first column is ``normal`` and second the part of ``tangent`` normal to it."""
    t = tangent - (tangent @ normal) * normal
    t /= np.linalg.norm(t)
    return np.column_stack([normal, t, np.cross(normal, t)])


def surface_point(kind: str, rotation: np.ndarray, center: np.ndarray, radius: float, half: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A point on a cylinder (``kind`` 'cylinder') or capsule surface, its outward unit normal and a
    tangent direction there (along which a box face may lie flat)."""
    axis = rotation[:, 2]
    angle = rng.uniform(0, 2 * np.pi)
    radial = rotation[:, 0] * np.cos(angle) + rotation[:, 1] * np.sin(angle)
    where = rng.integers(3)
    if where == 0 or (kind == "capsule" and where == 1):  # the side: a line along the axis
        s = rng.uniform(-half, half)
        return center + s * axis + radius * radial, radial, axis
    if kind == "cylinder" and where == 1:  # an end face, flat
        sign = rng.choice([-1.0, 1.0])
        r = radius * np.sqrt(rng.uniform(0, 1))
        return center + sign * half * axis + r * radial, sign * axis, radial
    if kind == "cylinder":  # the rim: a box face tilted between side and end
        sign = rng.choice([-1.0, 1.0])
        tilt = rng.uniform(0.1, 1.4)
        normal = np.cos(tilt) * radial + np.sin(tilt) * sign * axis
        return center + sign * half * axis + radius * radial, normal, np.cross(normal, radial)
    sign = rng.choice([-1.0, 1.0])  # a capsule's cap: a point on its hemisphere
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    if direction @ (sign * axis) < 0:
        direction -= 2 * (direction @ axis) * axis
    return center + sign * half * axis + radius * direction, direction, np.cross(direction, axis)


def run(robot_name: str, placements: int, seed: int = 0) -> Outcome:
    config = load_config([f"task.robot={robot_name}"])
    runner = TaskRunner(PushOffTask(config.task), seed=seed)
    runner.reset()
    task = runner.task
    kin = task.kinematics
    scene = task.make_collision_scene(runner.physics)
    safety = make_task_filter(task, dataclasses.replace(config.safety, obstacle_rows=True),
                              scene=scene)
    half_sizes = np.asarray(config.task.obstacles.size) / 2
    parts = list(scene.moving_parts)
    count = len([n for n in scene.environment if n.startswith("obstacle_")])
    far = np.array([[3.0, 3.0 + i, 0.0] for i in range(count)])
    rng = np.random.default_rng(seed)
    home = np.asarray(config.task.arm.home)
    limit = task.robot.velocity_limit
    out = Outcome()
    for _ in range(placements):
        q = np.clip(home + rng.uniform(-0.8, 0.8, len(home)), task.robot.position_lower + 0.06,
                    task.robot.position_upper - 0.06)
        kin.update(q)
        scene.update_robot()
        part = parts[rng.integers(len(parts))]
        obj = scene.robot[part]
        shape = obj.collisionGeometry()
        kind = "cylinder" if part == "pusher" else "capsule"
        point, normal, tangent = surface_point(kind, np.asarray(obj.getRotation()),
                                               np.asarray(obj.getTranslation()), shape.radius,
                                               shape.halfLength, rng)
        gap = GAPS[rng.integers(len(GAPS))]
        axis = rng.integers(3)  # the box axis along the face normal
        order = [axis, (axis + 1) % 3, (axis + 2) % 3]
        frame = _frame(normal, tangent if rng.random() < 0.5 else rng.normal(size=3))
        rotation = np.zeros((3, 3))
        rotation[:, order] = frame  # box axis ``axis`` along the outward normal: its -half face touches
        offset = rng.uniform(-0.9, 0.9, 3) * half_sizes  # where on the face the point lies
        offset[axis] = -half_sizes[axis]
        center = point + gap * normal - rotation @ offset
        positions = far.copy()
        positions[0] = center
        rotations = np.tile(np.eye(3), (count, 1, 1))
        rotations[0] = rotation
        scene.update_objects(np.array([3.0, -3.0, 0.0]), np.eye(3), positions, rotations)
        result = safety(q, np.zeros(len(q)), rng.uniform(-1, 1, len(q)) * limit)
        out.placements += 1
        out.statuses[result.status] += 1
        out.nonfinite_commands += int(not np.isfinite(result.command).all())
        d = scene.distance(part, "obstacle_0").distance
        out.worst_error = max(out.worst_error, abs(d - gap))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--placements", type=int, default=50000, help="per arm")
    parser.add_argument("--robot", choices=arm_names(), action="append")
    args = parser.parse_args()
    from ahrm_stack.kinematics.scene import GUARD
    for robot in args.robot or arm_names():
        start = time.perf_counter()
        out = run(robot, args.placements)
        print(f"{robot}: {out.placements} near-touching placements in {time.perf_counter() - start:.0f} s, "
              f"process alive; worst |d - gap| {out.worst_error:.2e} m (goal <= {ACCURACY:g}); "
              f"non-finite commands {out.nonfinite_commands}; filter statuses {dict(out.statuses)}; "
              f"guarded queries so far {GUARD.failures}", flush=True)


if __name__ == "__main__":
    main()
