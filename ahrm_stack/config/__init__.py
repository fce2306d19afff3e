"""Typed, validated configuration read from the YAML files in ``configs/``.

Every tunable number of the project lives in ``configs/*.yaml``; this package describes those files
as frozen dataclasses (:class:`ahrm_stack.schema.Section`) whose fields carry their rules, and turns
the files into them once, at start-up, with pydantic (``ahrm_stack/schema.py``). Anything it does not
recognise is refused with one line that names the dotted key, the rule or the allowed keys/values,
and the file (or "override"), e.g. ``ppo.learning_rate must be > 0, got -1.0 (override)``.

One idea per module; this ``__init__`` re-exports the names the rest of the project imports:

* ``fields.py``: the shared field types (``Pos``, ``PosInt``, ``Pair`` ...) and :data:`LIMITS`;
* ``task.py``: :class:`TaskConfig` and its sections, :class:`ScriptedConfig`;
* ``safety.py``: :class:`SafetyConfig` (and :func:`arm_acceleration_limit`, the arm in use's
  ``safety.acceleration_limit``); ``learning.py``: mechanism, PPO and training sections;
* ``root.py``: :class:`Config`, the six sections and the rules across them;
* ``files.py``: where the YAML files live; ``load.py``: files, profiles and overrides to a
  :class:`Config` (:func:`load_config`, :func:`config_from_dict`, :func:`fill_missing`);
* ``extra.py``: the video and experiment files (:func:`load_extra`); ``robots.py``: arms built
  from a URDF (:func:`load_robot_config`).

Field comments state units. Defaults are NOT given in the sections: every value comes from YAML
(fields marked ``derived()`` are computed from others and never read or written).

Overrides use dotted keys, e.g. ``task.layout.mode=random`` or ``task.episode.duration=30``; values
are parsed as YAML scalars/lists. ``config.to_dict()`` is the YAML-shaped mapping a run folder's
``config.yaml`` stores; :func:`config_from_dict` reads it back into an equal object.

To add a key: the field in its section (in the module above that holds it), with its rules and
markers and a comment with units, and its line in the section's YAML file; nothing else. E.g.::

    collect_workers: Annotated[PosInt, le(LIMITS["num_envs"]), legacy(1)]  # processes
    table_margin: Annotated[NonNeg, stricter("higher")]  # m (a key of the safety section)

The markers (``ahrm_stack/schema.py``) hold the per-key rules that are not validation:

* ``legacy(value)`` (or ``legacy_rule(f)``): the value a run folder written before the key existed
  behaved as, a literal (so an old run does not change when a default in ``configs/`` does). A
  run's ``config.yaml`` that lacks the key gets it (:func:`fill_missing`, one generic filler), so
  old runs and checkpoints load, resume and take overrides of the new key. A key without the
  marker is required: an old file without it is refused, naming the key.
* ``stricter(direction)``, required on every key of :class:`SafetyConfig` (a test fails without
  it): ``on``, ``higher``, ``lower`` or ``none`` (no order). Deploy's
  :func:`~ahrm_stack.deploy.merge_safety` reads it: a checkpoint's safety value is used where it
  is stricter than deploy's, ignored (with a note) where it is weaker.

A run folder's ``config.yaml`` is ``{schema_version: SCHEMA_VERSION, **config.to_dict()}``
(:func:`ahrm_stack.run_config.run_config_text`); every reader goes through
:func:`ahrm_stack.run_config.load_run_config`. Renaming or removing a key raises
:data:`SCHEMA_VERSION` with a conversion step in :func:`fill_missing`, and
``python -m ahrm_stack.run_config docs`` rewrites the committed run folders. Rules over several
keys go in the section's ``check``.
"""

from __future__ import annotations

from ahrm_stack.config.extra import ExperimentConfig, PaperRow, VideoConfig, load_extra
from ahrm_stack.config.fields import LIMITS, Frozen, Method, NonNeg, NonNegInt, Pair, Pos, PosInt, Vec3
from ahrm_stack.config.files import CONFIG_DIR, PROFILE_DIR, ROBOTS_DIR, SECTIONS
from ahrm_stack.config.learning import LaneFrame, MechanismConfig, Order, PPOConfig, TrainConfig, Window
from ahrm_stack.config.load import (SCHEMA_VERSION, apply_overrides, config_from_dict, config_source, fill_missing,
                                    load_config, load_raw, profile_overrides)
from ahrm_stack.config.robots import ArmEntry, UrdfArmConfig, arm_names, compose_deploy, compose_task, load_arm
from ahrm_stack.config.root import Config
from ahrm_stack.config.safety import (SELF_COLLISION_PAIRS_2026_12_01, AccelerationLimits, SafetyConfig,
                                      SelfCollisionPairs, arm_acceleration_limit)
from ahrm_stack.config.task import (ActionConfig, ArmConfig, CubeConfig, EpisodeConfig, HomeDeg, LayoutConfig,
                                    NearCubeStartConfig, ObservationConfig, ObstacleConfig, PusherConfig, RegionConfig,
                                    RewardConfig, Robot, ScriptedConfig, StartIKConfig, TableConfig, TaskConfig)
from ahrm_stack.schema import ConfigError, read_yaml

_read_yaml = read_yaml  # the earlier name, still imported by a few modules

__all__ = [
    "AccelerationLimits", "ActionConfig", "ArmConfig", "ArmEntry", "CONFIG_DIR", "Config", "ConfigError", "CubeConfig",
    "EpisodeConfig",
    "ExperimentConfig", "Frozen", "HomeDeg", "LIMITS", "LaneFrame", "LayoutConfig", "MechanismConfig", "Method",
    "NearCubeStartConfig", "NonNeg", "NonNegInt", "ObservationConfig", "ObstacleConfig", "Order", "PPOConfig",
    "PROFILE_DIR", "Pair", "PaperRow", "Pos", "PosInt", "PusherConfig", "ROBOTS_DIR", "RegionConfig",
    "RewardConfig", "Robot", "SCHEMA_VERSION", "SECTIONS", "SELF_COLLISION_PAIRS_2026_12_01",
    "SafetyConfig", "ScriptedConfig", "SelfCollisionPairs", "StartIKConfig", "TableConfig", "TaskConfig",
    "TrainConfig", "UrdfArmConfig", "Vec3", "VideoConfig", "Window", "apply_overrides", "arm_acceleration_limit",
    "arm_names",
    "compose_deploy", "compose_task", "config_from_dict",
    "config_source", "fill_missing", "load_arm", "load_config", "load_extra", "load_raw",
    "profile_overrides",
]
