"""PPO building blocks (TorchRL 0.14): observation normaliser, actor, critic, loss, GAE, buffer.

Kept apart from the training loop (``ahrm_stack/learning/training.py``) the way TorchRL's sota PPO keeps
``utils_mujoco.py`` apart from ``ppo_mujoco.py``. Every hyper-parameter comes from
:class:`PPOConfig` (``configs/ppo.yaml``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torch.nn.functional import softplus
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from ahrm_stack.config import PPOConfig
from ahrm_stack.learning.lane_frame import LaneMirror


class RunningNorm(nn.Module):
    """Observation normaliser with running mean and variance kept in buffers (so they are part of
    the policy's state dict and checkpoints). ``update`` is called by the trainer, never in
    ``forward``, so collection and the PPO update see the same statistics."""

    def __init__(self, size: int, clip: float, enabled: bool = True, min_std: float = 0.0) -> None:
        super().__init__()
        self.clip = clip
        self.enabled = enabled
        self.min_std = float(min_std)  # ppo.normalizer_min_std: no feature is scaled up by more
        # than 1 / min_std, so one that barely varied in training (a joint never commanded, an
        # obstacle's height) cannot turn a small measurement error into a saturated input
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(0.0))

    @torch.no_grad()
    def update(self, batch: torch.Tensor) -> None:
        if not self.enabled:
            return
        batch = batch.reshape(-1, batch.shape[-1]).double()
        n = batch.shape[0]
        mean, var = batch.mean(0), batch.var(0, unbiased=False)
        total = self.count + n
        delta = mean - self.mean
        new_mean = self.mean + delta * n / total
        m2 = self.var * self.count + var * n + delta**2 * self.count * n / total
        self.mean.copy_(new_mean)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        if not self.enabled or self.count == 0:
            return observation
        return ((observation - self.mean.to(observation.dtype)) / self.std(observation.dtype)).clamp(
            -self.clip, self.clip)

    def std(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """The per-feature scale: sqrt(var + 1e-8), at least ``min_std`` (observation units)."""
        std = torch.sqrt(self.var + 1e-8)
        if self.min_std > 0:
            std = std.clamp(min=self.min_std)
        return std.to(dtype)


class GaussianHead(nn.Module):
    """Mean from the network; a state-independent standard deviation: learned (a parameter), or
    fixed / scheduled (a buffer the trainer sets with :meth:`set_std`)."""

    def __init__(self, action_dim: int, init_std: float, learned: bool) -> None:
        super().__init__()
        log_std = torch.full((action_dim,), float(torch.log(torch.tensor(init_std))))
        if learned:
            self.log_std = nn.Parameter(log_std)
        else:
            self.register_buffer("log_std", log_std)

    @torch.no_grad()
    def set_std(self, std: float) -> None:
        """Set every action dimension's standard deviation (pre-tanh) to ``std``."""
        self.log_std.fill_(float(np.log(std)))

    def forward(self, mean: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return mean, self.log_std.exp().expand_as(mean)


_ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class FramedNorm(nn.Module):
    """The lane frame (:class:`~ahrm_stack.learning.lane_frame.LaneMirror`), then the normaliser:
    observation -> (normalised observation in the lane frame, the action's signs back to the world)."""

    def __init__(self, mirror: LaneMirror, normalizer: RunningNorm) -> None:
        super().__init__()
        self.mirror, self.normalizer = mirror, normalizer

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        framed, action_sign = self.mirror.canonical(observation)
        return self.normalizer(framed), action_sign


class PrivilegedInput(nn.Module):
    """The asymmetric critic's input (``ppo.critic_privileged``): the normalised observation and the
    privileged one-hot (the planner's lane), its entries swapped where the lane frame is mirrored
    (``action_sign``'s x entry -1), so that the critic reads the lane in the policy's frame."""

    def __init__(self, swap: Sequence[int] | None = None) -> None:
        super().__init__()
        self.swap = None if swap is None else list(swap)

    def forward(self, observation_norm: torch.Tensor, privileged: torch.Tensor,
                action_sign: torch.Tensor | None = None) -> torch.Tensor:
        if action_sign is not None and self.swap is not None:
            mirrored = action_sign[..., :1] < 0
            privileged = torch.where(mirrored, privileged[..., self.swap], privileged)
        return torch.cat([observation_norm, privileged], dim=-1)


class SignedLoc(nn.Module):
    """The Gaussian's mean mapped from the lane frame to the world: ``loc * action_sign``."""

    def forward(self, loc: torch.Tensor, action_sign: torch.Tensor) -> torch.Tensor:
        return loc * action_sign


@dataclasses.dataclass
class Modules:
    normalizer: RunningNorm
    head: GaussianHead  # the policy's standard deviation lives here
    actor: ProbabilisticActor
    critic: TensorDictSequential
    mirror: LaneMirror | None = None  # ppo.lane_frame; None: the world frame

    def framed(self, observation: torch.Tensor) -> torch.Tensor:
        """Observations as the normaliser sees them (in the lane frame, if there is one): what its
        statistics must be updated from."""
        return observation if self.mirror is None else self.mirror(observation)


def make_modules(config: PPOConfig, observation_dim: int, action_dim: int,
                 mirror: LaneMirror | None = None, privileged_swap: Sequence[int] | None = None) -> Modules:
    """Actor (TanhNormal over [-1, 1]) and critic, sharing one observation normaliser; with a
    ``mirror`` (``ppo.lane_frame``, :func:`~ahrm_stack.learning.lane_frame.lane_mirror_for`) both
    read the observation in the lane frame and the actor's mean is mapped back to the world.

    ``privileged_swap`` (``ppo.critic_privileged``; the permutation of the environment's
    ``privileged`` entries under the mirror): the critic also reads them (:class:`PrivilegedInput`);
    the actor never does. Left out (inference: only the actor is loaded), the critic is the plain one."""
    normalizer = RunningNorm(observation_dim, config.normalizer_clip, config.normalize_observations,
                             config.normalizer_min_std)
    if mirror is None:
        norm_module = TensorDictModule(normalizer, in_keys=["observation"], out_keys=["observation_norm"])
    else:
        norm_module = TensorDictModule(FramedNorm(mirror, normalizer), in_keys=["observation"],
                                       out_keys=["observation_norm", "action_sign"])
    activation = _ACTIVATIONS[config.activation]
    head = GaussianHead(action_dim, config.init_std, config.std_mode == "learned")
    actor_net = nn.Sequential(
        MLP(in_features=observation_dim, out_features=action_dim, num_cells=list(config.hidden_sizes),
            activation_class=activation),
        head)
    if config.actor_init_scale != 1.0:  # after the init: the random stream (and the critic) stay as they were
        output = [m for m in actor_net.modules() if isinstance(m, nn.Linear)][-1]
        with torch.no_grad():
            output.weight.mul_(config.actor_init_scale)
            output.bias.mul_(config.actor_init_scale)
    parts = [norm_module, TensorDictModule(actor_net, in_keys=["observation_norm"], out_keys=["loc", "scale"])]
    if mirror is not None:
        parts.append(TensorDictModule(SignedLoc(), in_keys=["loc", "action_sign"], out_keys=["loc"]))
    actor_body = TensorDictSequential(*parts)
    actor = ProbabilisticActor(
        actor_body, in_keys=["loc", "scale"], distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0}, return_log_prob=True)
    privileged = privileged_swap is not None
    critic_net = MLP(in_features=observation_dim + (len(privileged_swap) if privileged else 0), out_features=1,
                     num_cells=list(config.hidden_sizes), activation_class=activation)
    if privileged:
        keys = ["observation_norm", "privileged"] + (["action_sign"] if mirror is not None else [])
        critic = TensorDictSequential(
            norm_module, TensorDictModule(PrivilegedInput(privileged_swap), in_keys=keys, out_keys=["critic_input"]),
            TensorDictModule(critic_net, in_keys=["critic_input"], out_keys=["state_value"]))
    else:
        critic = TensorDictSequential(
            norm_module, TensorDictModule(critic_net, in_keys=["observation_norm"], out_keys=["state_value"]))
    return Modules(normalizer, head, actor, critic, mirror)


_LOG_SQRT_2PI = math.log(math.sqrt(2.0 * math.pi))
_LOG2 = math.log(2.0)


def tanh_normal_log_prob_at(x: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """log π of a TanhNormal over [-1, 1] (pre-tanh mean ``loc``, std ``scale``) at the action
    tanh(``x``), given its pre-tanh value ``x`` (each (..., act_dim)), summed over the last dimension:
    TransformedDistribution.log_prob's order — minus the tanh log-Jacobian 2 (log 2 − x − softplus(−2x)),
    plus the base Normal's log density — so the result is TorchRL's to the bit."""
    base = -((x - loc) ** 2) / (2 * scale**2) - scale.log() - _LOG_SQRT_2PI
    jacobian = 2.0 * (_LOG2 - x - softplus(-2.0 * x))
    return (0.0 - jacobian.sum(-1)) + base.sum(-1)


def safe_tanh(x: torch.Tensor) -> torch.Tensor:
    """TorchRL's ``safetanh_noeps`` (tanh clamped to 1 - the dtype's resolution) as plain ops, for
    use without gradients: the same two ops, so the same values bit for bit, without the autograd
    ``Function.apply`` (which binds its signature with ``inspect`` on every call: ~10 us)."""
    lim = 1.0 - torch.finfo(x.dtype).resolution
    return x.tanh().clamp(-lim, lim)


def safe_atanh(y: torch.Tensor) -> torch.Tensor:
    """TorchRL's ``safeatanh_noeps`` as plain ops (see :func:`safe_tanh`)."""
    lim = 1.0 - torch.finfo(y.dtype).resolution
    return y.clamp(-lim, lim).atanh()


_PLAIN_ACTIVATIONS = {nn.Tanh: torch.tanh, nn.ReLU: torch.relu}


class PlainForward:
    """The actor network of :func:`make_modules` (``nn.Sequential(MLP, GaussianHead)``) as plain
    torch calls: ``F.linear`` and the activation per layer, then the head's scale — the ops the
    modules run, so the same values bit for bit, without ~10 ``nn.Module.__call__`` dispatches per
    call (measured inside collection, where the caches are cold between steps: ~650 -> ~460 us per
    4-environment call with the 3x256 network). It holds the modules, not their tensors: parameters
    updated in place (the optimiser, ``load_state_dict``) are seen; :meth:`of` returns None for any
    other network, which then runs as modules."""

    def __init__(self, linears: list[nn.Linear], activation, head: GaussianHead) -> None:
        self.linears, self.activation, self.head = linears, activation, head

    @classmethod
    def of(cls, net: nn.Module) -> PlainForward | None:
        if not (isinstance(net, nn.Sequential) and len(net) == 2 and isinstance(net[0], MLP)
                and isinstance(net[1], GaussianHead) and not getattr(net[0], "_reshape_out", True)):
            return None
        layers = list(net[0])
        linears = layers[0::2]
        activations = {type(m) for m in layers[1::2]}
        if (len(layers) % 2 != 1 or not all(type(m) is nn.Linear for m in linears) or len(activations) > 1
                or not activations <= set(_PLAIN_ACTIVATIONS)):
            return None
        activation = _PLAIN_ACTIVATIONS[activations.pop()] if activations else None
        return cls(linears, activation, net[1])

    def __call__(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        linears, activation = self.linears, self.activation
        last = len(linears) - 1
        for i, layer in enumerate(linears):
            x = torch.nn.functional.linear(x, layer.weight, layer.bias)
            if i < last:
                x = activation(x)
        return x, self.head.log_std.exp().expand_as(x)


def normalised(normalizer: RunningNorm, mirror: LaneMirror | None,
               observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The networks' input (the observation in the lane frame, if there is one, normalised) and
    the action's signs back to the world (None without a lane frame)."""
    if mirror is None:
        return normalizer(observation), None
    framed, action_sign = mirror.canonical(observation)
    return normalizer(framed), action_sign


class LeanActor(TensorDictModuleBase):
    """The actor's deterministic action as one plain torch forward: normaliser, MLP, squashing.

    For deploy and evaluation. It shares (does not copy) the actor's normaliser and network, and
    gives the action of the :class:`ProbabilisticActor` under ``ExplorationType.DETERMINISTIC``
    (TanhNormal's deterministic sample: the safe tanh of the mean; a test checks 1e-6) at a
    fraction of the cost: no distribution object, log-probability or per-module TensorDict
    plumbing per call (measured with the default 3x256 network: ~0.15 ms against ~1 ms).
    Called with a TensorDict it writes ``"action"`` (what ``env.rollout`` and deploy use);
    :meth:`act` maps an observation tensor (..., obs_dim) to the action (..., action_dim) in [-1, 1].
    """

    in_keys = ["observation"]
    out_keys = ["action"]

    def __init__(self, normalizer: RunningNorm, net: nn.Module, mirror: LaneMirror | None = None) -> None:
        super().__init__()
        self.normalizer, self.net, self.mirror = normalizer, net, mirror
        self._forward = PlainForward.of(net) or net

    def act(self, observation: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            norm, action_sign = normalised(self.normalizer, self.mirror, observation)
            loc = self._forward(norm)[0]
            if action_sign is not None:
                loc = loc * action_sign
            return safe_tanh(loc)  # SafeTanhTransform's value

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict.set("action", self.act(tensordict.get("observation")))


class LeanCollectionActor(TensorDictModuleBase):
    """The actor as the Collector calls it, as plain torch ops: same keys, values and random stream.

    Writes what the :class:`ProbabilisticActor` writes (``observation_norm``, ``loc``, ``scale``,
    ``action``, ``action_log_prob``): under ``ExplorationType.RANDOM`` a TanhNormal sample (the same
    normal draw as ``Normal.rsample``, so the same action for the same torch seed) and its
    log-probability (TanhNormal's, taken at the pre-tanh sample as its cached transform does);
    otherwise the deterministic action and its log-probability (taken at atanh(action), as TorchRL
    does there). A test checks both against the
    TorchRL actor (1e-6). Shares the actor's parameters; no gradient (collection only: the PPO
    loss re-evaluates the TorchRL actor). Saves the per-call cost of the distribution object and
    of the module stack's TensorDict plumbing (see benchmarks/bench_policy.py).
    """

    KEYS = ["observation_norm", "loc", "scale", "action", "action_log_prob"]
    in_keys = ["observation"]
    out_keys = KEYS

    def __init__(self, normalizer: RunningNorm, net: nn.Module, mirror: LaneMirror | None = None) -> None:
        super().__init__()
        self.normalizer, self.net, self.mirror = normalizer, net, mirror
        self._forward = PlainForward.of(net) or net
        if mirror is not None:  # the lane frame's signs, as the TorchRL actor writes them
            self.out_keys = [*self.KEYS, "action_sign"]

    def sample(self, observation: torch.Tensor, random: bool = True) -> tuple[torch.Tensor, ...]:
        """(observation_norm, loc, scale, action, action_log_prob[, action_sign]) for observations
        (..., obs_dim): ``random`` a TanhNormal sample (torch's global random stream), else the
        deterministic action; ``action_sign`` with a lane frame."""
        with torch.no_grad():
            norm, action_sign = normalised(self.normalizer, self.mirror, observation)
            loc, scale = self._forward(norm)
            if action_sign is not None:
                loc = loc * action_sign
            if random:
                x = loc + torch.empty_like(loc).normal_() * scale  # Normal.rsample's draw
                action = safe_tanh(x)
            else:  # TorchRL evaluates this one's log-probability at atanh(action), not at loc
                action = safe_tanh(loc)
                x = safe_atanh(action)
            log_prob = tanh_normal_log_prob_at(x, loc, scale)
        if action_sign is not None:
            return norm, loc, scale, action, log_prob, action_sign
        return norm, loc, scale, action, log_prob

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        values = self.sample(tensordict.get("observation"), exploration_type() == ExplorationType.RANDOM)
        for key, value in zip(self.out_keys, values):
            tensordict.set(key, value)
        return tensordict


def lean_collection_actor(actor) -> LeanCollectionActor | None:
    """The :class:`LeanCollectionActor` of an actor built by :func:`make_modules`, or None."""
    lean = lean_actor(actor)
    return None if lean is None else LeanCollectionActor(lean.normalizer, lean.net, lean.mirror)


def lean_actor(actor) -> LeanActor | None:
    """The :class:`LeanActor` of an actor built by :func:`make_modules` (sharing its parameters),
    or None for anything else (e.g. a wrapper function)."""
    if isinstance(actor, LeanActor):
        return actor
    if not isinstance(actor, ProbabilisticActor):
        return None
    body = actor.module[0] if len(actor.module) else None
    if not isinstance(body, TensorDictSequential) or len(body.module) not in (2, 3):
        return None
    norm, net = body.module[0].module, body.module[1].module
    mirror = None
    if len(body.module) == 3:  # the lane frame: FramedNorm, the network, SignedLoc
        if not (isinstance(norm, FramedNorm) and isinstance(body.module[2].module, SignedLoc)):
            return None
        norm, mirror = norm.normalizer, norm.mirror
    if not (isinstance(norm, RunningNorm) and isinstance(net, nn.Sequential) and isinstance(net[-1], GaussianHead)):
        return None
    return LeanActor(norm, net, mirror)


def scheduled_std(config: PPOConfig, frames: int) -> float:
    """``std_mode: scheduled``: log-linear from ``init_std`` at frame 0 to ``final_std`` at
    ``std_schedule_frames``, constant after."""
    fraction = min(1.0, frames / config.std_schedule_frames)
    return float(np.exp((1 - fraction) * np.log(config.init_std) + fraction * np.log(config.final_std)))


def anchor_coeff(config: PPOConfig, frames: int) -> float:
    """The BC anchor's weight after ``frames``: linear from ``bc_coeff`` to ``bc_coeff_final`` over
    ``bc_decay_frames`` (constant ``bc_coeff`` when that is 0)."""
    if config.bc_decay_frames == 0:
        return config.bc_coeff
    fraction = min(1.0, frames / config.bc_decay_frames)
    return (1 - fraction) * config.bc_coeff + fraction * config.bc_coeff_final


def make_loss(config: PPOConfig, modules: Modules) -> tuple[ClipPPOLoss, GAE]:
    loss = ClipPPOLoss(modules.actor, modules.critic, clip_epsilon=config.clip_epsilon,
                       entropy_bonus=config.entropy_coeff > 0, entropy_coeff=config.entropy_coeff,
                       critic_coeff=config.critic_coeff, loss_critic_type="l2",
                       normalize_advantage=config.normalize_advantage)
    advantage = GAE(gamma=config.gamma, lmbda=config.gae_lambda, value_network=modules.critic,
                    average_gae=False)
    return loss, advantage


def make_buffer(config: PPOConfig) -> ReplayBuffer:
    return ReplayBuffer(storage=LazyTensorStorage(config.frames_per_batch),
                        sampler=SamplerWithoutReplacement(), batch_size=config.mini_batch_size)
