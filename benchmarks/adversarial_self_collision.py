"""Adversarial joint-velocity requests through the deployment filter: does the arm ever touch itself?

For each arm, three kinds of request, each for ``--steps`` control steps (episodes of
``--episode`` steps; by default with the cube and obstacles moved off to the floor, so that only
the arm, its base and the table are within reach — ``--props task`` keeps the random layout, and
the arm then also shoves the props about), every one through the safety
filter of deployment (``configs/safety.yaml`` with ``obstacle_rows: true``) and into the simulator:

* ``fold``   — drive every joint at up to 1.5x its velocity limit toward a configuration drawn
               where some pair of arm parts overlaps (a new one every 100 steps);
* ``limits`` — drive each joint at 1.5x its limit toward one of its position limits (continuous
               joints spin), a new choice every 100 steps;
* ``random`` — uniform random requests in +-1.5x the limits, a new one every 20 steps.

Counted in the simulator after every physics step (2 ms): MuJoCo contacts between two bodies of
the arm (base, links, pusher), joint positions outside their limits, joint speeds above the
actuators' velocity limits; and the filter's statuses. Goal: all three zero with the rows on.

Usage: python benchmarks/adversarial_self_collision.py [--steps N] [--robot NAME]
(NAME: an arm of configs/robots/; default: every arm)
       [--no-self-rows] (the comparison: the same requests without the self-collision rows)
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

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from ahrm_stack.config import arm_names, load_config  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402
from ahrm_stack.kinematics.scene import GUARD  # noqa: E402

MODES = ("fold", "limits", "random")
OVERDRIVE = 1.5  # requests up to this multiple of the velocity limits


@dataclasses.dataclass
class Tally:
    steps: int = 0
    substeps: int = 0
    self_contact_substeps: int = 0
    position_violations: int = 0
    velocity_violations: int = 0
    peak_speed_ratio: float = 0.0
    statuses: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    fallbacks: int = 0
    violated: int = 0
    contact_pairs: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    violated_rows: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    fast_joints: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    external_contacts: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    overspeed_in_contact: int = 0  # velocity violations while the arm touches the table or a prop


def arm_bodies(physics, task) -> dict[int, str]:
    """MuJoCo body id -> arm part name, for the base, the links and the pusher's bodies."""
    model = physics.model.ptr
    prefix = task.arm.mjcf_model.model
    robot = task.robot
    parts = {model.body(f"{prefix}/{robot.base_body}").id: "base"}
    for i, body in enumerate(robot.link_bodies):
        parts[model.body(f"{prefix}/{body}").id] = f"link{i + 1}"
    for b in range(model.nbody):
        if model.body(b).name.startswith(f"{prefix}/pusher"):
            parts[b] = "pusher"
    return parts


def folded_targets(task, scene, rng, count: int) -> np.ndarray:
    """Joint vectors within the limits where some pair of non-neighbouring arm parts overlaps."""
    robot, kin = task.robot, task.kinematics
    lower = np.where(robot.limited, robot.position_lower, -np.pi)
    upper = np.where(robot.limited, robot.position_upper, np.pi)
    names = list(scene.robot)
    order = [robot.base_body, *robot.link_bodies, "pusher"]
    pairs = [(a, b) for i, a in enumerate(order) for j, b in enumerate(order)
             if j - i >= 2 and a in names and b in names]
    found = []
    while len(found) < count:
        q = rng.uniform(lower, upper)
        kin.update(q)
        scene.update_robot()
        if any(scene.distance(a, b).distance < 0 for a, b in pairs):
            found.append(q)
    return np.array(found)


def clear_props(physics, task) -> None:
    """Move the cube and the obstacles onto the floor far from the arm (their free joints)."""
    model = physics.model.ptr
    for n, prop in enumerate([task.cube, *task.obstacles]):
        body = int(physics.bind(prop.geom).bodyid)
        address = int(model.jnt_qposadr[model.body_jntadr[body]])
        physics.data.qpos[address:address + 7] = [4.0 + n, 4.0, 0.1, 1.0, 0.0, 0.0, 0.0]
        physics.data.qvel[int(model.jnt_dofadr[model.body_jntadr[body]]) + np.arange(6)] = 0.0
    mujoco.mj_forward(model, physics.data.ptr)


