"""The deployed policy's forward pass in NumPy on preallocated arrays (:class:`NumpyPolicy`).

A trained actor (:func:`~ahrm_stack.learning.ppo.make_modules`; its
:class:`~ahrm_stack.learning.ppo.LeanActor`) is normaliser -> MLP -> Gaussian head -> safe tanh.
For one observation per control tick, torch's per-call costs (the tensor, the module calls, the
autograd ``Function`` of the safe tanh, the normaliser's square root) are most of the forward pass;
here the frozen weights are NumPy float32 arrays and every intermediate is a buffer written in
place, so a call allocates nothing but its returned action. Same float32 arithmetic as torch; the
action agrees with ``LeanActor.act`` to float32 rounding (BLAS summation order; a test checks
1e-5), and a NaN in the observation gives NaN in the action, as torch does (the deploy loop stops
on it). A policy trained in a lane frame (``ppo.lane_frame``) carries its mirror here as index and
sign arrays (:class:`FrozenMirror`): the observation is mirrored in place before the normaliser
and the mean's x entry negated before the squashing, as the torch actor does.
"""

from __future__ import annotations

import typing

import numpy as np

class NumpyPolicy:
    """The deterministic action of a :class:`~ahrm_stack.learning.ppo.LeanActor`, frozen at
    construction (later changes to the actor's weights are not seen).

    Build it with :meth:`from_actor` (None for an actor of another structure)."""

    def __init__(self, mean: np.ndarray | None, std: np.ndarray | None, clip: float,
                 weights: list[np.ndarray], biases: list[np.ndarray],
                 activations: list[tuple[str, float]], squash_limit: float,
                 mirror: "FrozenMirror | None" = None) -> None:
        self._mean, self._std = mean, std  # None: no normalisation (disabled, or no statistics)
        self._mirror = mirror  # ppo.lane_frame; None: the world frame
        self._clip = np.float32(clip)
        self._weights = [np.ascontiguousarray(w.T, dtype=np.float32) for w in weights]  # (in, out)
        self._biases = [np.asarray(b, dtype=np.float32) for b in biases]
        self._activations = activations  # after each hidden layer: (name, ELU alpha)
        self._limit = np.float32(squash_limit)
        self.observation_dim = self._weights[0].shape[0]
        self.action_dim = self._weights[-1].shape[1]
        self._input = np.empty(self.observation_dim, dtype=np.float32)
        self._layers = [np.empty(w.shape[1], dtype=np.float32) for w in self._weights]
        self._scratch = [np.empty(w.shape[1], dtype=np.float32) for w in self._weights]

    @classmethod
    def from_actor(cls, actor) -> "NumpyPolicy | None":
        """The NumPy forward of ``actor`` (a :func:`make_modules` actor or its ``LeanActor``), or
        None when its normaliser, network or head is not the structure this class knows."""
        import torch
        from torch import nn

        from ahrm_stack.learning.ppo import GaussianHead, RunningNorm, lean_actor

        lean = lean_actor(actor)
        if lean is None or not isinstance(lean.normalizer, RunningNorm):
            return None
        net = lean.net
        if not (isinstance(net, nn.Sequential) and len(net) == 2
                and isinstance(net[1], GaussianHead) and isinstance(net[0], nn.Sequential)):
            return None
        weights, biases, activations = [], [], []
        expect_linear = True
        for layer in net[0]:
            if expect_linear and isinstance(layer, nn.Linear) and layer.bias is not None:
                weights.append(layer.weight.detach().cpu().numpy().copy())
                biases.append(layer.bias.detach().cpu().numpy().copy())
            elif not expect_linear and type(layer) in (nn.Tanh, nn.ReLU, nn.ELU):
                activations.append((type(layer).__name__, float(getattr(layer, "alpha", 1.0))))
            else:
                return None
            expect_linear = not expect_linear
        if not weights or len(activations) != len(weights) - 1:
            return None  # no layer, or a network that ends in an activation
        if any(w.dtype != np.float32 for w in weights):
            return None
        norm = lean.normalizer
        mean = std = None
        with torch.no_grad():
            if norm.enabled and float(norm.count) != 0.0:
                # exactly RunningNorm.forward's constants for float32 observations
                norm_mean = typing.cast(torch.Tensor, norm.mean)
                mean = norm_mean.to(torch.float32).cpu().numpy().copy()
                std = norm.std(torch.float32).cpu().numpy().copy()
            limit = 1.0 - torch.finfo(torch.float32).resolution  # torchrl's safetanh_noeps
        mirror = None if lean.mirror is None else FrozenMirror.from_module(lean.mirror)
        if mirror is not None and not mirror.fits(weights[0].shape[1], weights[-1].shape[0]):
            return None
        return cls(mean, std, float(norm.clip), weights, biases, activations, limit, mirror)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """The action in [-1, 1] (float32, a new array) of one observation vector (any float
        type; rounded to float32 first, as ``torch.as_tensor(..., dtype=float32)`` does)."""
        x = self._input
        np.copyto(x, observation, casting="unsafe")
        # ppo.lane_frame: the observation framed in place; the mean's signs when its lane is -x
        flip = self._mirror.action_sign if self._mirror is not None and self._mirror.frame(x) else None
        if self._mean is not None:
            np.subtract(x, self._mean, out=x)
            np.divide(x, self._std, out=x)
            np.clip(x, -self._clip, self._clip, out=x)
        last = len(self._weights) - 1
        for k, (weight, bias) in enumerate(zip(self._weights, self._biases)):
            out = self._layers[k]
            np.matmul(x, weight, out=out)
            np.add(out, bias, out=out)
            if k < last:
                name, alpha = self._activations[k]
                if name == "Tanh":
                    np.tanh(out, out=out)
                elif name == "ReLU":
                    np.maximum(out, np.float32(0.0), out=out)
                else:  # ELU: x if x > 0 else alpha * expm1(x)
                    negative = self._scratch[k]
                    np.minimum(out, np.float32(0.0), out=negative)
                    np.expm1(negative, out=negative)
                    negative *= np.float32(alpha)
                    np.copyto(out, negative, where=~(out > 0))
            x = out
        if flip is not None:  # the mean back to the world: as SignedLoc, before the squashing
            np.multiply(x, flip, out=x)
        action = np.tanh(x)
        np.clip(action, -self._limit, self._limit, out=action)
        return action


