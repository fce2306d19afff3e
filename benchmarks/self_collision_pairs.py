"""Which pairs of arm parts can meet: the geometry behind ``safety.self_collision_pairs``.

For each arm, every pair of parts (base, link1 ... link6, pusher) that are not neighbours in the
kinematic chain (the pusher is rigid on link 6, so pusher-link6 are neighbours) is measured over
random joint configurations within the joint limits (continuous joints over a full turn): the
signed distance between the parts' capsules (the pusher's cylinder), in the collision scene the
filter uses. A pair is a candidate for a row when it can come within the activation distance and
is not already that close at the arm's home posture... the table printed here is the evidence;
the choice (with the reasons) is written in configs/safety.yaml.

Usage: python benchmarks/self_collision_pairs.py [--samples N] [--robot jaco|j2s6s200]
"""

from __future__ import annotations

import argparse
import itertools
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402


def part_names(robot) -> dict[str, str]:
    names = {"base": robot.base_body}
    names.update({f"link{i + 1}": body for i, body in enumerate(robot.link_bodies)})
    names["pusher"] = "pusher"
    return names


def measure(robot_name: str, samples: int, seed: int = 0):
    config = load_config([f"task.robot={robot_name}"])
    runner = TaskRunner(PushOffTask(config.task), seed=0)
    runner.reset()
    task = runner.task
    robot, kin = task.robot, task.kinematics
    scene = task.make_collision_scene(runner.physics)
    names = part_names(robot)
    order = list(names)
    pairs = [(a, b) for (i, a), (j, b) in itertools.combinations(enumerate(order), 2) if j - i >= 2]
    rng = np.random.default_rng(seed)
    lower = np.where(robot.limited, robot.position_lower, -np.pi)
    upper = np.where(robot.limited, robot.position_upper, np.pi)
    table = np.zeros((samples + 1, len(pairs)))
    for k in range(samples + 1):
        q = np.asarray(config.task.arm.home) if k == 0 else rng.uniform(lower, upper)
        kin.update(q)
        scene.update_robot()
        table[k] = [scene.distance(names[a], names[b]).distance for a, b in pairs]
    return config, pairs, table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--robot", choices=["jaco", "j2s6s200"], action="append")
    args = parser.parse_args()
    for robot in args.robot or ["jaco", "j2s6s200"]:
        config, pairs, table = measure(robot, args.samples)
        safe = config.safety.obstacle_safe_distance
        active = config.safety.obstacle_activation_distance
        print(f"\n{robot}: {args.samples} random configurations; d_safe {safe} m, activation {active} m")
        print(f"{'pair':>16} {'home':>8} {'min':>8} {'p1':>8} {'median':>8} {'max':>8} "
              f"{'<d_safe':>8} {'<activ.':>8}")
        for (a, b), column in zip(pairs, table.T):
            home, rest = column[0], column[1:]
            print(f"{a + '/' + b:>16} {home:8.3f} {rest.min():8.3f} {np.percentile(rest, 1):8.3f} "
                  f"{np.median(rest):8.3f} {rest.max():8.3f} {np.mean(rest < safe):8.3f} "
                  f"{np.mean(rest < active):8.3f}")


if __name__ == "__main__":
    main()
