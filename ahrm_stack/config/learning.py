"""The learning sections: the reward mechanism (``configs/mechanism.yaml``), PPO
(``configs/ppo.yaml``) and training (``configs/train.yaml``)."""

from __future__ import annotations

from pathlib import Path

import typing
from typing import Annotated, Any, Literal

from pydantic import AfterValidator

from ahrm_stack.config.fields import LIMITS, Frozen, Method, NonNeg, NonNegInt, Pos, PosInt
from ahrm_stack.names import OBJECTIVE_NAMES
from ahrm_stack.schema import (MISSING, Bool, ConfigError, Float, Section, Str, count, fail, le, legacy, legacy_rule,
                               within)


def _order(value: tuple[str, str, str]) -> tuple[str, str, str]:
    if sorted(value) != sorted(OBJECTIVE_NAMES):
        fail(f": {list(value)} must be a permutation of {list(OBJECTIVE_NAMES)}")
    return value


def _bc_coeff(ppo: typing.Mapping[str, Any], root: typing.Mapping[str, Any]) -> Any:
    """Legacy ``ppo.bc_coeff_final``: ``ppo.bc_coeff`` (a constant anchor before the schedule)."""
    return ppo.get("bc_coeff", MISSING)


Order = Annotated[tuple[Str, Str, Str], AfterValidator(_order)]  # objective names, first = highest


Window = Annotated[PosInt, le(LIMITS["window"])]


@Frozen
class MechanismConfig(Section):
    """Reward mechanisms of spec §4. Orders list objective names: avoid, manipulate, time."""

    method: Method
    fixed_order: Order  # FHRM: one order for every phase
    manual_orders: tuple[Order, Order, Order]  # MHRM, per phase
    initial_orders: tuple[Order, Order, Order]  # AHRM, per phase
    convergence_window: Window  # W episodes
    convergence_tolerance: Pos  # relative to max(1, |mean|)
    constraint_window: Window  # episodes averaged for tau
    constraint_min_steps: Window  # steps in a phase before the constraint is checked
    constraint_margin: NonNeg  # a per-step average below tau - margin ends the episode
    constraint_check: Annotated[Literal["running", "episode", "none"], legacy("running")]  # the priority
    # constraint (spec §4): running: the running per-step average, from constraint_min_steps steps of
    # a phase on, ends the episode as a truncation (the spec's [choice]) | episode: the paper's
    # Algorithm 1, checked once at the episode's end on each phase's per-step average; a violating
    # episode runs to its end and its transitions are left out of the update (those of the batch in
    # which it ends: an earlier batch's were already learned from) | none: never checked
    priority_period: Window  # P: visiting episodes between priority determinations
    # magnitude (spec Eqs. 3-5): |mean episode sum of f_i| high to low | violation: the per-step
    # average of f_i low to high (the most often violated objective first)
    priority_rule: Annotated[Literal["magnitude", "violation"], legacy("magnitude")]  # (legacy: before
    # 2026-12-02 the spec's ranking)
    blend_band: Pos  # delta, m
    blend_slope: Pos  # alpha, 1/m


LaneFrame = Literal["none", "mirror", "mirror_no_joints", "cube_side_no_joints", "tip_side_no_joints"]  # ppo.lane_frame (learning/lane_frame.py)


