"""Evaluation with a deterministic policy: the paper's Table II metrics (spec §7).

Episodes use fresh seeds (``seed_offset + i``), distinct from training's, and the distribution's
deterministic action; by default the validation split of the run's own layouts
(``configs/seeds.yaml`` ``evaluation.run.validation``): every evaluation a training makes uses it,
never the sealed test split. Metrics: successes, success rate, episodes touching an obstacle, time to
success (mean ± std over successes, s), cube travel (mean ± std, m), safety-filter interventions
per episode and joint-limit violations.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
import yaml
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ahrm_stack.config import Config
from ahrm_stack.run_config import load_run_config
from ahrm_stack.env.episode import EpisodeSummary
from ahrm_stack.env.episode_loop import Act
from ahrm_stack.realism import nominal
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.checkpoint import load
from ahrm_stack.learning.lane_frame import lane_mirror_for
from ahrm_stack.learning.ppo import LeanActor, lean_actor, make_modules
from ahrm_stack.seeds import evaluation_range

# configs/seeds.yaml: the run's own layouts, validation split (disjoint from training and from test)
VALIDATION_SEED_OFFSET = evaluation_range("run", "validation").start


@dataclasses.dataclass
class EvaluationTable:
    episodes: int
    successes: int
    touched_episodes: int
    time_mean: float
    time_std: float
    travel_mean: float
    travel_std: float
    interventions_per_episode: float
    joint_limit_violations: int

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else float("nan")

    @classmethod
    def from_summaries(cls, summaries: list[EpisodeSummary]) -> "EvaluationTable":
        times = [s.time_to_success for s in summaries if s.success]
        travel = [s.cube_travel for s in summaries]
        return cls(len(summaries), sum(s.success for s in summaries),
                   sum(s.touched for s in summaries),
                   float(np.mean(times)) if times else float("nan"),
                   float(np.std(times)) if times else float("nan"),
                   float(np.mean(travel)), float(np.std(travel)),
                   float(np.mean([s.interventions for s in summaries])),
                   sum(s.joint_limit_violations for s in summaries))

    def __str__(self) -> str:
        return (f"episodes {self.episodes} | successes {self.successes} ({self.success_rate:.1%}) | "
                f"touched obstacles {self.touched_episodes} | time {self.time_mean:.2f} ± "
                f"{self.time_std:.2f} s | cube travel {self.travel_mean:.4f} ± {self.travel_std:.4f} m | "
                f"interventions/episode {self.interventions_per_episode:.1f} | "
                f"joint-limit violations {self.joint_limit_violations}")


def load_policy(run_dir: Path, policy_file: Path | None = None,
                runnable: bool = True) -> tuple[Config, Callable[[TensorDict], TensorDict]]:
    """The run's config and its deterministic policy (``policy_file``, default the final
    ``policy.pt``; loaded safely).

    The policy is the actor's lean inference path (:class:`~ahrm_stack.learning.ppo.LeanActor`:
    TensorDict in, ``"action"`` written; ``.act(observation)`` on a plain tensor), which gives the
    deterministic action of the TorchRL actor at a fraction of its per-call cost."""
    run_dir = Path(run_dir)
    config = load_run_config(run_dir, runnable=runnable)
    saved = load(Path(policy_file) if policy_file is not None else run_dir / "policy.pt")
    modules = make_modules(config.ppo, saved["observation_dim"], saved["action_dim"],
                           lane_mirror_for(config, saved["observation_dim"], saved["action_dim"]))
    modules.actor.load_state_dict(saved["actor"])
    modules.actor.eval()
    return config, lean_actor(modules.actor)


def policy_act(runner: TaskRunner, policy) -> Act:
    """A deterministic policy's control step on ``runner`` for
    :func:`~ahrm_stack.env.episode_loop.episode`: the runner's observation vector in, the policy's
    normalised action (``policy.act``, e.g. from :func:`load_policy`) executed through the filter."""

    def act():
        observation = torch.as_tensor(runner.flat_observation(), dtype=torch.float32)
        action = policy.act(observation).numpy()
        return (action, *runner.step_action(action))

    return act


def run_episodes(env: PushOffEnv, policy, episodes: int,
                 seed_offset: int = VALIDATION_SEED_OFFSET) -> list[EpisodeSummary]:
    """Deterministic episodes ``seed_offset + i``. An actor built by ``make_modules`` runs through
    its lean inference path (same action, cheaper); any other callable is used as it is."""
    policy = lean_actor(policy) or policy
    summaries = []
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        for i in range(episodes):
            env.set_seed(seed_offset + i)
            env.completed.clear()
            if isinstance(policy, LeanActor):
                _lean_episode(env, policy)
            else:
                env.rollout(max_steps=env.task.config.max_steps, policy=policy, break_when_any_done=True)
            summaries += env.completed
    return summaries


def _lean_episode(env: PushOffEnv, policy: LeanActor) -> None:
    """One episode of ``env.rollout(policy, break_when_any_done=True)`` without TorchRL's per-step
    TensorDicts: the same resets, observations (one ``flat_observation`` call per state, as the
    environment's ``_observation`` makes), float32 actions and steps, so the same
    :attr:`PushOffEnv.completed` summary (``tests/test_rollouts_lean.py`` holds it to the rollout)."""
    env.begin()
    observation = torch.as_tensor(env.runner.flat_observation(), dtype=torch.float32)
    for _ in range(env.task.config.max_steps):
        _, _, terminated, truncated = env.advance(policy.act(observation).numpy())
        observation = torch.as_tensor(env.runner.flat_observation(), dtype=torch.float32)
        if terminated or truncated:
            return


def write_episodes_csv(path: Path, summaries: list[EpisodeSummary],
                       extra: Sequence[dict[str, object]] | None = None) -> None:
    """One row per episode: the summary's fields and its failure mode, then ``extra``'s columns
    (one mapping per episode, e.g. the evaluation's lane agreement) when given."""
    rows = [dataclasses.asdict(s) | {"failure_mode": s.failure_mode()} for s in summaries]
    for row in rows:  # an evaluation writes its own lane columns (extra); training's bookkeeping
        for key in ("events", "end_order", "lane_agrees"):
            row.pop(key, None)
    if extra is not None:
        if len(extra) != len(rows):
            raise ValueError(f"{len(extra)} extra rows for {len(rows)} episodes")
        rows = [row | more for row, more in zip(rows, extra)]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def evaluate_run(run_dir: Path, episodes: int) -> EvaluationTable:
    """The run's deterministic evaluation at the end of training, on its own distribution's
    validation split: ``evaluation.yaml`` (the table, ``split: validation``) and ``evaluation.csv``
    (per episode, as ``python -m ahrm_stack.evaluate RUN_DIR`` writes)."""
    config, policy = load_policy(run_dir)
    env = PushOffEnv(nominal(config.task), config.safety, seed=VALIDATION_SEED_OFFSET)
    summaries = run_episodes(env, policy, episodes)
    table = EvaluationTable.from_summaries(summaries)
    if summaries:
        write_episodes_csv(Path(run_dir) / "evaluation.csv", summaries)
    (Path(run_dir) / "evaluation.yaml").write_text(yaml.safe_dump(
        {"split": "validation", "seed_offset": VALIDATION_SEED_OFFSET, **dataclasses.asdict(table),
         "success_rate": table.success_rate}, sort_keys=False))
    return table
