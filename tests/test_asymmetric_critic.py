"""The asymmetric critic (``ppo.critic_privileged``, issue 56): the critic reads the planner's lane,
the policy never does."""

from __future__ import annotations

import pytest
import torch

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.learning.trainer import Trainer

TINY = ["ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "train.num_envs=2", "train.frames=64",
        "ppo.hidden_sizes=[16,16]", "train.time_limit=1.0"]


@pytest.mark.parametrize("frame", ["none", "tip_side_no_joints"])
def test_the_critic_reads_the_planners_lane_and_the_actor_does_not(frame):
    config = load_config(["profile=scratch-own-lane", "task.arm.near_cube.bearing=behind_free",
                          f"ppo.lane_frame={frame}", "ppo.critic_privileged=true", *TINY])
    trainer = Trainer(config)
    result = trainer.iteration()
    data = trainer._collector.next()  # a second batch, to probe the modules on real steps
    privileged = data["privileged"]
    assert privileged.shape[-1] == 2 and torch.all(privileged.sum(-1) == 1)  # one-hot, every step
    for env in trainer.envs:  # the planner's lane at the episode's start
        assert env.privileged[list(env.task.config.layout.lane_directions).index(env._planned)] == 1.0
    flipped = data.clone()
    flipped.set("privileged", 1.0 - privileged)
    with torch.no_grad():
        v, w = (trainer.modules.critic(d.clone())["state_value"] for d in (data, flipped))
        a, b = (trainer.modules.actor(d.clone())["loc"] for d in (data, flipped))
    assert not torch.allclose(v, w)  # the critic reads it
    assert torch.equal(a, b)  # the actor does not
    assert trainer.modules.critic.module[-1].module[0].in_features == data["observation"].shape[-1] + 2
    assert result.batch["updates"] > 0
    trainer.close()


def test_in_the_mirrored_frame_the_critic_reads_the_lane_swapped():
    from ahrm_stack.learning.ppo import PrivilegedInput

    module = PrivilegedInput([1, 0])
    norm = torch.zeros(2, 3)
    lane = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    sign = torch.tensor([[1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    out = module(norm, lane, sign)
    assert out[0, 3:].tolist() == [1.0, 0.0] and out[1, 3:].tolist() == [0.0, 1.0]


def test_demonstrations_and_a_privileged_critic_are_refused():
    with pytest.raises(ConfigError, match="ppo.critic_privileged"):
        load_config(["ppo.critic_privileged=true"])  # the default warm-starts from demonstrations