@Frozen
class PPOConfig(Section):
    """PPO hyper-parameters (spec §6). ``configs/ppo.yaml`` holds the learnability study's choices;
    the paper's Table I values are ``configs/profiles/paper.yaml``."""

    gamma: Annotated[Float, within(0, 1)]
    gae_lambda: Annotated[Float, within(0, 1)]
    frames_per_batch: Annotated[PosInt, le(LIMITS["frames_per_batch"])]
    mini_batch_size: PosInt
    epochs: Annotated[PosInt, le(LIMITS["epochs"])]
    learning_rate: Pos
    clip_epsilon: Pos
    entropy_coeff: NonNeg
    critic_coeff: NonNeg
    max_grad_norm: Pos  # the gradient's norm is clipped to this (per network with optimizer: separate)
    optimizer: Annotated[Literal["shared", "separate"], legacy("shared")]  # shared: one Adam and one
    # gradient clip over the actor and the critic together | separate: one each, as the paper's
    # MATLAB agent has (separate actor and critic representations, each with its own options)
    hidden_sizes: Annotated[tuple[Annotated[PosInt, le(LIMITS["hidden_width"])], ...],
                            count(1, LIMITS["hidden_layers"])]  # actor and critic layer widths
    activation: Literal["tanh", "relu", "elu"]
    init_std: Pos  # initial standard deviation of the (pre-tanh) Gaussian policy
    actor_init_scale: Annotated[Float, within(0, 1, "(]"), legacy(1.0)]  # the actor's output layer starts with its
    # initial weights and bias times this (1: the library's init; 0.01: Andrychowicz et al. 2021)
    std_mode: Literal["learned", "fixed", "scheduled"]  # scheduled: init_std -> final_std
    final_std: Pos  # std_mode scheduled: the standard deviation reached after std_schedule_frames
    std_schedule_frames: PosInt  # frames over which the std goes (log-linearly) to final_std
    target_kl: NonNeg  # stop a batch's epochs once the approximate KL exceeds 1.5x this (0: off)
    normalize_advantage: Bool  # scale each mini-batch's advantages to zero mean, unit std
    normalize_observations: Bool
    normalizer_clip: Pos  # normalised observations are clipped to +-this
    normalizer_min_std: Annotated[NonNeg, legacy(0.0)]  # the normaliser's per-feature scale is at least this (observation
    # units; 0: sqrt(var + 1e-8) as it is): a feature that barely varied in training cannot turn a
    # small measurement error into a saturated input (legacy: before 2026-12-04 no floor)
    update_normalizer: Bool  # keep updating its statistics from every batch (false: frozen once set)
    bc_coeff: NonNeg  # weight of a behaviour-cloning term toward the demonstrations (0: off)
    bc_coeff_final: Annotated[NonNeg, legacy_rule(_bc_coeff)]  # the anchor's weight goes linearly
    # from bc_coeff to this ...
    bc_decay_frames: Annotated[NonNegInt, legacy(0)]  # ... over this many frames (0: constant bc_coeff)
    reward_scale: Annotated[Pos, legacy(1.0)]  # rewards are multiplied by this before GAE (the critic
    # learns scaled returns)
    critic_privileged: Annotated[Bool, legacy(False)]  # an asymmetric critic: it also reads the
    # planner's lane (one-hot, in the lane frame), which the policy never sees; the critic is not
    # deployed, so a policy trained so stays planner-free at deployment (not "planner-free throughout")
    lane_frame: Annotated[LaneFrame, legacy("none")]  # the policy reads the world mirrored
    # x -> -x when the episode's lane is -x (learning/lane_frame.py); no_joints: joint entries zeroed;
    # cube_side_no_joints: mirrored when the cube's observed x is < 0 instead (no planner input);
    # tip_side_no_joints: mirrored when the tip is on the cube's +x side, per step (no planner input)

    def check(self, key: str) -> None:
        if self.frames_per_batch % self.mini_batch_size:
            raise ConfigError(f"{key}.frames_per_batch ({self.frames_per_batch}) must be a multiple of "
                              f"{key}.mini_batch_size ({self.mini_batch_size})")


