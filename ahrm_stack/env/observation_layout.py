"""Where each part of the task's observation vector sits (:func:`observation_layout`): one
description read by the task's consumers (the lane frame, training's sensing model)."""

from __future__ import annotations

from ahrm_stack.config import TaskConfig

PROP_SIZE = 6  # per free body: world position (3) then linear velocity (3)


def observation_layout(task: TaskConfig, num_joints: int, num_commanded: int) -> dict[str, slice]:
    """Where each part of :meth:`~ahrm_stack.env.task.PushOffTask.flat_observation` sits.

    ``num_joints``: the arm's joints; ``num_commanded``: its commanded joints (the previous
    action's size). Keys: ``joints_pos`` (sin, cos per joint, interleaved), ``joints_vel``,
    ``pusher_tip``, ``cube`` and ``obstacle_i`` (position then linear velocity), ``previous_action``,
    ``phase``, ``boundary_distance`` and, as ``task.observation`` enables them,
    ``relative_to_cube``, ``lane_clearance``, ``lane_choice``."""
    sizes = [("joints_pos", 2 * num_joints), ("joints_vel", num_joints), ("pusher_tip", 3),
             ("cube", PROP_SIZE)]
    sizes += [(f"obstacle_{i}", PROP_SIZE) for i in range(len(task.obstacles.fixed_layout))]
    sizes += [("previous_action", num_commanded), ("phase", 3), ("boundary_distance", 1)]
    observation = task.observation
    lanes = len(task.layout.lane_directions)
    if observation.relative:
        sizes.append(("relative_to_cube", 3 + 2 * len(task.obstacles.fixed_layout)))
    if observation.lanes:
        sizes.append(("lane_clearance", lanes))
    if observation.lane_choice:
        sizes.append(("lane_choice", lanes))
    layout, start = {}, 0
    for name, size in sizes:
        layout[name] = slice(start, start + size)
        start += size
    return layout


__all__ = ["PROP_SIZE", "observation_layout"]
