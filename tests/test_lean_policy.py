"""The lean inference path (LeanActor) gives the TorchRL actor's deterministic action."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ahrm_stack.config import load_config
from ahrm_stack.learning.ppo import LeanActor, lean_actor, make_modules


def _modules(overrides=(), obs_dim=40, act_dim=3, seed=0):
    torch.manual_seed(seed)
    config = load_config(list(overrides))
    modules = make_modules(config.ppo, obs_dim, act_dim)
    for p in modules.actor.parameters():  # non-trivial weights, and a large mean to reach tanh's tails
        p.data.normal_(0.0, 0.5)
    modules.normalizer.update(torch.randn(500, obs_dim) * 3.0 + 1.0)  # non-trivial statistics
    return modules


def _reference(actor, observation: torch.Tensor) -> torch.Tensor:
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        out = actor(TensorDict({"observation": observation}, batch_size=observation.shape[:-1]))
    return out["action"]


@pytest.mark.parametrize("overrides", [(), ("ppo.activation=relu", "ppo.hidden_sizes=[64,32]"),
                                       ("ppo.normalize_observations=false",)])
def test_lean_actor_matches_deterministic_actor(overrides):
    modules = _modules(overrides)
    lean = lean_actor(modules.actor)
    assert isinstance(lean, LeanActor)
    obs = torch.randn(200, 40) * 4.0
    want = _reference(modules.actor, obs)
    np.testing.assert_allclose(lean.act(obs).numpy(), want.numpy(), atol=1e-6, rtol=0)
    for row in obs[:20]:  # one observation at a time, through a TensorDict (deploy's call)
        got = lean(TensorDict({"observation": row}, batch_size=[]))["action"]
        np.testing.assert_allclose(got.numpy(), _reference(modules.actor, row).numpy(), atol=1e-6, rtol=0)


def test_lean_actor_shares_parameters_and_statistics():
    modules = _modules()
    lean = lean_actor(modules.actor)
    obs = torch.randn(10, 40)
    modules.normalizer.update(torch.randn(100, 40) * 10.0)  # training goes on: the lean path follows
    with torch.no_grad():
        next(modules.actor.parameters()).add_(0.1)
    np.testing.assert_allclose(lean.act(obs).numpy(), _reference(modules.actor, obs).numpy(), atol=1e-6, rtol=0)


def test_lean_actor_passes_other_policies_through():
    assert lean_actor(lambda td: td) is None
    modules = _modules()
    lean = lean_actor(modules.actor)
    assert lean_actor(lean) is lean


@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_lean_collection_actor_matches_torchrl_actor(mode):
    from ahrm_stack.learning.ppo import lean_collection_actor

    modules = _modules()
    lean = lean_collection_actor(modules.actor)
    for obs, batch in ((torch.randn(300, 40) * 3.0, [300]), (torch.randn(40), [])):
        torch.manual_seed(7)
        with torch.no_grad(), set_exploration_type(mode):
            want = modules.actor(TensorDict({"observation": obs}, batch_size=batch))
        torch.manual_seed(7)  # the same normal draw: the same sampled action
        with set_exploration_type(mode):
            got = lean(TensorDict({"observation": obs}, batch_size=batch))
        for key in ("observation_norm", "loc", "scale", "action", "action_log_prob"):
            np.testing.assert_allclose(got[key].numpy(), want[key].numpy(), atol=1e-6, rtol=1e-6, err_msg=key)


@pytest.mark.parametrize("mode", ["cartesian", "joint"])
def test_deploy_policy_controller_requests_what_the_torchrl_actor_gives(mode):
    """deploy's PolicyController has one forward pass, NumpyPolicy, and requests what the
    TensorDict call of the TorchRL actor (and the lean actor's torch forward) gives for the same
    observation (5e-5: NumPy's float32 BLAS sums in another order than torch's, over 256-wide
    layers of weights with std 0.5 and inputs of ~3: with numpy 2.4.6 the difference reaches 1.8e-5
    here); an actor of another structure is refused in one line."""
    from types import SimpleNamespace

    from ahrm_stack.deploy import PolicyController, PolicyStructureError

    config = load_config([f"task.action.mode={mode}"])
    modules = _modules(act_dim=3 if mode == "cartesian" else 5)
    robot = SimpleNamespace(velocity_limit=np.linspace(0.5, 1.0, 6), commanded_joints=(0, 1, 2, 3, 4),
                            num_joints=6)
    world = SimpleNamespace(robot=robot, current=None)
    world.observation = lambda copy=True: world.current
    fast = PolicyController(world, lean_actor(modules.actor), config)
    for actor in (modules.actor, lean_actor(modules.actor)):
        assert type(PolicyController(world, actor, config)._numpy) is type(fast._numpy)
    with pytest.raises(PolicyStructureError, match=r"the policy's actor \(function\) is not a trained actor"):
        PolicyController(world, lambda td: modules.actor(td), config)
    lean = lean_actor(modules.actor)
    for observation in torch.randn(20, 40).numpy() * 3.0:
        world.current = observation
        as_tensor = torch.as_tensor(observation, dtype=torch.float32)
        want = fast.control.request_keeping_faults(_reference(modules.actor, as_tensor).numpy())
        np.testing.assert_allclose(fast(), want, atol=5e-5, rtol=0)
        np.testing.assert_allclose(fast.control.request_keeping_faults(lean.act(as_tensor).numpy()), want,
                                   atol=1e-6, rtol=0)


def test_deploy_policy_controller_smooths_as_in_training():
    """task.action.smoothing acts in deploy as in the environment: each tick's request is
    s * previous + (1 - s) * the policy's, and reset() starts afresh."""
    from types import SimpleNamespace

    from ahrm_stack.deploy import PolicyController

    s = 0.6
    config = load_config([f"task.action.smoothing={s}", "train.warm_start=none", "ppo.bc_coeff=0"])
    modules = _modules(act_dim=3)
    robot = SimpleNamespace(velocity_limit=np.linspace(0.5, 1.0, 6), commanded_joints=(0, 1, 2, 3, 4),
                            num_joints=6)
    world = SimpleNamespace(robot=robot, current=None)
    world.observation = lambda copy=True: world.current
    smoothed = PolicyController(world, lean_actor(modules.actor), config)
    raw = PolicyController(world, lean_actor(modules.actor), load_config([]))  # the same actor, s = 0
    smoothed.reset()
    expected = None
    for observation in torch.randn(6, 40).numpy() * 3.0:
        world.current = observation
        plain = raw()
        expected = plain if expected is None else s * expected + (1 - s) * plain
        np.testing.assert_allclose(smoothed(), expected, atol=1e-12)
    smoothed.reset()
    np.testing.assert_allclose(smoothed(), raw(), atol=1e-12)


@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_plain_forward_is_the_network_bit_for_bit(activation):
    from ahrm_stack.learning.ppo import PlainForward, safe_atanh, safe_tanh
    from torchrl.modules.distributions.continuous import safeatanh_noeps, safetanh_noeps

    modules = _modules((f"ppo.activation={activation}", "ppo.hidden_sizes=[64,32]"))
    net = lean_actor(modules.actor).net
    plain = PlainForward.of(net)
    assert plain is not None
    obs = torch.randn(50, 40) * 3.0
    with torch.no_grad():
        for want, got in zip(net(obs), plain(obs)):
            assert torch.equal(want, got)
        for p in net.parameters():  # updated in place (the optimiser, load_state_dict): seen
            p.mul_(0.5)
        for want, got in zip(net(obs), plain(obs)):
            assert torch.equal(want, got)
        x = torch.randn(1000) * 10.0  # through tanh's saturated tails, where the clamp acts
        assert torch.equal(safe_tanh(x), safetanh_noeps(x))
        y = safetanh_noeps(x)
        assert torch.equal(safe_atanh(y), safeatanh_noeps(y))


def test_plain_forward_declines_other_networks():
    from ahrm_stack.learning.ppo import PlainForward

    modules = _modules(("ppo.activation=elu",))
    assert PlainForward.of(lean_actor(modules.actor).net) is None  # ELU: the modules run
    assert PlainForward.of(torch.nn.Sequential(torch.nn.Linear(3, 2))) is None