@Frozen
class TrainConfig(Section):
    episodes: Annotated[PosInt, le(LIMITS["episodes"])]  # training stops after this many episodes
    seed: Annotated[NonNegInt, le(LIMITS["seed"])]
    runs_dir: Str  # run folders are created here (relative to the working directory)
    checkpoint_every: PosInt  # batches between checkpoints
    keep_checkpoints: Annotated[PosInt, le(LIMITS["keep_checkpoints"])]  # most recent kept on disk
    eval_episodes: Annotated[NonNegInt, le(LIMITS["eval_episodes"])]  # deterministic evaluation
    # episodes at the end of training (0: none)
    eval_every: NonNegInt  # also evaluate (eval_episodes) every this many training episodes (0: never)
    threads: Annotated[PosInt, le(LIMITS["threads"], " (training also refuses more than this "
                                                     "machine's CPU count)")]  # torch intra-op threads
    update_threads: Annotated[PosInt, le(LIMITS["threads"]), legacy(1)]  # torch threads for GAE and the PPO
    # epochs (the environments wait then); at most the machine's CPU count is used. More than 1 pays
    # only for a run alone on the machine (two runs at once with 2 each ran ~3x slower)
    warm_start: Literal["none", "bc"]  # bc: behaviour cloning from scripted demonstrations first
    demo_episodes: Annotated[PosInt, le(LIMITS["demo_episodes"])]  # scripted-controller episodes
    # recorded for warm start and the BC anchor
    bc_epochs: Annotated[PosInt, le(LIMITS["bc_epochs"])]  # passes over the demonstrations for
    # behaviour cloning and the critic refit
    bc_learning_rate: Pos
    demo_noise: NonNeg  # std of noise on the executed demonstration actions (normalised; labels clean)
    expert: Annotated[Literal["stateful", "stateless", "policy"], legacy("stateful")]  # the teacher of the demonstrations
    # and the DAgger labels: the scripted controller with its stages carried over from step to step, or inferred from
    # each state alone; policy: train.teacher_run's trained policy (the planner-taught route)
    teacher_run: Annotated[Str, legacy("")]  # expert: policy: the run folder (config.yaml, policy.pt) whose policy labels
    # the states, on its own observation (the terms this run's observation lacks, e.g. the planner's lane_choice, are
    # computed for it); its task.action must be this run's. Empty with the scripted experts
    num_envs: Annotated[PosInt, le(LIMITS["num_envs"])]  # environments stepped together (in one
    # process, sharing the reward mechanism)
    env_workers: Annotated[PosInt, legacy(1)]  # processes the num_envs environments are split over (1: the trainer's own)
    dagger_rounds: Annotated[NonNegInt, legacy(0)]  # after cloning: rounds of (run the clone, label its states with the
    # scripted controller, refit on all data so far); 0: none
    dagger_episodes: Annotated[PosInt, legacy(30)]  # episodes per round
    dagger_duration: Annotated[Pos, legacy(15.0)]  # s, a round's episode is cut after this much simulated time
    frames: Annotated[NonNegInt, legacy(0)]  # training stops once this many frames are collected (0: ``episodes`` decides)
    eval_every_frames: Annotated[NonNegInt, legacy(0)]  # ... or evaluate every this many frames (0: never); either triggers
    eval_beside: Annotated[Bool, legacy(False)]  # interim evaluations in a worker process while
    # training goes on (the same rows; ahrm_stack.learning.interim); false: in the training's process
    time_limit: Annotated[NonNeg, legacy(0.0)]  # s, training episodes are truncated here (0: task.episode.duration);
    # evaluation keeps task.episode.duration
    touch_end: Annotated[bool, legacy(False)]  # a touch of an obstacle ends a training episode as a terminal failure, its
    # step's reward lowered by touch_penalty(ppo.gamma) (evaluation: touches never end an episode)
    touch_end_after: Annotated[NonNegInt, legacy(0)]  # frames: with touch_end, touches end episodes only from this many
    # frames collected on (0: from the start)
    touch_cost_after: Annotated[NonNegInt, legacy(0)]  # frames: task.rewards.touch_cost is charged only from this many
    # frames collected on (0: from the start; legacy: before 2026-12-08 from the start)
    start_curriculum: Annotated[Literal["none", "near_cube", "scripted_states"], legacy("none")]  # near_cube: start near the
    # cube (task.arm.near_cube), more starts by task.arm.start as the level rises; scripted_states:
    # start from the scripted controller's recorded states, further back as the level rises
    curriculum_states: Annotated[PosInt, legacy(100)]  # scripted_states: scripted episodes recorded (the won ones are used)
    curriculum_window: Annotated[PosInt, legacy(50)]  # training episodes whose success rate decides a rise of the level
    curriculum_threshold: Annotated[Float, within(0, 1), legacy(0.5)]  # success rate over the window that raises it
    curriculum_step: Annotated[Float, within(0, 1, "(]"), legacy(0.25)]  # the level's rise (0 to 1; at 1 the task
    # draws every start)

    def check(self, key: str) -> None:
        if self.num_envs % self.env_workers:
            raise ConfigError(f"{key}.num_envs ({self.num_envs}) must be a multiple of "
                              f"{key}.env_workers ({self.env_workers})")
        if self.env_workers > 1 and self.start_curriculum == "scripted_states":
            raise ConfigError(f"{key}.start_curriculum ({self.start_curriculum}) needs "
                              f"{key}.env_workers: 1 (the recorded states are not sent to worker processes)")
        if not self.runs_dir.strip():
            raise ConfigError(f"{key}.runs_dir must name a folder, got {self.runs_dir!r}")
        if (self.expert == "policy") != bool(self.teacher_run.strip()):
            raise ConfigError(f"{key}.teacher_run names the teacher's run folder exactly when {key}.expert is policy "
                              f"(got expert {self.expert!r}, teacher_run {self.teacher_run!r})")
        if self.teacher_run.strip():
            folder = Path(self.teacher_run)
            missing = [name for name in ("config.yaml", "policy.pt") if not (folder / name).is_file()]
            if missing:
                raise ConfigError(f"{key}.teacher_run: {self.teacher_run!r} has no {' or '.join(missing)} "
                                  "(a finished run folder is the teacher)")