class FrozenMirror:
    """:class:`~ahrm_stack.learning.lane_frame.LaneMirror` as NumPy arrays, frozen (float32)."""

    def __init__(self, permutation: np.ndarray, sign: np.ndarray, keep: np.ndarray,
                 minus_index: int, action_sign: np.ndarray, key_sign: float = 1.0,
                 key_threshold: float = 0.5) -> None:
        self.permutation = np.asarray(permutation, dtype=np.intp)
        self.sign = np.asarray(sign, dtype=np.float32)
        self.keep = np.asarray(keep, dtype=np.float32)
        self.minus_index = int(minus_index)
        self.action_sign = np.asarray(action_sign, dtype=np.float32)
        self.key_sign = np.float32(key_sign)  # mirrored where key_sign * x[minus_index] > key_threshold
        self.key_threshold = np.float32(key_threshold)
        self._scratch = np.empty(self.permutation.shape, dtype=np.float32)

    @classmethod
    def from_module(cls, mirror) -> "FrozenMirror":
        return cls(mirror.permutation.cpu().numpy(), mirror.sign.cpu().numpy(),
                   mirror.keep.cpu().numpy(), int(mirror.minus_index), mirror.action_sign.cpu().numpy(),
                   float(mirror.key_sign), float(mirror.key_threshold))

    def fits(self, observation_dim: int, action_dim: int) -> bool:
        return (self.permutation.shape == self.sign.shape == self.keep.shape == (observation_dim,)
                and self.action_sign.shape == (action_dim,) and 0 <= self.minus_index < observation_dim)

    def frame(self, x: np.ndarray) -> bool:
        """Map the float32 observation ``x`` into the lane frame in place (as
        ``LaneMirror.canonical``); True when mirrored (its lane is -x, or its cube at x < 0: the
        action's signs then apply)."""
        minus = bool(x[self.minus_index] * self.key_sign > self.key_threshold)
        if minus:
            np.take(x, self.permutation, out=self._scratch)
            np.multiply(self._scratch, self.sign, out=x)
        np.multiply(x, self.keep, out=x)
        return minus


__all__ = ["FrozenMirror", "NumpyPolicy"]
