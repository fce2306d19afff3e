"""The deployment loop: feedback → kinematics and phase → controller → safety filter → command.

Usage::

    python -m ahrm_stack.deploy --backend sim [--checkpoint RUN_DIR] [--duration S] [--rate HZ]
                                [--realtime | --fast] [--seed N] [--telemetry PATH]

Without ``--checkpoint`` the scripted mink controller drives the arm; with one, the run's
deterministic policy does (its ``config.yaml`` gives the task, so the arm model is the trained one).
Settings come from ``configs/deploy.yaml`` (:func:`load_deploy_settings`); the task, safety and
scripted sections from ``configs/*.yaml`` as in training.

The safety filter's settings are always deploy's own (``configs/safety.yaml``, plus ``key=value``
overrides for the scripted controller). A checkpoint's ``safety`` section may only tighten them
(:func:`merge_safety`: a larger margin, a lower limit, more rows, a smaller workspace box, a row
family turned on; each key's direction is the ``stricter(...)`` marker on its field of
:class:`~ahrm_stack.config.SafetyConfig`); a weaker value is ignored, and every difference is
printed (a WARNING naming the key for a weaker one) and written to the telemetry. Ignoring rather
than refusing lets a policy trained with a lighter filter (or none: an ablation) be deployed behind
the full one.

Exit status: 0 success; 1 the run ended without success (duration, watchdog, hardware stop);
2 bad input (settings, command line, checkpoint, a refused pickle: a one-line error, nothing
written, the arm never touched; or the arm not near the posture the policy was trained from:
one line, nothing moved, :mod:`~ahrm_stack.deploy.start_check`); 3 a software fault stopped the
arm (:class:`DeployFault`); 130 Ctrl-C / SIGTERM. ``--check`` measures the arm's link instead
(the Gen2 USB budget, the arm held still): 0 fits, 1 does not, 2 bad input, 3 no arm.

Every control period (``1 / rate_hz`` s) :class:`DeployLoop` does, in this order:

1. ``refresh_feedback`` — a dropped frame, a stale frame (repeated id or older than
   ``watchdog.max_feedback_age`` periods) or a lost connection stops the arm; a NaN reading, a fault
   flag, a joint past its position limit or a joint speed beyond ``(1 + velocity_tolerance)`` times
   its limit e-stops it;
2. perception (cube and obstacle poses) into :class:`WorldModel`, which computes the phase k, the
   boundary distance x and the training observation with the task's own code (the observation
   written into one preallocated vector, bit for bit the task's ``flat_observation``);
3. judging from perception (:mod:`~ahrm_stack.deploy.judging`, ``success``, ``touch`` and
   ``progress`` in ``configs/deploy.yaml``): the cube perceived past a table edge by a margin for
   several ticks stops the arm, and is a success unless perception has it back on the table
   during a settle time after the stop; an obstacle perceived displaced from its start position
   counts as touched; no task progress for ``progress.timeout`` s stops the arm (the watchdog);
4. the controller's nominal joint velocities (rad/s);
5. the QP safety filter with the obstacle rows on (a reported violation e-stops);
6. ``send_joint_speeds`` — the adapter re-checks the limits and e-stops on a bad command; a command
   not sent within ``watchdog.command_deadline`` periods of the tick is a missed deadline.

Ctrl-C (SIGINT) and SIGTERM stop the arm before the program exits. So does every fault: an
exception in start-up, perception, the world model, the controller or the filter, a wrong obstacle
count, or a controller request that is not finite (NaN from a policy is a fault, never zeroed):
the arm is commanded to zero velocity in the tick that sees it, the stop and its cause are logged,
and the run ends (:class:`DeployFault`). Every tick and every event is a line of the JSONL
telemetry log (time, phase, nominal and filtered command, active constraints, touched, loop
latency; events: stops, the success judgement, touches); every run, however it ends, closes with a
summary line (success, touched and which obstacles when, duration, interventions, deadline misses,
latency p50/p99, stop reason, fault).

Perception: the sim backend's :meth:`~ahrm_stack.sim_arm.SimArm.perception` stands in for a perception
module (exact poses from the simulator). The scripted controller needs object poses too; it runs on
the :class:`WorldModel`'s own mirror of the scene, fed only by feedback and perception, never on
the simulator's physics.

The package, one idea per module:

* :mod:`~ahrm_stack.deploy.settings` — ``configs/deploy.yaml`` and its validator;
* :mod:`~ahrm_stack.deploy.safety_settings` — the filter's settings, a checkpoint may only tighten;
* :mod:`~ahrm_stack.deploy.world` — :class:`WorldModel`, the mirror of the scene;
* :mod:`~ahrm_stack.deploy.controllers` — the scripted and the policy controller;
* :mod:`~ahrm_stack.deploy.policy` — :class:`~ahrm_stack.deploy.policy.NumpyPolicy`, the policy's
  forward pass in NumPy on preallocated arrays (the policy controller's fast path);
* :mod:`~ahrm_stack.deploy.judging` — how a run went, from perception: success, touching, progress;
* :mod:`~ahrm_stack.deploy.start_check` — does the arm start where the policy was trained to start;
* :mod:`~ahrm_stack.deploy.loop` — :class:`DeployLoop`, its summary and faults;
* :mod:`~ahrm_stack.deploy.run` — building one run (config, telemetry, adapter, loop);
* :mod:`~ahrm_stack.deploy.bring_up` — the steps before a run: ``--check`` (the link, the arm held
  still) and ``--home`` (to the start posture, after a typed confirmation);
* :mod:`~ahrm_stack.deploy.cli` — the command line (:func:`main`; the backend is chosen in
  :func:`~ahrm_stack.deploy.cli.run_backend`).

How a policy's action becomes the filter's request, and which filter method takes it, is
:mod:`ahrm_stack.env.control_step` — the same code as in training.
"""

from ahrm_stack.deploy.cli import main, run_backend
from ahrm_stack.deploy.controllers import PolicyController, PolicyStructureError, ScriptedController, make_controller
from ahrm_stack.deploy.loop import DeployFault, DeployLoop, DeploySummary
from ahrm_stack.deploy.run import deploy, deploy_sim, load_controller_config, open_telemetry
from ahrm_stack.deploy.safety_settings import SafetyNote, merge_safety, require_filter, safety_directions
from ahrm_stack.deploy.settings import (DEPLOY_CONFIG, DeployConfigError, DeploySettings,
                                        KortexSection, ProgressSettings, SimSettings,
                                        StartPostureSettings, SuccessSettings, TouchSettings,
                                        WatchdogSettings,
                                        control_periods, deploy_settings_from_dict,
                                        load_deploy_settings)
from ahrm_stack.deploy.world import WorldModel

__all__ = ["DEPLOY_CONFIG", "DeployConfigError", "DeployFault", "DeployLoop", "DeploySettings", "DeploySummary",
           "KortexSection", "PolicyController", "PolicyStructureError", "ProgressSettings", "SafetyNote",
           "ScriptedController",
           "SimSettings", "StartPostureSettings", "SuccessSettings", "TouchSettings", "WatchdogSettings", "WorldModel",
           "control_periods", "deploy_settings_from_dict", "deploy", "deploy_sim",
           "load_controller_config", "load_deploy_settings", "main", "make_controller", "merge_safety",
           "open_telemetry", "require_filter", "run_backend", "safety_directions"]
