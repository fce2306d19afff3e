"""The whole configuration: :class:`Config`, the six sections of ``configs/`` together, and the
rules that span several of them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ahrm_stack.config.fields import LIMITS, Frozen
from ahrm_stack.config.learning import MechanismConfig, PPOConfig, TrainConfig
from ahrm_stack.config.safety import SafetyConfig, arm_acceleration_limit
from ahrm_stack.config.task import ScriptedConfig, TaskConfig
from ahrm_stack.schema import ConfigError, Section, read_yaml


@Frozen
class Config(Section):
    task: TaskConfig
    scripted: ScriptedConfig
    safety: SafetyConfig
    mechanism: MechanismConfig
    ppo: PPOConfig
    train: TrainConfig

    def derive(self) -> None:
        # safety.acceleration_limit: task.robot's values (from the per-arm mapping, or the one list
        # checked against the arm's joints), so that every reader of a loaded config, and the run's
        # config.yaml, has the list of the arm in use
        limit = arm_acceleration_limit(self.safety.acceleration_limit, self.task.robot, len(self.task.arm.home))
        if limit != self.safety.acceleration_limit:
            object.__setattr__(self, "safety", dataclasses.replace(self.safety, acceleration_limit=limit))

    def check(self, key: str) -> None:
        ppo, train, episode = self.ppo, self.train, self.task.episode
        if ppo.frames_per_batch % train.num_envs:
            raise ConfigError(f"ppo.frames_per_batch ({ppo.frames_per_batch}) must be a multiple of "
                              f"train.num_envs ({train.num_envs})")
        steps = round(episode.duration / episode.control_period)
        uses_demos = train.warm_start == "bc" or ppo.bc_coeff > 0
        if uses_demos and train.demo_episodes * steps > LIMITS["demo_steps"]:
            raise ConfigError(f"train.demo_episodes ({train.demo_episodes}) x {steps} steps per "
                              f"episode (task.episode.duration) exceeds {LIMITS['demo_steps']} "
                              "demonstration steps held in memory")
        if ppo.critic_privileged and uses_demos:
            raise ConfigError("ppo.critic_privileged needs train.warm_start: none and ppo.bc_coeff: 0 (the "
                              "demonstrations hold no privileged entries for the critic's refit)")
        if ppo.lane_frame != "none":
            task = self.task
            if ppo.lane_frame.startswith("mirror") and not task.observation.lane_choice:
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs task.observation.lane_choice: "
                                  "true (the episode's lane decides whether the policy's frame is mirrored)")
            if ppo.lane_frame == "tip_side_no_joints" and not task.observation.relative:
                raise ConfigError("ppo.lane_frame: tip_side_no_joints needs task.observation.relative: true "
                                  "(the tip's x relative to the cube decides whether the frame is mirrored)")
            if task.action.mode != "cartesian":
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs task.action.mode: cartesian (a "
                                  f"joint-velocity action has no mirror image), got {task.action.mode}")
            if set(task.layout.lane_directions) != {"+x", "-x"}:
                raise ConfigError(f"ppo.lane_frame: {ppo.lane_frame} needs both lanes, +x and -x, in "
                                  f"task.layout.lane_directions, got {list(task.layout.lane_directions)}")
        if train.expert == "policy":  # TrainConfig.check: teacher_run is then a run folder
            path = Path(train.teacher_run) / "config.yaml"
            theirs = read_yaml(path).get("task", {}).get("action", {})
            mine = self.task.action.to_dict()
            if not isinstance(theirs, dict) or {k: mine.get(k) for k in theirs} != theirs:
                raise ConfigError(f"train.teacher_run: {path}'s task.action ({theirs}) is not this run's ({mine}): "
                                  "the teacher's actions are the student's labels")
        if self.task.regions.distance_clip < self.mechanism.blend_band:
            raise ConfigError(f"task.regions.distance_clip ({self.task.regions.distance_clip} m) must "
                              f"be >= mechanism.blend_band ({self.mechanism.blend_band} m)")
