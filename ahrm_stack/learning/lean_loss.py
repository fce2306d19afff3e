"""TorchRL's clipped PPO loss for the networks of :func:`~ahrm_stack.learning.ppo.make_modules`, as
plain torch ops.

``ClipPPOLoss`` re-runs the actor and the critic through their TensorDict module stacks, builds a
TanhNormal per mini-batch and computes diagnostics the trainer does not read (ESS, ratio statistics);
measured quiet on the 2-core VM (``benchmarks/bench_loss.py``, 3x256 networks, 256 samples), its
forward took 5.6 ms of the 9.0 ms forward + backward + clip, against 2.5 of 5.8 ms here. :class:`LeanClipPPOLoss`
computes the same quantities from the same parameters (shared, not copied) with the same floating-point
operations, so the values and the gradients agree with ``ClipPPOLoss`` (``tests/test_lean_loss.py``
checks both on trained and saturated policies, with and without the lane frame and advantage
normalisation); it covers what the trainer uses: no entropy bonus, no value clipping, an l2 critic.
:func:`lean_loss_for` returns None for anything else, and the trainer keeps ``ClipPPOLoss`` then.

Per mini-batch of N samples (TensorDict keys as TorchRL writes them):
- ``observation`` (N, obs_dim), ``action`` (N, act_dim) in [-1, 1] (the TanhNormal sample),
  ``action_log_prob`` (N,) at collection, ``advantage`` and ``value_target`` (N, 1) from GAE;
- ``loss_objective``: −mean(min(r A, clip(r, 1−ε, 1+ε) A)), r = π(a|s) / π_old(a|s), A standardised
  over the mini-batch when ``ppo.normalize_advantage`` (torch's unbiased std, clamped at float32's
  resolution, as TorchRL does);
- ``loss_critic``: ``critic_coeff`` × mean((V(s) − value_target)²);
- ``kl_approx``: mean(log π_old − log π), ``clip_fraction``: the share of clipped ratios.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.modules.distributions.continuous import safeatanh_noeps

from ahrm_stack.config import PPOConfig
from ahrm_stack.learning.ppo import Modules, lean_actor, normalised, tanh_normal_log_prob_at

_EPS = torch.finfo(torch.float).resolution  # TorchRL's _standardize: std.clamp_min(eps)


def tanh_normal_log_prob(loc: torch.Tensor, scale: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """log π(action) of a TanhNormal over [-1, 1] with pre-tanh mean ``loc`` and std ``scale``
    (each (..., act_dim)); summed over the last dimension. As TorchRL's TanhNormal.log_prob: at the
    pre-tanh value the safe atanh of the stored action gives."""
    return tanh_normal_log_prob_at(safeatanh_noeps(action), loc, scale)


class LeanClipPPOLoss:
    """``ClipPPOLoss(actor, critic, clip_epsilon, entropy_bonus=False, critic_coeff,
    loss_critic_type="l2", normalize_advantage)`` for the modules of ``make_modules``.

    Called with a mini-batch TensorDict it returns a dict of 0-d tensors (``loss_objective``,
    ``loss_critic`` with gradients; ``kl_approx``, ``clip_fraction`` detached), the keys the trainer
    reads from ``ClipPPOLoss``. The parameters are the modules' own: the trainer's optimiser and
    gradient clip stay on ``ClipPPOLoss.parameters()``, which are the same tensors.
    """

    def __init__(self, config: PPOConfig, modules: Modules, actor_net: nn.Module, critic_net: nn.Module) -> None:
        self.normalizer, self.mirror = modules.normalizer, modules.mirror
        self.actor_net, self.critic_net = actor_net, critic_net
        self.critic_coeff = float(config.critic_coeff)
        self.normalize_advantage = bool(config.normalize_advantage)
        self.clip_low, self.clip_high = math.log1p(-config.clip_epsilon), math.log1p(config.clip_epsilon)

    def __call__(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        norm, action_sign = normalised(self.normalizer, self.mirror, batch.get("observation"))
        loc, scale = self.actor_net(norm)
        if action_sign is not None:
            loc = loc * action_sign
        log_prob = tanh_normal_log_prob(loc, scale, batch.get("action"))
        previous = batch.get("action_log_prob")
        advantage = batch.get("advantage")
        if self.normalize_advantage and advantage.numel() > 1:
            advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(_EPS)
        log_weight = (log_prob - previous).unsqueeze(-1)
        gain1 = log_weight.exp() * advantage
        clipped = log_weight.clamp(self.clip_low, self.clip_high)
        gain2 = clipped.exp() * advantage
        gain = torch.stack([gain1, gain2], -1).min(dim=-1).values
        value = self.critic_net(norm)
        critic = (batch.get("value_target") - value) ** 2
        with torch.no_grad():
            kl_approx = (previous - log_prob).unsqueeze(-1).mean()
            clip_fraction = (clipped != log_weight).to(log_weight.dtype).mean()
        return {"loss_objective": (-gain).mean(), "loss_critic": (self.critic_coeff * critic).mean(),
                "kl_approx": kl_approx, "clip_fraction": clip_fraction}


def lean_loss_for(config: PPOConfig, modules: Modules) -> LeanClipPPOLoss | None:
    """The lean loss for these modules and settings, or None where it does not apply (an entropy
    bonus, whose TanhNormal estimate draws random samples; networks not built by ``make_modules``)."""
    if config.entropy_coeff > 0:
        return None
    lean = lean_actor(modules.actor)
    if lean is None or len(modules.critic.module) != 2:
        return None
    critic_net = modules.critic.module[1].module
    if not isinstance(critic_net, nn.Module):
        return None
    return LeanClipPPOLoss(config, modules, lean.net, critic_net)
