"""The lane frame: the policy reads the world mirrored x -> -x when its episode's lane is -x.

The push-off's two lanes (``task.layout.lane_directions``: +x and -x) are mirror images of each
other about the plane x = 0 (the table is centred there, the arm's base sits on it, and the
layout and start distributions are symmetric in x). A policy that learns to push along one lane
has learned nothing about the other: the study's from-scratch policies pushed one preferred way
and touched obstacles whenever the episode's free lane was the other one (docs/scratch-study.md,
round 3). In the lane frame the network only ever sees episodes whose lane is +x:

* the **observation** is mirrored when the episode's lane (the observation's ``lane_choice``
  one-hot, the plan :func:`~ahrm_stack.env.layout.choose_lane` fixes at the episode's start) is
  -x: every world-frame x coordinate and x velocity changes sign (the tip, the cube's and each
  obstacle's position and velocity, the tip and obstacles relative to the cube), and the entries
  per lane (``lane_clearance``, ``lane_choice``) swap their +x and -x entries;
* the **action** (``task.action.mode: cartesian``: the tip's velocity in the world frame) the
  network proposes in that frame is mapped back: the Gaussian's mean has its x entry negated.
  A sign change has a unit Jacobian, so the log-probability of a world-frame action is the
  frame's log-probability: PPO's ratios are unchanged.

The arm's joint entries (joint angles as sin/cos, joint velocities, the previous action, which
is the joint-velocity command as a fraction of the limits) have no exact mirror: the arm is not
its own mirror image (its wrist is chiral). ``ppo.lane_frame: mirror`` keeps them as measured,
``mirror_no_joints`` sets them to 0 in the frame (so that the two lanes look exactly alike to the
network; the Cartesian actions and the safety filter's differential IK do not need them).

``ppo.lane_frame: cube_side_no_joints`` keys the same mirror on something that is not the planner:
the cube's own side of the table, mirrored when the cube's observed x is below 0 (the joint entries
zeroed). It tells the network nothing about the lane (the choice depends on the obstacles); it
only shows it one half of the table, so that pushes learned on one side serve the other.

``ppo.lane_frame: tip_side_no_joints`` keys it on the pusher tip's side of the cube, per step:
mirrored when the observed tip is at larger x than the cube (``relative_to_cube``'s x > 0). Every
state is then seen with the tip on the cube's -x side, so that a push away from the tip is always
+x in the frame and the near-cube starts behind a free lane (``task.arm.near_cube.bearing:
behind_free``) are one task, as the planner's lane makes them for ``mirror*``, without the
planner: the key is the policy's own observation. Where the lane ahead (in the frame) is blocked,
the way round the cube crosses x = cube x, and the frame turns with the tip.

Everything here is torch on the policy's side: the environment, the rewards, the safety filter
and the deploy loop stay in the world frame, and a checkpoint carries the mirror as buffers.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from ahrm_stack.config import Config, LaneFrame, TaskConfig
from ahrm_stack.env.observation_layout import observation_layout

MIRRORED_LANE = {"+x": "-x", "-x": "+x"}


class LaneMirror(nn.Module):
    """Observation -> (observation in the lane frame, per-action-entry signs back to the world).

    Built by :func:`make_lane_mirror`; its index tensors are buffers, so a checkpoint carries them.
    ``permutation[i]``: the world entry that entry i of the mirrored observation reads;
    ``sign[i]``: -1 for x coordinates, else +1; ``keep[i]``: 0 for entries dropped in the frame
    (whether mirrored or not); ``minus_index``: the entry that decides the mirror, the
    ``lane_choice`` entry of the -x lane (or, ``cube_side_no_joints``, the cube's x; ``tip_side_no_joints``,
    the tip's x relative to the cube): mirrored where ``key_sign`` x that entry > ``key_threshold``
    (1 and 0.5: the -x lane; -1 and 0 m: the cube at x < 0; 1 and 0 m: the tip on the cube's +x side;
    rebuilt from the config, not stored in checkpoints); ``action_sign``: -1 for the
    action's x entry."""

    permutation: torch.Tensor
    sign: torch.Tensor
    keep: torch.Tensor
    minus_index: torch.Tensor
    action_sign: torch.Tensor
    key_sign: torch.Tensor
    key_threshold: torch.Tensor

    def __init__(self, permutation: Sequence[int], sign: Sequence[float], keep: Sequence[float],
                 minus_index: int, action_sign: Sequence[float], key_sign: float = 1.0,
                 key_threshold: float = 0.5) -> None:
        super().__init__()
        self.register_buffer("permutation", torch.as_tensor(permutation, dtype=torch.long))
        self.register_buffer("sign", torch.as_tensor(sign, dtype=torch.float32))
        self.register_buffer("keep", torch.as_tensor(keep, dtype=torch.float32))
        self.register_buffer("minus_index", torch.as_tensor(minus_index, dtype=torch.long))
        self.register_buffer("action_sign", torch.as_tensor(action_sign, dtype=torch.float32))
        # not in the state dict: checkpoints written before them load as they were
        self.register_buffer("key_sign", torch.tensor(key_sign, dtype=torch.float32), persistent=False)
        self.register_buffer("key_threshold", torch.tensor(key_threshold, dtype=torch.float32), persistent=False)

    def mirrored(self, observation: torch.Tensor) -> torch.Tensor:
        """Boolean (..., 1): the observation is to be mirrored (its lane is -x, or its cube at x < 0)."""
        key = observation.index_select(-1, self.minus_index.reshape(1))
        return key * self.key_sign.to(observation.dtype) > self.key_threshold.to(observation.dtype)

    def canonical(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(observation in the lane frame, signs (..., action_dim) that map an action of the
        frame to the world: -1 on the x entry where the lane is -x, else +1)."""
        minus = self.mirrored(observation)
        sign = self.sign.to(observation.dtype)
        mirrored = observation.index_select(-1, self.permutation) * sign
        framed = torch.where(minus, mirrored, observation) * self.keep.to(observation.dtype)
        action_sign = self.action_sign.to(observation.dtype)
        return framed, torch.where(minus, action_sign, torch.ones_like(action_sign))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.canonical(observation)[0]


def make_lane_mirror(task: TaskConfig, frame: LaneFrame, num_joints: int, num_commanded: int,
                     observation_dim: int, action_dim: int) -> LaneMirror | None:
    """The :class:`LaneMirror` of ``ppo.lane_frame`` for this task's observation (None for
    ``none``). ``ValueError`` when ``observation_dim`` is not the layout's size."""
    if frame == "none":
        return None
    layout = observation_layout(task, num_joints, num_commanded)
    directions: list[str] = list(task.layout.lane_directions)
    by_lane = frame.startswith("mirror")
    if (by_lane and "lane_choice" not in layout) or "-x" not in directions:  # Config.check names the key
        raise ValueError("ppo.lane_frame needs task.observation.lane_choice (mirror*) and a -x lane")
    size = max(s.stop for s in layout.values())
    if size != observation_dim:
        raise ValueError(f"ppo.lane_frame: the observation has {observation_dim} entries, the task's "
                         f"layout {size}")
    permutation = list(range(observation_dim))
    sign = [1.0] * observation_dim
    keep = [1.0] * observation_dim
    x_entries = [layout["pusher_tip"].start]
    for name in ["cube", *(f"obstacle_{i}" for i in range(len(task.obstacles.fixed_layout)))]:
        x_entries += [layout[name].start, layout[name].start + 3]  # position x, velocity x
    if "relative_to_cube" in layout:
        relative = layout["relative_to_cube"]
        x_entries += [relative.start] + list(range(relative.start + 3, relative.stop, 2))
    for i in x_entries:
        sign[i] = -1.0
    for name in ("lane_clearance", "lane_choice"):
        if name in layout:
            for i, direction in enumerate(directions):
                permutation[layout[name].start + i] = layout[name].start + directions.index(
                    MIRRORED_LANE[direction])
    if frame.endswith("no_joints"):
        for name in ("joints_pos", "joints_vel", "previous_action"):
            for i in range(layout[name].start, layout[name].stop):
                keep[i] = 0.0
    action_sign = [1.0] * action_dim
    action_sign[0] = -1.0  # Cartesian actions: (x, y, z) of the tip's velocity, world frame
    if by_lane:
        return LaneMirror(permutation, sign, keep, layout["lane_choice"].start + directions.index("-x"),
                          action_sign)
    if frame == "tip_side_no_joints":  # tip - cube, x (m): mirrored on the cube's +x side
        if "relative_to_cube" not in layout:  # Config.check names the key
            raise ValueError("ppo.lane_frame: tip_side_no_joints needs task.observation.relative")
        return LaneMirror(permutation, sign, keep, layout["relative_to_cube"].start, action_sign,
                          key_sign=1.0, key_threshold=0.0)
    return LaneMirror(permutation, sign, keep, layout["cube"].start, action_sign, key_sign=-1.0, key_threshold=0.0)


def lane_mirror_for(config: Config, observation_dim: int, action_dim: int,
                    num_joints: int | None = None, num_commanded: int | None = None) -> LaneMirror | None:
    """The lane mirror of a run's config (None for ``ppo.lane_frame: none``). Joint counts come
    from the task's robot description unless given."""
    if config.ppo.lane_frame == "none":
        return None
    if num_joints is None or num_commanded is None:
        from ahrm_stack.robot import describe, make_arm

        robot = describe(config.task.robot, make_arm(config.task.robot))
        num_joints, num_commanded = robot.num_joints, len(robot.commanded_joints)
    return make_lane_mirror(config.task, config.ppo.lane_frame, num_joints, num_commanded,
                            observation_dim, action_dim)


__all__ = ["LaneFrame", "LaneMirror", "lane_mirror_for", "make_lane_mirror",
           "observation_layout"]
