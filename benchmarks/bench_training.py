"""Training throughput: the whole PPO loop against env-only collection of the same environments.

For each setting (by default three: one environment in the trainer's process, ``train.num_envs=1``;
the same with the update on two threads, ``train.update_threads=2``; and two environments in two
worker processes, ``train.num_envs=2 train.env_workers=2``):

env only : the trainer's ``LeanCollector`` over the environments a second ``Trainer`` builds from the
           same config (other seeds): the training time limit (``train.time_limit``), the start
           curriculum's first level and the touch ending, in its process or an ``EnvPool`` of worker
           processes (:mod:`ahrm_stack.learning.pool`); the actions tanh(N(0, ``ppo.init_std``)), the
           initial policy's noise, with no network. Before 2026-12-04 these environments had the task's
           60 s episodes and its default starts with uniform random actions (so no resets and mostly
           phase 1 in a 2048-frame batch), and before 2026-12-03 a TorchRL ``Collector``;
training : ``Trainer.iteration`` (collection with the configured policy through its lean collection
           path — ``ppo.hidden_sizes``, 3x256 by default — GAE, PPO epochs with the BC anchor).

env replay: the same environments' work without the learning: a twin ``Trainer`` of the same config
           and seed (so the same environments, starts and random streams) steps, through the same
           ``LeanCollector``, the actions the training loop's policy took in each batch just before,
           so it visits the same states (checked: every observation equal) at the cost of no
           network. The noise policy's trajectories are not the policy's, so their cost differs
           (by up to ~10 % either way, measured); the replay is the like-for-like comparison.
           Both are printed; the goal is read on the replay.

All in frames per second, batches interleaved; prints per setting the ratios training/env (goal
>= 0.8), the absolute training rate (aim >= 1000 frames/s) and the projected wall time of the
300-episode run for 1200-step (unsuccessful) episodes — the worst case.

Usage: python benchmarks/bench_training.py [--batches N] [--settings S ...] [--quick] [key=value ...]
       a setting is a comma-separated override list, e.g. --settings "" "train.num_envs=2,train.env_workers=2";
       overrides for every setting go before --settings (after it they are read as settings), e.g.
       python benchmarks/bench_training.py profile=scratch --settings "" "task.episode.noslip_iterations=0"
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import torch  # noqa: E402

from _scripted import QUICK_TRAINING  # noqa: E402
from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.learning.collection import LeanCollector, RandomActor  # noqa: E402
from ahrm_stack.learning.trainer import Trainer  # noqa: E402

SETTINGS = ("", "train.update_threads=2", "train.num_envs=2,train.env_workers=2")
GOAL_RATIO, AIM_RATE = 0.8, 1000.0


def env_only(config) -> tuple[LeanCollector, Trainer]:
    """A random policy's collector over the environments a second trainer builds from ``config``
    (seed ``train.seed + 1``): the training time limit, the start curriculum at its first level and
    the touch ending, in the process or in an ``EnvPool`` of workers; actions ``tanh(N(0, init_std))``,
    the initial policy's noise. Returns the collector and that trainer (to close)."""
    source = Trainer(dataclasses.replace(config, train=dataclasses.replace(config.train, seed=config.train.seed + 1)),
                     collect_demos=False)
    source._set_touch_end()
    stepper = source.env if source.workers else source.envs
    action_dim = source.env.action_spec.shape[-1]
    actor = RandomActor(action_dim, std=config.ppo.init_std)
    return LeanCollector(stepper, actor, config.ppo.frames_per_batch), source


class ReplayActor:
    """Hands :class:`LeanCollector` the actions of a recorded batch, step by step (``sample`` returns
    the action alone): the batch's ``"action"``, shape [N, T, act] (or [T, act] with one
    environment, which the collector calls with one observation)."""

    out_keys = ["action"]

    def __init__(self) -> None:
        self.actions: torch.Tensor | None = None
        self.step = 0

    def load(self, actions: torch.Tensor) -> None:
        self.actions, self.step = actions, 0

    def sample(self, observation: torch.Tensor) -> tuple[torch.Tensor]:
        assert self.actions is not None
        action = self.actions[..., self.step, :]
        self.step += 1
        return (action,)


class Recorded:
    """Wraps a trainer's ``_collect`` to keep the last batch it collected (its actions, its
    observations)."""

    def __init__(self, trainer: Trainer) -> None:
        self.batch = None
        self._collect = trainer._collect
        trainer._collect = self  # type: ignore[method-assign]

    def __call__(self):
        self.batch = self._collect()
        return self.batch


def replay_twin(config) -> tuple[LeanCollector, ReplayActor, Trainer]:
    """A twin of the training trainer (same config and seed) whose environments replay the training
    loop's actions. It collects no demonstrations: they come from environments of their own, not the
    trainer's (the observation check holds with the default config's behaviour cloning)."""
    twin = Trainer(config, collect_demos=False)
    twin._set_touch_end()
    actor = ReplayActor()
    stepper = twin.env if twin.workers else twin.envs
    return LeanCollector(stepper, actor, config.ppo.frames_per_batch), actor, twin


