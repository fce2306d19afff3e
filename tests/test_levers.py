"""Each lever of the learnability study (issue 5) is a config value, and each takes effect.

Every test builds a real (small) trainer or environment from ``load_config`` overrides and checks
the built object, or one real PPO iteration, against the value that was asked for.
"""

import numpy as np
import pytest
import torch

from ahrm_stack.config import ConfigError, load_config, profile_overrides
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.demonstrations import collect_demonstrations
from ahrm_stack.learning.ppo import scheduled_std
from ahrm_stack.learning.trainer import Trainer
from ahrm_stack.seeds import seed_table

TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=64", "ppo.mini_batch_size=32",
        "task.episode.duration=1.0", "train.warm_start=none", "ppo.bc_coeff=0"]


def _trainer(*overrides: str) -> Trainer:
    return Trainer(load_config([*TINY, *overrides]))


def _linear_sizes(module: torch.nn.Module) -> list[tuple[int, int]]:
    return [(m.in_features, m.out_features) for m in module.modules() if isinstance(m, torch.nn.Linear)]


def test_action_mode_sets_the_action_space():
    assert _trainer("task.action.mode=joint").envs[0].action_spec.shape[-1] == 5
    trainer = _trainer("task.action.mode=cartesian")
    assert trainer.envs[0].action_spec.shape[-1] == 3
    result = trainer.iteration()  # the cartesian path steps the real filter's differential IK
    assert result.batch["frames"] == 64
    trainer.close()


def test_network_width_and_activation():
    trainer = _trainer("ppo.hidden_sizes=[24,8]", "ppo.activation=relu")
    sizes = _linear_sizes(trainer.modules.actor)
    observation = trainer.envs[0].observation_spec["observation"].shape[-1]
    assert sizes == [(observation, 24), (24, 8), (8, trainer.envs[0].action_spec.shape[-1])]
    assert _linear_sizes(trainer.modules.critic)[-1] == (8, 1)
    assert any(isinstance(m, torch.nn.ReLU) for m in trainer.modules.actor.modules())


def test_learning_rate_reaches_the_optimiser():
    assert _trainer("ppo.learning_rate=3.5e-5").optimizers[0].param_groups[0]["lr"] == pytest.approx(3.5e-5)


def test_observation_normalisation_on_and_off():
    on, off = _trainer("ppo.normalize_observations=true"), _trainer("ppo.normalize_observations=false")
    on.iteration()
    off.iteration()
    assert on.modules.normalizer.count == 64 and off.modules.normalizer.count == 0
    observation = torch.randn(on.envs[0].observation_spec["observation"].shape[-1]) * 5
    assert torch.equal(off.modules.normalizer(observation), observation)
    assert not torch.equal(on.modules.normalizer(observation), observation)
    on.close()
    off.close()


def test_normaliser_frozen_or_updated():
    frozen = _trainer("ppo.update_normalizer=false")
    frozen.iteration()  # the first batch sets the statistics
    mean = frozen.modules.normalizer.mean.clone()
    frozen.iteration()
    assert frozen.modules.normalizer.count == 64 and torch.equal(frozen.modules.normalizer.mean, mean)
    running = _trainer("ppo.update_normalizer=true")
    running.iteration()
    running.iteration()
    assert running.modules.normalizer.count == 128
    frozen.close()
    running.close()


def test_entropy_coefficient():
    with_bonus = _trainer("ppo.entropy_coeff=0.01")
    without = _trainer("ppo.entropy_coeff=0")
    assert with_bonus.loss.entropy_coeff == pytest.approx(0.01)
    assert "loss_entropy" in with_bonus.iteration().batch
    assert "loss_entropy" not in without.iteration().batch
    with_bonus.close()
    without.close()


def test_initial_pose():
    home = [240.0, 204.2, 55.4, 350.7, 36.2, 75.0]
    config = load_config([*TINY, f"task.arm.home_deg={home}", "task.arm.joint_jitter=1e-9",
                          "task.arm.start=home"])
    env = PushOffEnv(config.task, config.safety, seed=0)
    q, _ = env.task.arm_state(env.runner.physics)
    np.testing.assert_allclose(np.degrees(q), home, atol=1e-3)


def test_batch_size_and_epochs_set_the_number_of_updates():
    trainer = _trainer("ppo.frames_per_batch=96", "ppo.mini_batch_size=32", "ppo.epochs=2",
                       "ppo.target_kl=0")  # no early stop: every mini-batch of every epoch
    result = trainer.iteration()
    assert result.batch["frames"] == 96 and result.batch["updates"] == 2 * 96 // 32
    trainer.close()


