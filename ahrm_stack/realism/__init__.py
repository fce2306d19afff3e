"""A real arm's imperfections, one module each, composed alike by training's runner
(:class:`~ahrm_stack.env.runner.TaskRunner`, ``task.realism``) and the sim backend's arm
(:class:`~ahrm_stack.sim_arm.SimArm`, ``deploy.sim.realism``), so that the robustness
evaluation measures the imperfections the policy trained under:

* :mod:`~ahrm_stack.realism.config`: :class:`RealismConfig`, the named sets (``configs/realism.yaml``),
  the groups the robustness evaluation applies one at a time;
* :mod:`~ahrm_stack.realism.actuation`: the command path (latency, actuator lag);
* :mod:`~ahrm_stack.realism.sensing`: the measurement path (joint feedback noise and quantisation,
  perception noise and latency);
* :mod:`~ahrm_stack.realism.dynamics`: the cube's and obstacles' mass and friction per episode.

A new imperfection is one module here, acting on the command path or the measurement path, its
keys on :class:`RealismConfig` with its group in :data:`GROUPS`; ``tests/test_realism_paths.py``
drives one command sequence through both compositions and requires the same actuator output and
measurements.
"""

from ahrm_stack.realism.actuation import ActuatorModel
from ahrm_stack.realism.config import (GROUPS, REALISM_FILE, SCALES, RealismConfig, nominal, realism_profiles,
                                       resolve_realism)
from ahrm_stack.realism.dynamics import DynamicsVariation, draw_dynamics
from ahrm_stack.realism.sensing import JointSensing, ObjectSensing, PerceptionDelay, measure

__all__ = ["ActuatorModel", "DynamicsVariation", "GROUPS", "JointSensing", "ObjectSensing", "PerceptionDelay",
           "REALISM_FILE", "RealismConfig", "SCALES", "draw_dynamics", "measure", "nominal", "realism_profiles",
           "resolve_realism"]
