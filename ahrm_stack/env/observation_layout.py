"""The task's observation, described once (:func:`observation_terms`): each term of the flat
observation vector in order, its size and the composer observation keys it concatenates. Everything
else is read from it: where each part sits (:func:`observation_layout`, used by training's sensing
model, the lane frame and the deploy loop's builder), the composer observation's key order
(:attr:`~ahrm_stack.env.task_observation.TaskObservation.observation_order`), which task observables
are declared, and the flat vector itself (:meth:`~ahrm_stack.env.task_observation.TaskObservation.
flat_observation`, which computes each term by its name). A new observation is one term here and its
value in ``TaskObservation`` (a test checks that every term has one and that the flat vector equals
the composer observation's concatenation).

Positions in m, world frame; joint angles as (sin, cos) interleaved per joint; velocities in rad/s
and m/s."""

from __future__ import annotations

import dataclasses

from ahrm_stack.config import TaskConfig

PROP_SIZE = 6  # per free body: world position (3) then linear velocity (3)

#: the terms computed by the task itself (composer ``Generic`` observables), not read from an entity
TASK_TERMS = ("pusher_tip", "previous_action", "phase", "boundary_distance", "relative_to_cube",
              "lane_clearance", "lane_choice")


@dataclasses.dataclass(frozen=True)
class ObservationTerm:
    """One part of the flat observation: ``name`` (its layout key), ``size`` (floats) and the
    composer observation ``keys`` whose values it concatenates, in order."""

    name: str
    size: int
    keys: tuple[str, ...]


def observation_terms(task: TaskConfig, num_joints: int, num_commanded: int, arm: str = "arm",
                      props: tuple[str, ...] | None = None) -> tuple[ObservationTerm, ...]:
    """The flat observation's terms, in order. ``num_joints``: the arm's joints; ``num_commanded``:
    its commanded joints (the previous action's size); ``arm`` and ``props``: the composer model
    names of the arm and of the cube and obstacles (their observables' key prefixes; placeholders
    where only the layout is wanted). ``task.observation`` enables ``relative_to_cube``,
    ``lane_clearance`` and ``lane_choice``."""
    obstacles = len(task.obstacles.fixed_layout)
    names = props if props is not None else ("cube", *(f"obstacle_{i}" for i in range(obstacles)))
    lanes = len(task.layout.lane_directions)
    terms = [ObservationTerm("joints_pos", 2 * num_joints, (f"{arm}/joints_pos",)),
             ObservationTerm("joints_vel", num_joints, (f"{arm}/joints_vel",)),
             ObservationTerm("pusher_tip", 3, ("pusher_tip",))]
    for i, model in enumerate(names):
        terms.append(ObservationTerm("cube" if i == 0 else f"obstacle_{i - 1}", PROP_SIZE,
                                     (f"{model}/position", f"{model}/linear_velocity")))
    terms += [ObservationTerm("previous_action", num_commanded, ("previous_action",)),
              ObservationTerm("phase", 3, ("phase",)),
              ObservationTerm("boundary_distance", 1, ("boundary_distance",))]
    observation = task.observation
    optional = (("relative_to_cube", observation.relative, 3 + 2 * obstacles),
                ("lane_clearance", observation.lanes, lanes),
                ("lane_choice", observation.lane_choice, lanes))
    terms += [ObservationTerm(name, size, (name,)) for name, on, size in optional if on]
    return tuple(terms)


def observation_layout(task: TaskConfig, num_joints: int, num_commanded: int) -> dict[str, slice]:
    """Where each term of :meth:`~ahrm_stack.env.task.PushOffTask.flat_observation` sits (its name
    -> its slice; :func:`observation_terms`'s names: ``joints_pos``, ``joints_vel``,
    ``pusher_tip``, ``cube`` and ``obstacle_i`` (position then linear velocity),
    ``previous_action``, ``phase``, ``boundary_distance`` and the optional ones)."""
    layout, start = {}, 0
    for term in observation_terms(task, num_joints, num_commanded):
        layout[term.name] = slice(start, start + term.size)
        start += term.size
    return layout


__all__ = ["ObservationTerm", "PROP_SIZE", "TASK_TERMS", "observation_layout", "observation_terms"]