def test_parallel_environments_are_seeded_apart_and_share_the_mechanism():
    trainer = _trainer("train.num_envs=2", "ppo.frames_per_batch=80", "ppo.mini_batch_size=40",
                       "train.seed=3")
    assert len(trainer.envs) == 2
    for i, env in enumerate(trainer.envs):  # fresh streams train.seed + i * env_stride
        expected = np.random.RandomState(3 + i * seed_table().env_stride).get_state()[1]
        np.testing.assert_array_equal(env.runner.random_state.get_state()[1], expected)
    assert trainer.envs[0].mechanism is trainer.envs[1].mechanism is trainer.mechanism
    result = trainer.iteration()
    assert result.batch["frames"] == 80
    # 1 s episodes (20 steps), 40 steps per environment: two episodes each
    assert len(result.episodes) == 4
    state = trainer.state_dict()
    assert len(state["env_rng"]) == 2 and state["env_rng"][0] != state["env_rng"][1]
    with pytest.raises(ConfigError, match="train.num_envs"):
        _trainer("train.num_envs=3", "ppo.frames_per_batch=64")
    trainer.close()


def test_standard_deviation_learned_fixed_and_scheduled():
    learned = _trainer("ppo.std_mode=learned", "ppo.init_std=0.3", "ppo.learning_rate=0.01")
    assert learned.modules.head.log_std.requires_grad
    before = learned.modules.head.log_std.detach().clone()
    learned.iteration()
    assert not torch.equal(before, learned.modules.head.log_std.detach())

    fixed = _trainer("ppo.std_mode=fixed", "ppo.init_std=0.3", "ppo.learning_rate=0.01")
    fixed.iteration()
    assert fixed.iteration().batch["std"] == pytest.approx(0.3)

    scheduled = _trainer("ppo.std_mode=scheduled", "ppo.init_std=0.4", "ppo.final_std=0.1",
                         "ppo.std_schedule_frames=128")
    stds = [scheduled.iteration().batch["std"] for _ in range(3)]  # at frames 0, 64, 128
    assert stds == pytest.approx([0.4, 0.2, 0.1])  # log-linear: the geometric mean halfway
    assert scheduled_std(scheduled.config.ppo, 10_000) == pytest.approx(0.1)
    for trainer in (learned, fixed, scheduled):
        trainer.close()


def test_kl_target_stops_the_epochs_early():
    free = _trainer("ppo.epochs=4", "ppo.learning_rate=0.05", "ppo.target_kl=0")
    stopped = _trainer("ppo.epochs=4", "ppo.learning_rate=0.05", "ppo.target_kl=1e-6")
    assert free.iteration().batch["updates"] == 8
    assert stopped.iteration().batch["updates"] < 8
    free.close()
    stopped.close()


def test_advantage_normalisation():
    """Before any update the probability ratio is 1, so the clipped objective is -mean(A): the raw
    advantages' mean without normalisation, and 0 (whatever their scale) with it."""
    for normalize in (False, True):
        trainer = _trainer(f"ppo.normalize_advantage={str(normalize).lower()}")
        data = trainer._collect().reshape(-1)
        with torch.no_grad():
            trainer.advantage(data)
            data["advantage"] = data["advantage"] * 100 + 1  # a scale and an offset far from 0/1
            objective = float(trainer.loss(data)["loss_objective"])
        expected = 0.0 if normalize else -float(data["advantage"].mean())
        assert objective == pytest.approx(expected, abs=1e-4, rel=1e-4)
        trainer.close()


def test_demonstration_noise_changes_the_states_not_the_labels():
    base = ["task.action.mode=cartesian", "task.arm.home_deg=[240,204.2,55.4,350.7,36.2,75]",
            "task.episode.duration=8", "task.arm.start=home", "task.layout.mode=fixed",
            "task.action.cartesian_max_speed=0.5", "task.realism=ideal"]  # noise: 0.15 m/s at this cap
    clean = collect_demonstrations(load_config(base), 1)
    noisy = collect_demonstrations(load_config([*base, "train.demo_noise=0.3"]), 1)
    assert clean.shape[0] > 0 and noisy.shape[0] > 0
    steps = min(clean.shape[0], noisy.shape[0])
    # the first observation is the same reset; after noisy steps the states part ways
    assert torch.equal(clean["observation"][0], noisy["observation"][0])
    assert not torch.allclose(clean["observation"][steps - 1], noisy["observation"][steps - 1])
    # labels are the controller's clipped requests, never the noisy executed actions
    assert noisy["action"].abs().max() <= 1.0


def test_profile_applies_its_overrides_and_later_overrides_win():
    paper = load_config(["profile=paper"])
    assert paper.task.action.mode == "joint"
    assert paper.ppo.hidden_sizes == (1000, 1000, 1000)
    assert paper.train.warm_start == "none"
    assert load_config(["profile=paper", "ppo.hidden_sizes=[64]"]).ppo.hidden_sizes == (64,)
    assert all("=" in item for item in profile_overrides("paper"))
    with pytest.raises(ConfigError, match="known profiles"):
        load_config(["profile=nope"])


def test_interim_evaluations_are_logged_with_their_policies(tmp_path):
    from ahrm_stack.train import main
    run = tmp_path / "run"
    assert main([*TINY, "train.episodes=4", "train.eval_every=2", "train.eval_episodes=1",
                 "--run-dir", str(run), "--no-progress"]) == 0
    rows = (run / "evaluations.csv").read_text().splitlines()
    assert rows[0].startswith("episode,frames,episodes,successes")
    assert len(rows) >= 2  # at least one interim evaluation before the end
    assert sorted(p.name for p in (run / "policies").iterdir())[0].startswith("episode-")
