"""The QP safety filter (spec §5): one call per control step, in training, evaluation and
deployment::

    safety = make_task_filter(task, config.safety,  # ahrm_stack.env.control_step
                              scene=task.make_collision_scene(physics))  # for the distance rows
    stats = InterventionStats()
    safety.reset(); stats.reset()                     # at episode start
    result = safety(q, dq, u_nom)                     # joint mode: rad/s in, rad/s out
    result = safety.cartesian(q, dq, v_nom)           # Cartesian mode: tip velocity in m/s
    runner.step_only(result.command); stats.add(result)

How a policy's action becomes ``u_nom`` or ``v_nom``, and which of the two calls takes it, is
:mod:`ahrm_stack.env.control_step` (training, demonstrations and deploy alike).

With obstacle rows on, keep the scene's objects current first:
``scene.update_objects(cube_position, cube_rotation, obstacle_positions, obstacle_rotations)``.
"""

from ahrm_stack.safety.constraints import ConstraintDefinitionError
from ahrm_stack.safety.filter import SafetyFilter, SafetyFilterError, braking_time, make_filter
from ahrm_stack.safety.result import FilterResult, InterventionStats

__all__ = ["ConstraintDefinitionError", "FilterResult", "InterventionStats", "SafetyFilter",
           "SafetyFilterError", "braking_time", "make_filter"]
