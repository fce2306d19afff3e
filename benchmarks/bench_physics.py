"""MuJoCo's step on the task's model: the configured solver options against alternatives, in one run.

Where the physics' time goes (its per-stage timers) and whether a solver option would buy
throughput. The scripted controller's episodes (both layout modes: phases 1-3, the arm touching the
cube; :mod:`_scripted`) are recorded once; their joint commands are replayed open loop, one
control step of ``task.substeps`` MuJoCo steps each, from the same start states on copies of the
task's model that differ in one option:

* ``configured``: the task as configured (Newton solver, elliptic cones, islands, libccd for the
  arm's meshes as dm_control's JACO model sets it);
* ``cg`` / ``pgs``: the conjugate-gradient / projected Gauss-Seidel solver;
* ``no islands``: constraint islands off; ``sparse``: sparse Jacobians; ``native ccd``: MuJoCo's
  own convex collider instead of libccd;
* ``sleeping``: ``task.episode.sleep`` (the resting obstacles leave the step; the cube stays awake);
* ``noslip 0``: ``task.episode.noslip_iterations=0`` (MuJoCo's default: no noslip passes after the
  main solver; the configured 5 are dm_control's composer arena's).

Every option but the configured one changes the contact solution within the solver's tolerance,
so the replays part from the recorded states (open loop, as in ``bench_env_step.py``): the figures
are costs, not equivalences. Interleaved episode by episode; prints us per MuJoCo step, the ratio
configured/option per option, and the configured model's stage timers (``mjData.timer``).
Usage: python benchmarks/bench_physics.py [--episodes N] [--repeats R] [--quick] [key=value ...]
"""

from __future__ import annotations

import dataclasses
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from _scripted import layout_configs, quick_parser, quiet, record  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402

_D = mujoco.mjtDisableBit
VARIANTS: dict[str, dict] = {
    "configured": {},
    "cg": {"solver": int(mujoco.mjtSolver.mjSOL_CG)},
    "pgs": {"solver": int(mujoco.mjtSolver.mjSOL_PGS)},
    "no islands": {"disable": int(_D.mjDSBL_ISLAND)},
    "sparse": {"jacobian": int(mujoco.mjtJacobian.mjJAC_SPARSE)},
    "native ccd": {"enable_native_ccd": True},
    "sleeping": {"sleep": True},
    "noslip 0": {"noslip_iterations": 0},
}
STAGES = ("mjTIMER_POS_KINEMATICS", "mjTIMER_POS_COLLISION", "mjTIMER_POS_MAKE", "mjTIMER_POS_PROJECT",
          "mjTIMER_VELOCITY", "mjTIMER_CONSTRAINT", "mjTIMER_ADVANCE")


def runner_for(cfg, variant: dict) -> TaskRunner:
    """A bare runner (no filter: the recorded commands are replayed as they reached the actuators)
    on its own copy of the task's model, with one option changed."""
    task_cfg = cfg.task
    if variant.get("sleep"):
        task_cfg = dataclasses.replace(task_cfg, episode=dataclasses.replace(task_cfg.episode, sleep=True))
    if "noslip_iterations" in variant:
        task_cfg = dataclasses.replace(task_cfg, episode=dataclasses.replace(
            task_cfg.episode, noslip_iterations=variant["noslip_iterations"]))
    runner = TaskRunner(PushOffTask(task_cfg), seed=0)
    opt = runner.physics.model.ptr.opt
    if "solver" in variant:
        opt.solver = variant["solver"]
    if "jacobian" in variant:
        opt.jacobian = variant["jacobian"]
    if "disable" in variant:
        opt.disableflags = int(opt.disableflags) | variant["disable"]
    if variant.get("enable_native_ccd"):
        opt.disableflags = int(opt.disableflags) & ~int(_D.mjDSBL_NATIVECCD)
    return runner


def main() -> None:
    parser = quick_parser(__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=2, help="scripted episodes per layout mode (default 2)")
    parser.add_argument("--repeats", type=int, default=3, help="replays of each episode (default 3)")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. task.layout.mode=random")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.repeats = 1, 1
    quiet()
    times = dict.fromkeys(VARIANTS, 0.0)
    contacts = {name: [] for name in VARIANTS}
    physics_steps = 0
    timer = np.zeros(len(STAGES))
    stage_index = [int(getattr(mujoco.mjtTimer, name)) for name in STAGES]
    for cfg in layout_configs(args.overrides):
        episodes = record(cfg, args.episodes)
        runners = {name: runner_for(cfg, variant) for name, variant in VARIANTS.items()}
        substeps = cfg.task.substeps
        for repeat in range(args.repeats):
            for episode in episodes:
                order = list(VARIANTS) if repeat % 2 == 0 else list(reversed(VARIANTS))
                for name in order:  # alternating order: neither end always runs first
                    runner = runners[name]
                    runner.seed(episode.seed)
                    runner.reset()
                    ctrl, step = runner.physics.data.ctrl, runner.physics.step
                    actuators = runner.task._arm_actuators
                    data = runner.physics.data.ptr
                    t0 = time.perf_counter()
                    for command in episode.commands:
                        ctrl[actuators] = command
                        step(substeps)
                    times[name] += time.perf_counter() - t0
                    contacts[name].append(data.ncon)
                physics_steps += len(episode.commands) * substeps
        # the configured model's stage timers, on one more replay (timing callbacks cost time)
        runner = runners["configured"]
        mujoco.set_mjcb_time(time.perf_counter)
        try:
            for episode in episodes:
                runner.seed(episode.seed)
                runner.reset()
                data = runner.physics.data.ptr
                before = np.array([data.timer[i].duration for i in stage_index])
                for command in episode.commands:
                    runner.physics.data.ctrl[runner.task._arm_actuators] = command
                    runner.physics.step(substeps)
                timer += np.array([data.timer[i].duration for i in stage_index]) - before
        finally:
            mujoco.set_mjcb_time(None)
    per_step = {name: total / physics_steps * 1e6 for name, total in times.items()}
    print(f"{physics_steps} MuJoCo steps per option (scripted episodes, both layout modes, x {args.repeats})")
    for name, us in per_step.items():
        print(f"{name:11s}: {us:6.1f} us per MuJoCo step, contacts at episode end {np.mean(contacts[name]):4.1f}"
              f"   ratio configured/{name}: {per_step['configured'] / us:.2f}")
    share = timer / max(timer.sum(), 1e-12)
    print("configured, share of the timed stages: " + ", ".join(
        f"{name.removeprefix('mjTIMER_').lower()} {100 * s:.0f} %" for name, s in zip(STAGES, share)))


if __name__ == "__main__":
    main()
