"""Representative trajectories for the benchmarks: the scripted controller's episodes, recorded once
and replayed.

The scripted pusher (mink IK) approaches, descends and pushes the cube off the table, so its
episodes visit phases 1-3 (random commands stay mostly in phase 1); the benchmarks record both
layout modes (:func:`layout_configs`). :func:`record` runs it through
the full task step in the configured action mode and keeps, per step, the request (a tip velocity
in m/s for ``action.mode: cartesian``, joint velocities in rad/s for ``joint``) and the joint
command the safety filter let through (rad/s; what the bare physics replays). Replaying the
requests from the same seed reproduces the episode (the simulation is deterministic).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from ahrm_stack import cli  # noqa: E402
from ahrm_stack.config import Config  # noqa: E402


QUICK_TRAINING = ("ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "ppo.epochs=1",
                  "train.demo_episodes=1", "train.bc_epochs=1")
"""The training benchmarks' ``--quick`` overrides: 64-frame batches, one epoch, one demonstration."""


@dataclasses.dataclass
class Episode:
    seed: int
    requests: np.ndarray  # (T, 3) m/s tip velocities (cartesian) or (T, 6) rad/s joint velocities
    commands: np.ndarray  # (T, 6) joint velocities that reached the actuators, rad/s
    phases: np.ndarray  # (T,) phase after each step
    success: bool


def record(config: Config, episodes: int, seed: int = 0) -> list[Episode]:
    """``episodes`` scripted episodes (seeds ``seed``, ``seed + 1``, ...) in the config's action mode."""
    from ahrm_stack.env.episode_loop import scripted_episode
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask

    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=seed, safety=config.safety)
    pusher = ScriptedPusher(task, config.scripted)
    cartesian = runner.control.cartesian  # the request the learner's actions map to
    out = []
    for episode_seed in range(seed, seed + episodes):
        requests, commands, phases = [], [], []
        for step in scripted_episode(runner, pusher, episode_seed, cartesian=cartesian):
            if step.sent is None:
                continue
            requests.append(np.array(step.sent, dtype=float))
            commands.append(task.command.copy())
            phases.append(step.info.phase)
        out.append(Episode(episode_seed, np.array(requests), np.array(commands), np.array(phases),
                           bool(step.terminated)))
    return out


LAYOUTS = ("fixed", "random")
"""Both layout modes: from the fixed layout the pusher starts inside B_obstacles (phases 2-3); the
random layouts also start it in phase 1."""


def layout_configs(overrides=()) -> list[Config]:
    """The config (with ``overrides``) once per layout mode of :data:`LAYOUTS`."""
    from ahrm_stack.config import load_config

    return [load_config([*overrides, f"task.layout.mode={mode}"]) for mode in LAYOUTS]


def phase_counts(episodes: list[Episode]) -> str:
    """``phase 1: n1, 2: n2, 3: n3 steps`` over the episodes."""
    counts = np.bincount(np.concatenate([e.phases for e in episodes]), minlength=4)
    return f"steps per phase 1/2/3: {counts[1]}/{counts[2]}/{counts[3]}"


def quick_parser(description: str) -> argparse.ArgumentParser:
    """An argument parser with ``--quick`` (a brief run: what the test suite uses to keep every
    benchmark alive). ``AHRM_BENCH_QUICK=1`` in the environment means the same."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (seconds): checks that the benchmark works, not its figures")
    cli.add_verbose_flag(parser)
    return parser


def quiet() -> None:
    """Benchmarks print figures, not the warnings of deliberately unfiltered runners."""
    logging.basicConfig(level=logging.ERROR)
    for name in ("ahrm_stack", "ahrm_stack.env.runner", "ahrm_stack.deploy"):
        logging.getLogger(name).setLevel(logging.ERROR)
