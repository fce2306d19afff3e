"""The field types every configuration section shares: the program's upper bounds
(:data:`LIMITS`), the shorthands of the field rules (``Pos``, ``PosInt``, ``Pair`` ...), the
method names and the frozen-dataclass decorator of the sections."""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

from ahrm_stack.schema import Float, Int, ge, gt

# Upper bounds: values past these would run (nearly) forever or exhaust the machine. They are
# limits of this program, not tunables, and sit far above any configuration in use. The sections'
# fields name them in their rules (``le(LIMITS[...])``).
LIMITS = {
    "substeps": 1000,  # physics steps per control step (control_period / physics_timestep)
    "control_period": 1.0,  # s
    "episode_steps": 100_000,  # control steps per episode (duration / control_period)
    "episodes": 1_000_000,  # training episodes
    "demo_episodes": 10_000,
    "demo_steps": 5_000_000,  # demo_episodes x episode steps: the demonstrations held in memory
    "bc_epochs": 100_000,
    "eval_episodes": 100_000,
    "num_envs": 256,
    "threads": 256,  # torch threads; training also stays within the machine's CPU count
    "keep_checkpoints": 1000,
    "seed": 2**31 - 1,  # numpy seeds are < 2**32; environment i adds i x 10_000
    "frames_per_batch": 1_000_000,  # the replay buffer holds one batch
    "epochs": 1000,
    "hidden_layers": 16,
    "hidden_width": 8192,
    "max_tries": 1_000_000,  # layout rejection sampling
    "settle_steps": 100_000,  # physics steps at reset
    "noslip_iterations": 1000,  # MuJoCo's noslip passes per physics step
    "osqp_max_iter": 1_000_000,
    "max_obstacle_rows": 100,
    "window": 1_000_000,  # mechanism windows and periods, episodes or steps
}

# Shorthands for the field rules.
Pos = Annotated[Float, gt(0)]  # a number > 0
NonNeg = Annotated[Float, ge(0)]  # a number >= 0
PosInt = Annotated[Int, gt(0)]
NonNegInt = Annotated[Int, ge(0)]
Pair = tuple[Float, Float]
Vec3 = tuple[Float, Float, Float]
Method = Literal["ahrm", "mhrm", "fhrm", "ls"]  # mechanism.method values

Frozen = dataclasses.dataclass(frozen=True)  # the decorator of every section
