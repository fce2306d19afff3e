"""Demonstrations from the scripted controller, behaviour cloning and the BC anchor take effect."""

import torch

from ahrm_stack.config import load_config
from ahrm_stack.learning.demonstrations import ACTION_LIMIT, bc_loss, collect_demonstrations, warm_start
from ahrm_stack.learning.ppo import make_modules
from ahrm_stack.learning.trainer import Trainer

SMALL = ["ppo.hidden_sizes=[32,32]", "ppo.frames_per_batch=128", "train.demo_episodes=2",
         "train.bc_epochs=30", "task.episode.duration=8"]


def test_demonstrations_are_successful_scripted_episodes():
    config = load_config(SMALL)
    demos = collect_demonstrations(config, 2)
    assert demos.shape[0] > 40  # two successful pushes of ~3-4 s at 20 Hz
    assert demos["action"].abs().max() <= ACTION_LIMIT
    assert demos["observation"].shape[-1] == 60
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
