"""Demonstrations from the scripted mink controller, behaviour cloning and the critic refit.

A demonstration step records the observation the learner would see and the normalised action
that reproduces the controller's request, in the learner's action mode (the inverse map of
:class:`~ahrm_stack.env.control_step.ControlStep`, whose forward map executes it):

- ``action.mode: joint``: a = clip(u[j] / v_max[j], -1, 1) for the commanded joints j (joint 6
  only spins the symmetric pusher and is held at zero, as for the learner), u the mink IK's
  joint velocities;
- ``action.mode: cartesian``: a = clip(v / cartesian_max_speed, -1, 1), v the controller's
  desired tip velocity (m/s, world frame), executed by the safety filter's differential IK exactly
  as the learner's actions are.

Either way the commands go through the same safety filter as the learner's. The teacher is
``train.expert``: the controller with its stages carried over from step to step (``stateful``)
or inferred from each state alone (``stateless``, which also re-approaches a cube it lost), or a
trained policy (``policy``, :class:`_PolicyTeacher`: ``train.teacher_run``'s, on its own
observation; the *planner-taught* route when that policy is planner-assisted and this run's
observation has no planner output). With
``train.demo_noise`` > 0 the executed action is the controller's plus Gaussian noise of that
standard deviation (normalised units) while the recorded label stays the controller's own action
(DART: the demonstrations then cover the states a slightly wrong policy visits, and show how to
recover from them).

Warm start (``train.warm_start: bc``): fit the actor's mean to the demonstrated actions
(pre-tanh, MSE on atanh(a)), then fit the critic to the demonstrations' discounted returns under
the reward mechanism's initial state. The same data serves as the anchor of the PPO update
(``ppo.bc_coeff``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch
from tensordict import TensorDict

from ahrm_stack.config import Config
from ahrm_stack.env.episode_loop import Step
from ahrm_stack.env.episode_loop import episode as episode_steps
from ahrm_stack.env.observation_layout import observation_layout, observation_terms
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.scripted import ScriptedPusher
from ahrm_stack.env.task import PushOffTask, StepInfo
from ahrm_stack.learning.mechanisms import RewardMechanism
from ahrm_stack.seeds import seed_table

DEMO_SEED_OFFSET = seed_table()["demonstrations"].start  # configs/seeds.yaml: disjoint from the rest
ACTION_LIMIT = 0.995  # demonstrated actions are kept inside the tanh's open interval


class _Teacher:
    """The scripted controller on its own task and runner, in the learner's action mode: labels a
    state with the controller's normalised action and executes a normalised action through the
    safety filter, as the learner's actions are."""

    def __init__(self, config: Config) -> None:
        self.task = PushOffTask(config.task)
        self.runner = TaskRunner(self.task, seed=DEMO_SEED_OFFSET, safety=config.safety)
        self.control = self.runner.control  # the learner's action <-> filter request maps
        self.controller = ScriptedPusher(self.task, config.scripted)
        self.mechanism = RewardMechanism(config.mechanism)
        self.stateless = config.train.expert == "stateless"

    def reset(self, episode: int) -> None:
        """Demonstration episode ``episode``: seed ``DEMO_SEED_OFFSET + episode``."""
        self.runner.seed(DEMO_SEED_OFFSET + episode)
        self.runner.reset()
        self.controller.reset(self.runner.physics)

    def label(self) -> np.ndarray:
        """The controller's action in the current state, normalised and clipped to ACTION_LIMIT."""
        physics = self.runner.physics
        # the controller's request in the learner's mode: tip velocity (m/s) or joints (rad/s)
        stateless = self.stateless
        request = (self.controller.tip_velocity(physics, stateless) if self.control.cartesian
                   else self.controller(physics, stateless))
        return np.clip(self.control.action(request), -ACTION_LIMIT, ACTION_LIMIT)

    def episode(self, episode: int, choose: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Iterator[Step]:
        """Demonstration episode ``episode`` (seed ``DEMO_SEED_OFFSET + episode``): in each state,
        ``choose(observation, label)`` gives the normalised action executed (:meth:`label`: the
        controller's); the steps as :func:`~ahrm_stack.env.episode_loop.episode` yields them."""

        def act() -> tuple[np.ndarray, StepInfo, bool, bool]:
            observation = self.runner.flat_observation()
            action = choose(observation, self.label())
            return (action, *self.runner.step_action(action))

        return episode_steps(self.runner, DEMO_SEED_OFFSET + episode, act, self.controller.reset)

    def gave_up(self) -> bool:
        """Whether the teacher has no useful label any more in this episode (the controller pushed
        past the table edge without success: its ``hold`` stage)."""
        return self.controller.stage == "hold"

    def reward(self, info: StepInfo) -> float:
        """The reward mechanism's reward for a step (in its initial state)."""
        return float(self.mechanism.reward(info.g, info.distances))

    def execute(self, action: np.ndarray) -> tuple[float, bool, bool]:
        """One control step with the normalised ``action``, exactly as the learner's actions are
        executed (:meth:`TaskRunner.step_action`: clipped to [-1, 1], through the safety filter);
        returns the mechanism's reward, terminated (success) and truncated."""
        info, terminated, truncated = self.runner.step_action(action)
        return self.reward(info), terminated, truncated


class _PolicyTeacher(_Teacher):
    """A trained policy as the teacher (``train.expert: policy``): ``train.teacher_run``'s
    deterministic action on the observation *its* config describes, assembled in each state from
    this run's (noise-free) observation vector, term by term (:func:`observation_terms`), with the
    terms this run does not observe computed by the task (e.g. ``lane_choice``, the scripted
    planner's lane: the teacher may see it, the student never does). Its action is the learner's
    normalised action: both runs' ``task.action`` must be the same."""

    def __init__(self, config: Config) -> None:
        super().__init__(config)
        from ahrm_stack.learning.ppo import LeanActor
        from ahrm_stack.learning.rollouts import load_policy  # (rollouts imports the env stack)

        teacher_config, policy = load_policy(Path(config.train.teacher_run))  # the same task.action (Config.check)
        self.policy: LeanActor = policy  # type: ignore[assignment]  # load_policy returns the lean actor
        robot = self.task.robot
        joints, commanded = robot.num_joints, len(robot.commanded_joints)
        self._mine = observation_layout(config.task, joints, commanded)
        self._terms = observation_terms(teacher_config.task, joints, commanded)
        for term in self._terms:
            mine = self._mine.get(term.name)
            if mine is not None and mine.stop - mine.start != term.size:
                raise ValueError(f"train.teacher_run: the teacher's observation term {term.name!r} has "
                                 f"{term.size} floats, this run's {mine.stop - mine.start}")
        self._values = self.task._term_values()

    def teacher_observation(self) -> np.ndarray:
        """The teacher's observation vector in the current state."""
        physics = self.runner.physics
        mine = self.task.flat_observation(physics)  # noise-free; the sensing model is not asked
        return np.concatenate([mine[self._mine[t.name]] if t.name in self._mine
                               else np.asarray(self._values[t.name](physics), dtype=float).ravel()
                               for t in self._terms])

    def label(self) -> np.ndarray:
        """The teacher policy's action in the current state, clipped to ACTION_LIMIT."""
        observation = torch.as_tensor(self.teacher_observation(), dtype=torch.float32)
        with torch.no_grad():
            action = self.policy.act(observation).numpy().astype(float)
        return np.clip(action, -ACTION_LIMIT, ACTION_LIMIT)

    def gave_up(self) -> bool:
        return False


def _teacher(config: Config) -> _Teacher:
    """The teacher ``train.expert`` names."""
    return _PolicyTeacher(config) if config.train.expert == "policy" else _Teacher(config)


def _dataset(observations: list, actions: list, returns: list) -> TensorDict:
    return TensorDict({
        "observation": torch.as_tensor(np.array(observations), dtype=torch.float32),
        "action": torch.as_tensor(np.array(actions), dtype=torch.float32),
        "return": torch.as_tensor(np.array(returns), dtype=torch.float32).unsqueeze(-1),
    }, batch_size=[len(observations)])


def _discounted(rewards: list[float], gamma: float) -> list[float]:
    discounted, running = [], 0.0
    for reward in reversed(rewards):
        running = reward + gamma * running
        discounted.append(running)
    return discounted[::-1]


def _demonstrate(teacher: _Teacher, episode: int, noise: np.random.Generator,
                 noise_std: float) -> tuple[list[np.ndarray], list[np.ndarray], list[float], bool]:
    """One demonstration episode: the observations, the controller's labels, the rewards and
    whether it succeeded; the executed action is the label plus ``noise_std`` Gaussian noise."""
    observations: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    rewards: list[float] = []

    def choose(observation: np.ndarray, label: np.ndarray) -> np.ndarray:
        observations.append(observation)
        labels.append(label)
        return label + noise.normal(0.0, noise_std, label.shape) if noise_std > 0 else label

    for step in teacher.episode(episode, choose):
        if step.sent is not None:
            rewards.append(teacher.reward(step.info))
    return observations, labels, rewards, step.terminated


def collect_demonstrations(config: Config, episodes: int) -> TensorDict:
    """Run the teacher (``train.expert``) for ``episodes`` seeded episodes; successful episodes only.

    Returns a flat TensorDict with ``observation``, ``action`` (normalised, commanded joints) and
    ``return`` (discounted return under the initial reward-mechanism state, ``ppo.gamma``).
    """
    teacher = _teacher(config)
    noise_std = config.train.demo_noise
    noise = np.random.default_rng(DEMO_SEED_OFFSET)
    observations, actions, returns = [], [], []
    for episode in range(episodes):
        obs, act, rewards, success = _demonstrate(teacher, episode, noise, noise_std)
        if not success:
            continue
        observations += obs
        actions += act
        returns += _discounted(rewards, config.ppo.gamma)  # success is terminal: no bootstrap
    if not observations:
        raise RuntimeError(f"the teacher ({config.train.expert}) produced no successful demonstration")
    return _dataset(observations, actions, returns)


def collect_corrections(config: Config, actor, episodes: int, first_episode: int) -> TensorDict:
    """DAgger: run ``actor`` (deterministic, plus ``train.demo_noise`` on the executed action)
    and label every state it visits with the teacher's action for that state (``train.expert``).

    Episodes use the demonstration seeds ``DEMO_SEED_OFFSET + first_episode + i`` (after the
    demonstrations', so new layouts) and stop at success, after ``train.dagger_duration`` s, or
    when the controller has pushed past the table edge without success (its ``hold`` stage).
    The controller is reset at each episode start and queried at every step; with
    ``train.expert: stateless`` its stage is inferred from each state alone
    (:meth:`~ahrm_stack.env.scripted.ScriptedPusher.infer_stage`), so a state's label does not
    depend on the path the actor took to it (with ``stateful`` the stage follows the tip the actor
    moves, and states that look alike can get opposite labels). Returns the same keys as
    :func:`collect_demonstrations`; ``return`` is the executed episode's discounted return (no
    bootstrap when cut), only used to warm the critic.
    """
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    teacher = _teacher(config)
    noise = np.random.default_rng(DEMO_SEED_OFFSET + first_episode)
    max_steps = int(round(config.train.dagger_duration / config.task.episode.control_period))
    observations, actions, returns = [], [], []
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for episode in range(first_episode, first_episode + episodes):
            teacher.reset(episode)
            rewards = []
            for _ in range(max_steps):
                observation = teacher.runner.flat_observation()
                label = teacher.label()
                if teacher.gave_up():  # e.g. pushed past the edge: no useful label
                    break
                observations.append(observation)
                actions.append(label)
                out = actor(TensorDict({"observation": torch.as_tensor(observation, dtype=torch.float32)}, []))
                executed = out["action"].numpy().astype(float)
                if config.train.demo_noise > 0:
                    executed = executed + noise.normal(0.0, config.train.demo_noise, executed.shape)
                reward, terminated, truncated = teacher.execute(executed)
                rewards.append(reward)
                if terminated or truncated:
                    break
            returns += _discounted(rewards, config.ppo.gamma)
    return _dataset(observations, actions, returns)


def bc_loss(actor, batch: TensorDict) -> torch.Tensor:
    """MSE between the actor's pre-tanh mean and atanh of the demonstrated actions."""
    out = actor.module[0](batch.select("observation").clone())  # normaliser + network: loc, scale
    target = torch.atanh(batch["action"].clamp(-ACTION_LIMIT, ACTION_LIMIT))
    return torch.mean((out["loc"] - target) ** 2)


def warm_start(modules, demos: TensorDict, epochs: int, learning_rate: float,
               batch_size: int, generator: torch.Generator,
               normalizer_data: TensorDict | None = None) -> dict[str, float]:
    """Behaviour cloning of the actor and a critic refit to the demonstrations' returns.

    The observation normaliser first takes in ``normalizer_data`` (default: ``demos``); a DAgger
    refit passes only the new observations, since its statistics already hold the older ones."""
    modules.normalizer.update(modules.framed((demos if normalizer_data is None else normalizer_data)["observation"]))
    actor_params = [p for p in modules.actor.parameters() if p.requires_grad]
    critic_params = [p for p in modules.critic.parameters() if p.requires_grad]
    actor_opt = torch.optim.Adam(actor_params, lr=learning_rate)
    critic_opt = torch.optim.Adam(critic_params, lr=learning_rate)
    n = demos.shape[0]
    for _ in range(epochs):
        order = torch.randperm(n, generator=generator)
        for start in range(0, n, batch_size):
            batch = demos[order[start:start + batch_size]]
            loss = bc_loss(modules.actor, batch)
            actor_opt.zero_grad()
            loss.backward()
            actor_opt.step()
            value = modules.critic(batch.select("observation").clone())["state_value"]
            critic_loss = torch.mean((value - batch["return"]) ** 2)
            critic_opt.zero_grad()
            critic_loss.backward()
            critic_opt.step()
    with torch.no_grad():
        final_bc = float(bc_loss(modules.actor, demos))
        value = modules.critic(demos.select("observation").clone())["state_value"]
        final_critic = float(torch.mean((value - demos["return"]) ** 2))
    return {"bc_loss": final_bc, "critic_loss": final_critic, "demo_steps": float(n)}