def measure(overrides: list[str], batches: int) -> dict:
    config = load_config(overrides)
    torch.set_num_threads(config.train.threads)
    trainer = Trainer(config)
    recorded = Recorded(trainer)
    frames = config.ppo.frames_per_batch
    collector, source = env_only(config)
    replay, replay_actor, twin = replay_twin(config)
    same = True

    def training_batch() -> tuple[float, dict, int]:
        """One training iteration: (seconds, the mechanism's state and the frame count before it)."""
        state, frames_before = copy.deepcopy(trainer.mechanism.state_dict()), trainer.frames
        t0 = time.perf_counter()
        trainer.iteration()
        return time.perf_counter() - t0, state, frames_before

    def replay_batch(mechanism_state: dict, frames_before: int) -> float:
        """The twin replays the last training batch from the state training collected it in: the
        reward mechanism's state (its priority constraint can end episodes; worker processes get it
        only at batch ends), the frame count (a delayed touch ending) and the start curriculum."""
        nonlocal same
        twin._completed()  # the twin's finished episodes: dropped (training's own update the mechanism)
        twin.mechanism.load_state_dict(mechanism_state)
        if twin.workers:
            twin.env.load_mechanism(mechanism_state)
        twin.frames = frames_before
        twin._set_touch_end()
        replay_actor.load(recorded.batch["action"])
        t0 = time.perf_counter()
        data = replay.next()
        elapsed = time.perf_counter() - t0
        same &= bool(torch.equal(data["observation"], recorded.batch["observation"]))
        twin.curriculum_level = trainer.curriculum_level  # the next batch's start curriculum
        twin._apply_curriculum()
        return elapsed

    collector.next()
    replay_batch(*training_batch()[1:])  # warm-up of all three
    env_time = train_time = replay_time = 0.0
    for _ in range(batches):
        t0 = time.perf_counter()
        collector.next()
        env_time += time.perf_counter() - t0
        seconds, state, frames_before = training_batch()
        train_time += seconds
        replay_time += replay_batch(state, frames_before)
    source.close()
    twin.close()
    trainer.close()
    n = frames * batches
    return dict(config=config, env=n / env_time, train=n / train_time, replay=n / replay_time, same=same)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_verbose_flag(parser)
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS),
                        help="comma-separated override lists, one per setting ('' = the config)")
    parser.add_argument("overrides", nargs="*", help="overrides for every setting")
    parser.add_argument("--quick", action="store_true", default=os.environ.get("AHRM_BENCH_QUICK") == "1",
                        help="a brief run (1 batch of 64 frames, 1 demonstration): checks that the benchmark works")
    args = parser.parse_args()
    if args.quick:
        args.batches = 1
        args.overrides = [*args.overrides, *QUICK_TRAINING]
    for setting in args.settings:
        extra = [o for o in setting.split(",") if o]
        result = measure([*args.overrides, *extra], args.batches)
        config, env_rate, train_rate = result["config"], result["env"], result["train"]
        replay_rate, ratio = result["replay"], train_rate / result["replay"]
        worst = config.train.episodes * config.task.max_steps / train_rate / 60
        print(f"setting: num_envs={config.train.num_envs} env_workers={config.train.env_workers} "
              f"({' '.join(extra) or 'the config'}); network {list(config.ppo.hidden_sizes)}, "
              f"{config.train.threads} thread(s) ({config.train.update_threads} for the update), "
              f"{config.ppo.frames_per_batch} frames/batch, "
              f"{config.ppo.epochs} epochs, {args.batches} batches")
        print(f"  env only (noise policy)  : {env_rate:7.0f} frames/s   (ratio training/this "
              f"{train_rate / env_rate:.3f})")
        print(f"  env only (replay)        : {replay_rate:7.0f} frames/s   (the training batches' "
              f"actions; same observations: {'yes' if result['same'] else 'NO'})")
        print(f"  training loop            : {train_rate:7.0f} frames/s   (aim >= {AIM_RATE:.0f}: "
              f"{'met' if train_rate >= AIM_RATE else 'NOT met'})")
        if not result["same"]:
            raise SystemExit("the replay left the training trajectories: its rate is not comparable")
        print(f"  ratio training/replay    : {ratio:.3f}   (goal >= {GOAL_RATIO}: "
              f"{'met' if ratio >= GOAL_RATIO else 'NOT met'})")
        print(f"  {config.train.episodes} episodes of {config.task.max_steps} steps at that rate: "
              f"{worst:.0f} min (worst case: no episode ends early)")


if __name__ == "__main__":
    main()
