"""Demonstrations from the scripted controller, behaviour cloning and the BC anchor take effect."""

import torch

from ahrm_stack.config import load_config
from ahrm_stack.learning.demonstrations import ACTION_LIMIT, bc_loss, collect_demonstrations, warm_start
from ahrm_stack.learning.ppo import make_modules
from ahrm_stack.learning.trainer import Trainer

SMALL = ["task.realism=ideal", "ppo.hidden_sizes=[32,32]", "ppo.frames_per_batch=128", "train.demo_episodes=2",
         "train.bc_epochs=30", "task.episode.duration=8"]


def test_demonstrations_are_successful_scripted_episodes():
    config = load_config(SMALL)
    demos = collect_demonstrations(config, 2)
    assert demos.shape[0] > 40  # two successful pushes of ~3-4 s at 20 Hz
    assert demos["action"].abs().max() <= ACTION_LIMIT
    assert demos["observation"].shape[-1] == 60 + 11 + 2 + 2  # spec §1, relative, lanes, lane choice
    # returns are discounted sums of non-positive penalties, and the last step of a success is terminal
    assert (demos["return"] <= 0).all()


def test_behaviour_cloning_fits_the_demonstrations():
    config = load_config(SMALL)
    demos = collect_demonstrations(config, 2)
    modules = make_modules(config.ppo, demos["observation"].shape[-1], demos["action"].shape[-1])
    before = float(bc_loss(modules.actor, demos))
    report = warm_start(modules, demos, 30, 1e-3, 64, torch.Generator().manual_seed(0))
    assert report["bc_loss"] < 0.5 * before


def test_warm_start_and_anchor_are_config_levers():
    plain = Trainer(load_config(SMALL + ["train.warm_start=none", "ppo.bc_coeff=0"]))
    assert plain.demos is None
    trainer = Trainer(load_config(SMALL + ["train.warm_start=bc", "ppo.bc_coeff=0.5"]))
    assert trainer.demos is not None and trainer.warm_start_report is None
    result = trainer.iteration()
    assert trainer.warm_start_report is not None
    assert "bc_loss" in result.batch
    trainer.close()
    plain.close()


def test_demo_episodes_and_bc_epochs_reach_the_trainer(monkeypatch):
    import ahrm_stack.learning.trainer as trainer_module

    calls = {}

    def spy_collect(config, episodes):
        calls["episodes"] = episodes
        return collect_demonstrations(config, episodes)

    def spy_warm_start(modules, demos, epochs, *args):
        calls["epochs"] = epochs
        return warm_start(modules, demos, epochs, *args)

    monkeypatch.setattr(trainer_module, "collect_demonstrations", spy_collect)
    monkeypatch.setattr(trainer_module, "warm_start", spy_warm_start)
    one = Trainer(load_config(SMALL + ["train.demo_episodes=1", "train.bc_epochs=1"]))
    assert calls["episodes"] == 1
    one.warm_start()
    assert calls["epochs"] == 1
    three = Trainer(load_config(SMALL + ["train.demo_episodes=3", "train.bc_epochs=7"]))
    assert calls["episodes"] == 3
    # three successful pushes hold about three times the steps of one (each ~3-4 s at 20 Hz)
    assert three.demos.shape[0] > 2 * one.demos.shape[0]
    three.warm_start()
    assert calls["epochs"] == 7
    # more epochs on the same kind of data fit it better than one
    assert three.warm_start_report["bc_loss"] < one.warm_start_report["bc_loss"]
    one.close()
    three.close()


def test_dagger_labels_are_the_controllers_actions_in_the_states_the_actor_visits():
    """A still actor (zero actions, no noise) never moves the tip: every label must be what a fresh
    controller, reset on the same seeded episode, asks for in that same (reset) state."""
    import numpy as np
    from tensordict import TensorDict

    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.learning.demonstrations import DEMO_SEED_OFFSET, collect_corrections

    config = load_config(SMALL + ["train.demo_noise=0", "train.dagger_duration=0.5"])

    def still(td):
        return TensorDict({"action": torch.zeros(3)}, [])

    data = collect_corrections(config, still, episodes=2, first_episode=5)
    assert data.shape[0] == 2 * 10  # 0.5 s at 20 Hz per episode, no success
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    controller = ScriptedPusher(task, config.scripted)
    for episode in range(2):
        runner.seed(DEMO_SEED_OFFSET + 5 + episode)
        runner.reset()
        controller.reset(runner.physics)
        stateless = config.train.expert == "stateless"
        expected = (controller.tip_velocity(runner.physics, stateless)
                    / config.task.action.cartesian_max_speed)
        first = data[episode * 10]
        np.testing.assert_allclose(first["observation"].numpy(), runner.flat_observation(), atol=1e-6)
        np.testing.assert_allclose(first["action"].numpy(),
                                   np.clip(expected, -ACTION_LIMIT, ACTION_LIMIT), atol=1e-6)


def test_dagger_rounds_add_corrections_to_the_anchor_data():
    trainer = Trainer(load_config(SMALL + ["train.dagger_rounds=1", "train.dagger_episodes=1",
                                           "train.dagger_duration=1", "train.bc_epochs=2"]))
    before = trainer.demos.shape[0]
    trainer.warm_start()
    assert before < trainer.demos.shape[0] <= before + 20  # one episode cut at 1 s (20 steps)
    assert trainer.warm_start_report["dagger_1_steps"] == trainer.demos.shape[0] - before
    trainer.close()


def test_the_anchor_weight_follows_its_schedule():
    from ahrm_stack.learning.ppo import anchor_coeff

    ppo = load_config(["ppo.bc_coeff=10", "ppo.bc_coeff_final=2", "ppo.bc_decay_frames=1000"]).ppo
    assert anchor_coeff(ppo, 0) == 10 and anchor_coeff(ppo, 250) == 8 and anchor_coeff(ppo, 5000) == 2
    assert anchor_coeff(load_config(["ppo.bc_coeff=3", "ppo.bc_decay_frames=0"]).ppo, 10**6) == 3  # 0: constant