def run(robot_name: str, mode: str, steps: int, episode: int, self_rows: bool, seed: int = 0,
        props: str = "away") -> Tally:
    """``props``: ``away`` moves the cube and obstacles off to the floor after every reset (the
    arm, its base and the table remain: only the arm can touch itself, and no prop pushes it);
    ``task`` keeps the task's layout (the arm also shoves the cube and obstacles about)."""
    config = load_config([f"task.robot={robot_name}", "task.layout.mode=random",
                          "safety.obstacle_rows=true", f"safety.self_collision_rows={str(self_rows).lower()}"])
    runner = TaskRunner(PushOffTask(config.task), seed=seed, safety=config.safety)
    runner.reset()
    task, physics = runner.task, runner.physics
    if props == "away":
        clear_props(physics, task)
    robot = task.robot
    model, data = physics.model.ptr, physics.data.ptr
    parts = arm_bodies(physics, task)
    joints = physics.bind(task.arm.joints)
    qadr, dofadr = np.asarray(joints.qposadr), np.asarray(joints.dofadr)
    limited = robot.limited
    rng = np.random.default_rng(seed)
    targets = folded_targets(task, task.make_collision_scene(physics), rng, 64) if mode == "fold" else None
    tally = Tally()
    step_physics = physics.step
    counting = [False]  # not while the episode is reset (the settling of the free bodies)

    def checked_step(nstep: int = 1) -> None:
        if not counting[0]:
            return step_physics(nstep)
        for _ in range(nstep):
            step_physics(1)
            tally.substeps += 1
            touching = external = False
            for c in data.contact[:data.ncon]:
                body1, body2 = int(model.geom_bodyid[c.geom1]), int(model.geom_bodyid[c.geom2])
                a, b = parts.get(body1), parts.get(body2)
                if a is not None and b is not None:
                    touching = True
                    tally.contact_pairs["/".join(sorted((a, b)))] += 1
                elif a is not None or b is not None:
                    external = True
                    other = model.body(body2 if a is not None else body1).name.split("/")[0] or "world"
                    tally.external_contacts[f"{a or b}/{other}"] += 1
            tally.self_contact_substeps += touching
            q, dq = data.qpos[qadr], data.qvel[dofadr]
            tally.position_violations += int(np.any(limited & ((q < robot.position_lower) | (q > robot.position_upper))))
            ratio = float(np.max(np.abs(dq) / robot.velocity_limit))
            tally.peak_speed_ratio = max(tally.peak_speed_ratio, ratio)
            tally.velocity_violations += int(ratio > 1.0)
            tally.overspeed_in_contact += int(ratio > 1.0 and external)
            if ratio > 1.0:
                tally.fast_joints[int(np.argmax(np.abs(dq) / robot.velocity_limit)) + 1] += 1

    physics.step = checked_step
    limit = robot.velocity_limit
    u_nom = np.zeros(robot.num_joints)
    in_episode = 0
    for step in range(steps):
        q = data.qpos[qadr].copy()
        if mode == "random" and step % 20 == 0:
            u_nom = rng.uniform(-OVERDRIVE, OVERDRIVE, robot.num_joints) * limit
        elif mode == "limits" and step % 100 == 0:
            side = rng.integers(0, 2, robot.num_joints)
            goal = np.where(side == 1, robot.position_upper, robot.position_lower)
            spin = rng.choice([-1.0, 1.0], robot.num_joints)
        if mode == "limits":
            u_nom = np.where(limited, np.sign(goal - q), spin) * OVERDRIVE * limit
        elif mode == "fold":
            if step % 100 == 0:
                target = targets[rng.integers(len(targets))]
            error = np.where(limited, target - q, np.angle(np.exp(1j * (target - q))))
            u_nom = np.clip(4.0 * error, -OVERDRIVE * limit, OVERDRIVE * limit)
        counting[0] = True
        _, terminated, truncated = runner.step_only(u_nom)
        counting[0] = False
        result = runner.last_filter_result
        tally.steps += 1
        tally.statuses[result.status] += 1
        tally.fallbacks += int(result.fallback)
        tally.violated += int(bool(result.violated))
        tally.violated_rows.update(result.violated)
        in_episode += 1
        if (props == "task" and (terminated or truncated)) or in_episode >= episode:
            runner.reset()
            if props == "away":
                clear_props(physics, task)
            in_episode = 0
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--steps", type=int, default=10000, help="control steps per arm and mode")
    parser.add_argument("--episode", type=int, default=400, help="control steps per episode")
    parser.add_argument("--robot", choices=arm_names(), action="append")
    parser.add_argument("--mode", choices=MODES, action="append")
    parser.add_argument("--no-self-rows", action="store_true", help="self-collision rows off")
    parser.add_argument("--props", choices=["away", "task"], default="away",
                        help="away: cube and obstacles moved off (default); task: the random layout")
    args = parser.parse_args()
    total = Tally()
    for robot in args.robot or arm_names():
        for mode in args.mode or MODES:
            start = time.perf_counter()
            t = run(robot, mode, args.steps, args.episode, not args.no_self_rows, props=args.props)
            print(f"{robot:9s} {mode:7s} {t.steps} steps ({t.substeps} physics steps, "
                  f"{time.perf_counter() - start:.0f} s): self-contact physics steps "
                  f"{t.self_contact_substeps}, position violations {t.position_violations}, "
                  f"velocity violations {t.velocity_violations} (peak |qvel|/v_max "
                  f"{t.peak_speed_ratio:.3f}); filter {dict(t.statuses)}, fallbacks {t.fallbacks}, "
                  f"violated {t.violated} {dict(t.violated_rows)}; contact pairs {dict(t.contact_pairs)}; "
                  f"overspeeding joints {dict(t.fast_joints)} ({t.overspeed_in_contact} while touching the "
                  f"table or a prop); arm-environment contacts {dict(t.external_contacts)}", flush=True)
            total.steps += t.steps
            total.self_contact_substeps += t.self_contact_substeps
            total.position_violations += t.position_violations
            total.velocity_violations += t.velocity_violations
    print(f"total: {total.steps} steps, self-contact physics steps {total.self_contact_substeps}, "
          f"position violations {total.position_violations}, velocity violations "
          f"{total.velocity_violations}; guarded distance queries {GUARD.failures}")


if __name__ == "__main__":
    main()
