"""Which pairs of arm parts can meet: the evidence behind ``safety.self_collision_pairs``.

For each arm, every pair of parts (base, link1 ... link6, pusher) that are not neighbours in the
kinematic chain is measured over random joint vectors within the joint limits (continuous joints
over a full turn): the signed distance between the parts' capsules (the pusher's cylinder) in the
collision scene the filter uses, and whether MuJoCo finds the two bodies' geoms in contact at the
same joint vector. Printed per pair: the distance at the home posture, its minimum, 1st
percentile, median and maximum over the draws, the fraction of draws below the safe distance and
below the activation distance, and the fraction in MuJoCo contact. The choice made from this table
(and why) is written next to the lists in configs/safety.yaml.

Usage: python benchmarks/self_collision_pairs.py [--samples N] [--robot NAME]
(NAME: an arm of configs/robots/; default: every arm)
"""

from __future__ import annotations

import argparse
import itertools
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from ahrm_stack.config import arm_names, load_config  # noqa: E402
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
    physics = runner.physics
    model, data = physics.model.ptr, physics.data.ptr
    prefix = task.arm.mjcf_model.model
    body_part = {model.body(f"{prefix}/{body}").id: part for part, body in names.items() if part != "pusher"}
    body_part.update({b: "pusher" for b in range(model.nbody) if model.body(b).name.startswith(f"{prefix}/pusher")})
    qadr = np.asarray(physics.bind(task.arm.joints).qposadr)
    rng = np.random.default_rng(seed)
    lower = np.where(robot.limited, robot.position_lower, -np.pi)
    upper = np.where(robot.limited, robot.position_upper, np.pi)
    table = np.zeros((samples + 1, len(pairs)))
    touching = np.zeros((samples + 1, len(pairs)), dtype=bool)
    column = {frozenset(pair): n for n, pair in enumerate(pairs)}
    for k in range(samples + 1):
        q = np.asarray(config.task.arm.home) if k == 0 else rng.uniform(lower, upper)
        kin.update(q)
        scene.update_robot()
        table[k] = [scene.distance(names[a], names[b]).distance for a, b in pairs]
        data.qpos[qadr] = q
        mujoco.mj_forward(model, data)
        for contact in data.contact[:data.ncon]:
            key = frozenset((body_part.get(int(model.geom_bodyid[contact.geom1])),
                             body_part.get(int(model.geom_bodyid[contact.geom2]))))
            if key in column and contact.dist < 0:
                touching[k, column[key]] = True
    return config, pairs, table, touching


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--robot", choices=arm_names(), action="append")
    args = parser.parse_args()
    for robot in args.robot or arm_names():
        config, pairs, table, touching = measure(robot, args.samples)
        safe = config.safety.obstacle_safe_distance
        active = config.safety.obstacle_activation_distance
        print(f"\n{robot}: {args.samples} random configurations; d_safe {safe} m, activation {active} m")
        print(f"{'pair':>16} {'home':>8} {'min':>8} {'p1':>8} {'median':>8} {'max':>8} "
              f"{'<d_safe':>8} {'<activ.':>8} {'mujoco':>8}")
        for (a, b), column, contact in zip(pairs, table.T, touching.T):
            home, rest = column[0], column[1:]
            print(f"{a + '/' + b:>16} {home:8.3f} {rest.min():8.3f} {np.percentile(rest, 1):8.3f} "
                  f"{np.median(rest):8.3f} {rest.max():8.3f} {np.mean(rest < safe):8.3f} "
                  f"{np.mean(rest < active):8.3f} {np.mean(contact[1:]):8.4f}")


if __name__ == "__main__":
    main()
