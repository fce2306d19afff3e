"""The lean PPO loss (ahrm_stack/learning/lean_loss.py) against TorchRL's ClipPPOLoss: the same
values and the same gradients on the same mini-batches, which the second library computes through
its own TensorDict modules and TanhNormal; and the trainer's update unchanged with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ahrm_stack.config import load_config
from ahrm_stack.learning import trainer as trainer_module
from ahrm_stack.learning.lean_loss import LeanClipPPOLoss, lean_loss_for, tanh_normal_log_prob
from ahrm_stack.learning.ppo import make_loss, make_modules
from ahrm_stack.learning.trainer import Trainer

TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=80", "ppo.mini_batch_size=40",
        "task.episode.duration=1.0", "train.warm_start=none", "ppo.bc_coeff=0", "train.seed=3"]
KEYS = ("loss_objective", "loss_critic", "kl_approx", "clip_fraction")


def _compare(config, modules, batch, tolerance=1e-6):
    reference, _ = make_loss(config.ppo, modules)
    lean = lean_loss_for(config.ppo, modules)
    assert isinstance(lean, LeanClipPPOLoss)
    parameters = list(reference.parameters())
    want = reference(batch)
    want_total = want["loss_objective"] + want["loss_critic"]
    want_grads = torch.autograd.grad(want_total, parameters, allow_unused=True)
    got = lean(batch)
    got_total = got["loss_objective"] + got["loss_critic"]
    got_grads = torch.autograd.grad(got_total, parameters, allow_unused=True)
    for key in KEYS:
        np.testing.assert_allclose(float(got[key].detach()), float(want[key].detach()), rtol=tolerance, atol=1e-7,
                                   err_msg=key)
    checked = 0
    for g, w in zip(got_grads, want_grads):
        if w is None:
            assert g is None or torch.count_nonzero(g) == 0
            continue
        np.testing.assert_allclose(g.numpy(), w.numpy(), rtol=tolerance, atol=1e-7)
        checked += 1
    assert checked == len(parameters)  # every parameter gets a gradient: actor, log_std, critic
    return got, want


def _synthetic_batch(modules, observation_dim, n, generator, saturate=0.0, mirror=None):
    """A mini-batch as the trainer builds it: actions sampled from the actor, then perturbed (so
    the ratios leave the clip range both ways), GAE-like advantages and targets."""
    from tensordict import TensorDict
    observation = torch.randn(n, observation_dim, generator=generator) * 2.0
    if mirror is not None:  # the lane-frame entries are what the mirror reads: keep them sensible
        observation[:, :] = observation.clamp(-3, 3)
    with torch.no_grad():
        data = modules.actor(TensorDict({"observation": observation}, batch_size=[n]))
    action = data["action"]
    if saturate:
        picks = torch.rand(n, generator=generator) < saturate
        action[picks] = torch.sign(action[picks]) * (1.0 - 1e-7)
    data.set("action", action)
    old = data["action_log_prob"] + torch.randn(n, generator=generator) * 0.5  # a stale behaviour policy
    return TensorDict({"observation": observation, "action": action, "action_log_prob": old,
                       "advantage": torch.randn(n, 1, generator=generator) * 3.0 + 0.5,
                       "value_target": torch.randn(n, 1, generator=generator) * 10.0}, batch_size=[n])


@pytest.mark.parametrize("lane_frame", ["none", "mirror_no_joints"])
@pytest.mark.parametrize("normalize", [True, False])
def test_lean_loss_equals_clip_ppo_loss_values_and_gradients(lane_frame, normalize):
    config = load_config(["profile=scratch", f"ppo.lane_frame={lane_frame}",
                          f"ppo.normalize_advantage={str(normalize).lower()}", "ppo.hidden_sizes=[32,32]",
                          "ppo.critic_coeff=0.7", "ppo.clip_epsilon=0.15"])
    trainer = Trainer(config, collect_demos=False)
    try:
        observation_dim = trainer.env.observation_spec["observation"].shape[-1]
        modules = trainer.modules
        generator = torch.Generator().manual_seed(7)
        with torch.no_grad():  # a trained-looking normaliser and a non-trivial std
            modules.normalizer.update(torch.randn(500, observation_dim, generator=generator) * 2.0 + 0.3)
            modules.head.log_std.add_(torch.linspace(-0.5, 0.4, modules.head.log_std.numel()))
        for saturate in (0.0, 0.3):
            batch = _synthetic_batch(modules, observation_dim, 256, generator, saturate, modules.mirror)
            got, _ = _compare(config, modules, batch)
            assert 0.0 < float(got["clip_fraction"]) < 1.0  # both branches of the clip were taken
    finally:
        trainer.close()


def test_lean_loss_on_a_collected_batch_after_gae():
    """A real batch from the task (TorchRL's GAE wrote advantage and value_target) and the
    replay buffer's mini-batch, the trainer's own path."""
    trainer = Trainer(load_config(TINY), collect_demos=False)
    try:
        data = trainer._collect()
        with torch.no_grad():
            trainer.advantage(data)
        trainer.buffer.extend(data.reshape(-1))
        batch = trainer.buffer.sample()
        _compare(trainer.config, trainer.modules, batch)
    finally:
        trainer.close()


def test_log_prob_is_the_tanh_normal_change_of_variables():
    """Hand computation: for a = tanh(x), log p(a) = log N(x; loc, scale) − log(1 − a²) per entry."""
    loc = torch.tensor([[0.3, -1.2]], dtype=torch.float64)  # float64: the sum cancels to ~0.01
    scale = torch.tensor([[0.5, 0.2]], dtype=torch.float64)
    x = torch.tensor([[0.1, -0.9]], dtype=torch.float64)
    action = torch.tanh(x)
    normal = -0.5 * ((x - loc) / scale) ** 2 - torch.log(scale) - 0.5 * math.log(2 * math.pi)
    want = (normal - torch.log(1 - action**2)).sum(-1)
    np.testing.assert_allclose(tanh_normal_log_prob(loc, scale, action).numpy(), want.numpy(), rtol=1e-9)


def test_lean_loss_is_not_used_where_it_does_not_apply():
    config = load_config([*TINY, "ppo.entropy_coeff=0.01"])
    modules = make_modules(config.ppo, 12, 3)
    assert lean_loss_for(config.ppo, modules) is None  # the entropy bonus: ClipPPOLoss
    config = load_config(TINY)
    assert isinstance(lean_loss_for(config.ppo, make_modules(config.ppo, 12, 3)), LeanClipPPOLoss)


def test_trainer_iteration_is_the_same_with_either_loss(monkeypatch):
    """Two trainers from the same seed, one with ClipPPOLoss: the same batch figures and the same
    parameters after two iterations (1e-5: the same ops, summed in a different order nowhere)."""
    results, states = [], []
    for lean in (True, False):
        if not lean:
            monkeypatch.setattr(trainer_module, "lean_loss_for", lambda config, modules: None)
        trainer = Trainer(load_config(TINY), collect_demos=False)
        assert (trainer.compute_loss is trainer.loss) is (not lean)
        try:
            results.append([trainer.iteration().batch for _ in range(2)])
            states.append({k: v.clone() for k, v in trainer.modules.actor.state_dict().items()})
        finally:
            trainer.close()
    for got, want in zip(*results):
        for key in ("loss_objective", "loss_critic", "kl_approx", "grad_norm", "updates"):
            np.testing.assert_allclose(got[key], want[key], rtol=1e-5, atol=1e-7, err_msg=key)
    for key in states[1]:
        np.testing.assert_allclose(states[0][key].numpy(), states[1][key].numpy(), rtol=1e-5, atol=1e-6, err_msg=key)
