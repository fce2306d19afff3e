"""Bare physics step vs the full task step, timed in one run on the same trajectories.

The scripted controller's episodes (both layout modes: phases 1-3; in the configured action mode,
``cartesian`` by default) are recorded once (:mod:`_scripted`) and replayed three ways:

* bare: the joint commands that reached the actuators, ``physics.step(substeps)`` only (one
  0.05 s control step of 2 ms MuJoCo steps);
* full: the task's control step on the recorded requests — safety filter (its differential IK in
  cartesian mode), actuation, the same physics, Pinocchio FK, phase geometry, contacts, reward
  components, success — plus the flat observation;
* TorchRL: ``PushOffEnv.step`` (``EnvBase.step``: the full step plus tensors and specs) on the
  recorded requests as normalised actions;
* and bare and full again with MuJoCo's body sleeping (``task.episode.sleep``) flipped from the
  config's value: the same requests, open loop (resting obstacles freeze ~2e-5 m apart, so the pushes
  differ slightly); its ratio is the speed-up of sleeping. Each pair runs in alternating order.

The five are interleaved episode by episode so that machine noise hits them alike; the ratios
are the figures. Goal: full/bare >= 0.9.
Usage: python benchmarks/bench_env_step.py [--episodes N] [--repeats R] [--quick] [key=value ...]
"""

from __future__ import annotations

import dataclasses
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402
import torch  # noqa: E402

from _scripted import layout_configs, phase_counts, quick_parser, quiet, record  # noqa: E402
from ahrm_stack.env.runner import TaskRunner  # noqa: E402
from ahrm_stack.env.task import PushOffTask  # noqa: E402
from ahrm_stack.env.torchrl_env import PushOffEnv  # noqa: E402

GOAL_RATIO = 0.9


def replay(cfg, episodes: list, repeats: int, times: dict, phases: list) -> None:
    """Replay ``episodes`` (recorded with ``cfg``) ``repeats`` times: bare, full and TorchRL, interleaved
    episode by episode; adds the seconds to ``times`` and the full step's phases to ``phases``."""
    other = dataclasses.replace(cfg.task, episode=dataclasses.replace(
        cfg.task.episode, sleep=not cfg.task.episode.sleep))  # body sleeping flipped
    runners = {"bare": TaskRunner(PushOffTask(cfg.task), seed=0),  # no filter: raw physics
               "full": TaskRunner(PushOffTask(cfg.task), seed=0, safety=cfg.safety),
               "bare_other": TaskRunner(PushOffTask(other), seed=0),
               "full_other": TaskRunner(PushOffTask(other), seed=0, safety=cfg.safety)}
    full_runner = runners["full"]
    env = PushOffEnv(cfg.task, cfg.safety, seed=0)
    control = full_runner.control  # the action <-> request maps of the config's action mode
    cartesian = control.cartesian
    substeps = cfg.task.substeps
    for repeat in range(repeats):
        for episode in episodes:
            first = repeat % 2 == 0  # each pair in alternating order, so neither always runs first
            for key in ("bare", "bare_other") if first else ("bare_other", "bare"):
                runner = runners[key]
                runner.seed(episode.seed)
                runner.reset()
                actuators = runner.task._arm_actuators
                ctrl, step = runner.physics.data.ctrl, runner.physics.step
                t0 = time.perf_counter()
                for command in episode.commands:
                    ctrl[actuators] = command
                    step(substeps)
                times[key] += time.perf_counter() - t0

            for key in ("full", "full_other") if first else ("full_other", "full"):
                runner = runners[key]
                runner.seed(episode.seed)
                runner.reset()
                advance = runner.step_cartesian if cartesian else runner.step_only
                t0 = time.perf_counter()
                for request in episode.requests:
                    info, _, _ = advance(request)
                    runner.flat_observation()
                    if key == "full":
                        phases.append(info.phase)
                times[key] += time.perf_counter() - t0

            env.set_seed(episode.seed)
            td = env.reset()
            actions = torch.as_tensor(np.array([control.action(r) for r in episode.requests]),
                                      dtype=torch.float32)
            t0 = time.perf_counter()
            for action in actions:
                td["action"] = action
                td = env.step(td)["next"]
            times["torchrl"] += time.perf_counter() - t0


def main() -> None:
    parser = quick_parser(__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=2, help="scripted episodes per layout mode (default 2)")
    parser.add_argument("--repeats", type=int, default=3, help="replays of each episode (default 3)")
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. task.action.mode=joint")
    args = parser.parse_args()
    if args.quick:
        args.episodes, args.repeats = 1, 1
    quiet()
    torch.set_num_threads(1)
    times = {"bare": 0.0, "full": 0.0, "torchrl": 0.0, "bare_other": 0.0, "full_other": 0.0}
    recorded, replayed = [], []
    for cfg in layout_configs(args.overrides):
        episodes = record(cfg, args.episodes)
        recorded += episodes
        replay(cfg, episodes, args.repeats, times, replayed)
    mode = cfg.task.action.mode
    steps = len(replayed)
    counts = np.bincount(replayed, minlength=4)
    print(f"action mode {mode}; {len(recorded)} scripted episodes (both layout modes) x {args.repeats}, "
          f"{steps} control steps; recorded {phase_counts(recorded)}; replayed 1/2/3: "
          f"{counts[1]}/{counts[2]}/{counts[3]}")
    flip = "awake" if cfg.task.episode.sleep else "sleeping"
    for name, key in (("bare physics step", "bare"), ("full task step", "full"), ("TorchRL env.step", "torchrl"),
                      (f"bare, {flip}", "bare_other"), (f"full, {flip}", "full_other")):
        total = times[key]
        print(f"{name:18s}: {steps / total:8.0f} control steps/s ({total / steps * 1e6:7.1f} us)")
    ratio = times["bare"] / times["full"]
    print(f"ratio full/bare   : {ratio:.3f}   (goal >= {GOAL_RATIO}: {'met' if ratio >= GOAL_RATIO else 'NOT met'})")
    print(f"ratio torchrl/bare: {times['bare'] / times['torchrl']:.3f}")
    awake, asleep = ("full_other", "full") if cfg.task.episode.sleep else ("full", "full_other")
    print(f"{flip}: full/bare {times['bare_other'] / times['full_other']:.3f}; the full step's speed-up "
          f"with task.episode.sleep (awake time / sleeping time): {times[awake] / times[asleep]:.3f}")


if __name__ == "__main__":
    main()
