"""Bad input at the edge: every bad override of ``python -m ahrm_stack.train`` (and of
``python -m ahrm_stack.evaluate --config``) is one line on stderr naming the key, a non-zero exit,
no traceback, and nothing written: no run folder, no file anywhere under the working directory.

The cases cover wrong types, negative / zero / NaN / infinite / huge values, strings for numbers,
lists of the wrong length, unknown choices, unknown keys, malformed overrides and layouts that do
not fit the table. The first ones of each kind also go through the real command line once.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from ahrm_stack import evaluate, train
import yaml

from ahrm_stack.config import ConfigError, load_config, load_raw
from ahrm_stack.env.torchrl_env import PushOffEnv, action_to_command

# A valid tiny run: each case below breaks exactly one thing in it.
BASE = ["train.episodes=2", "task.episode.duration=1", "train.eval_episodes=0", "train.warm_start=none",
        "ppo.bc_coeff=0", "ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "ppo.hidden_sizes=[32,32]"]

# (overrides, the key the message must name)
CASES = [
    # wrong types, strings for numbers
    ("train.episodes=abc", "train.episodes"),
    ("train.episodes=1.5", "train.episodes"),
    ("train.episodes=true", "train.episodes"),
    ("train.episodes=1e3", "train.episodes"),  # YAML 1.1: a string
    ("train.seed=abc", "train.seed"),
    ("train.runs_dir=[a]", "train.runs_dir"),
    ("ppo.frames_per_batch=64.5", "ppo.frames_per_batch"),
    ("ppo.hidden_sizes=32", "ppo.hidden_sizes"),
    ("ppo.hidden_sizes=[32,abc]", "ppo.hidden_sizes"),
    ("ppo.normalize_observations=maybe", "ppo.normalize_observations"),
    ("task.episode.duration=soon", "task.episode.duration"),
    ("task.episode=5", "task.episode"),
    # negative, zero
    ("train.episodes=-1", "train.episodes"),
    ("train.episodes=0", "train.episodes"),
    ("train.threads=0", "train.threads"),
    ("train.update_threads=0", "train.update_threads"),
    ("train.seed=-1", "train.seed"),
    ("train.keep_checkpoints=0", "train.keep_checkpoints"),
    ("train.checkpoint_every=0", "train.checkpoint_every"),
    ("train.eval_episodes=-1", "train.eval_episodes"),
    ("train.eval_every=-5", "train.eval_every"),
    ("train.demo_noise=-0.1", "train.demo_noise"),
    ("ppo.frames_per_batch=0", "ppo.frames_per_batch"),
    ("ppo.hidden_sizes=[32,-1]", "ppo.hidden_sizes"),
    ("ppo.hidden_sizes=[]", "ppo.hidden_sizes"),
    ("ppo.learning_rate=-1", "ppo.learning_rate"),
    ("ppo.clip_epsilon=0", "ppo.clip_epsilon"),
    ("ppo.gamma=-0.1", "ppo.gamma"),
    ("ppo.gae_lambda=2", "ppo.gae_lambda"),
    ("ppo.std_schedule_frames=0", "ppo.std_schedule_frames"),
    ("task.episode.control_period=0", "task.episode.control_period"),
    ("task.cube.size=0", "task.cube.size"),
    ("task.action.cartesian_max_speed=0", "task.action.cartesian_max_speed"),
    ("task.rewards.progress_eps=-1", "task.rewards.progress_eps"),
    ("task.layout.settle_steps=-1", "task.layout.settle_steps"),
    ("safety.max_obstacle_rows=-1", "safety.max_obstacle_rows"),
    ("safety.osqp_eps=0", "safety.osqp_eps"),
    ("safety.acceleration_limit=[4,4,4,6,6,-6]", "safety.acceleration_limit"),
    ("mechanism.convergence_window=0", "mechanism.convergence_window"),
    ("mechanism.blend_slope=-40", "mechanism.blend_slope"),
    # NaN, infinity
    ("train.bc_learning_rate=.nan", "train.bc_learning_rate"),
    ("train.bc_learning_rate=.inf", "train.bc_learning_rate"),
    ("ppo.gamma=.nan", "ppo.gamma"),
    ("ppo.init_std=.inf", "ppo.init_std"),
    ("safety.acceleration_limit=[4,4,4,6,6,.nan]", "safety.acceleration_limit"),
    # huge: would run (nearly) forever or exhaust the machine
    ("train.episodes=1000000000", "train.episodes"),
    ("train.demo_episodes=1000000000", "train.demo_episodes"),
    (["train.warm_start=bc", "train.demo_episodes=10000", "task.episode.duration=60"], "train.demo_episodes"),
    ("train.bc_epochs=1000000000", "train.bc_epochs"),
    ("train.threads=1000", "train.threads"),
    ("train.update_threads=1000", "train.update_threads"),
    ("train.num_envs=100000", "train.num_envs"),
    ("train.seed=99999999999", "train.seed"),
    ("ppo.frames_per_batch=1000000000", "ppo.frames_per_batch"),
    ("ppo.epochs=1000000000", "ppo.epochs"),
    ("ppo.hidden_sizes=[1000000,1000000]", "ppo.hidden_sizes"),
    ("ppo.hidden_sizes=[8,8,8,8,8,8,8,8,8,8,8,8,8,8,8,8,8]", "ppo.hidden_sizes"),
    ("task.episode.physics_timestep=1e-9", "task.episode.physics_timestep"),
    ("task.episode.duration=1000000000", "task.episode.duration"),
    ("task.layout.max_tries=1000000000000", "task.layout.max_tries"),
    ("task.layout.settle_steps=1000000000", "task.layout.settle_steps"),
    ("safety.osqp_max_iter=1000000000000", "safety.osqp_max_iter"),
    ("safety.max_obstacle_rows=100000", "safety.max_obstacle_rows"),
    ("mechanism.constraint_window=1000000000000", "mechanism.constraint_window"),
    # ranges and relations between keys
    ("ppo.gamma=1.5", "ppo.gamma"),
    ("ppo.mini_batch_size=48", "ppo.mini_batch_size"),
    ("train.num_envs=3", "train.num_envs"),
    ("task.episode.physics_timestep=0.1", "task.episode.physics_timestep"),
    ("task.episode.duration=0.01", "task.episode.duration"),
    ("safety.velocity_margin=1", "safety.velocity_margin"),
    ("safety.workspace_lower=[1,1,1]", "safety.workspace_lower"),
    ("safety.enabled=false", "safety.enabled"),
    ("task.regions.distance_clip=0.001", "task.regions.distance_clip"),
    ("task.layout.radial_range=[0.3,0.1]", "task.layout.radial_range"),
    # lists of the wrong length
    ("task.arm.home_deg.jaco=[1,2,3]", "task.arm.home_deg"),
    ("task.arm.home_deg=[1,2,3,4,5,6,7]", "task.arm.home_deg"),
    ("task.arm.base_position=[0,0]", "task.arm.base_position"),
    ("task.table.half_extent=[0.45]", "task.table.half_extent"),
    ("task.obstacles.fixed_layout=[[0.1]]", "task.obstacles.fixed_layout"),
    ("safety.acceleration_limit=[4,4,4]", "safety.acceleration_limit"),
    ("mechanism.manual_orders=[[avoid,manipulate,time]]", "mechanism.manual_orders"),
    # unknown choices
    ("task.robot=ur5", "task.robot"),
    ("task.action.mode=torque", "task.action.mode"),
    ("task.layout.mode=spiral", "task.layout.mode"),
    ("task.layout.lane_directions=[+y]", "task.layout.lane_directions"),
    ("train.warm_start=maybe", "train.warm_start"),
    ("ppo.activation=sigmoid", "ppo.activation"),
    ("ppo.std_mode=random", "ppo.std_mode"),
    ("safety.solver=cvxpy", "safety.solver"),
    ("scripted.solver=nonexistent", "scripted.solver"),
    ("mechanism.method=sarsa", "mechanism.method"),
    ("mechanism.fixed_order=[avoid,avoid,time]", "mechanism.fixed_order"),
    # layouts that do not fit the table
    (["task.layout.mode=fixed", "task.obstacles.fixed_layout=[[0.0,0.0]]"], "task.obstacles.fixed_layout"),
    (["task.layout.mode=fixed",
      "task.obstacles.fixed_layout=[[5,5],[0.16,-0.12],[-0.02,-0.17],[-0.15,0.16]]"],
     "task.obstacles.fixed_layout"),
    (["task.layout.mode=fixed", "task.obstacles.fixed_layout=[[0.12,0.0],[-0.12,0.0]]"], "task.obstacles.fixed_layout"),
    (["task.layout.mode=fixed", "task.cube.position=[2,2]"], "task.cube.position"),
    (["task.layout.mode=fixed", "task.cube.size=1"], "task.cube.position"),
    (["task.layout.mode=random", "task.layout.radial_range=[5,6]"], "task.layout.radial_range"),
    # malformed overrides, unknown keys and profiles
    ("tsk.episode.duration=3", "tsk"),
    ("ppo.learning_rat=1", "ppo.learning_rat"),
    ("task.cube.size.x=3", "task.cube.size"),
    ("train.episodes", "train.episodes"),
    ("train.episodes=[1,", "train.episodes"),
    ("profile=nosuch", "profile"),
]


def _ids():
    return [case if isinstance(case, str) else " ".join(case) for case, _ in CASES]


def _listing(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_at_least_39_cases_of_every_kind():
    assert len(CASES) >= 39


@pytest.mark.parametrize("overrides,key", CASES, ids=_ids())
def test_bad_train_override_is_one_line_naming_the_key(overrides, key, tmp_path, monkeypatch, capsys):
    overrides = [overrides] if isinstance(overrides, str) else overrides
    monkeypatch.chdir(tmp_path)  # the default runs_dir would be created here
    before = _listing(tmp_path)
    rc = train.main([*BASE, *overrides, "--run-dir", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and err[0].startswith("error: "), err
    assert key in err[0], err[0]
    assert "Traceback" not in err[0]
    assert _listing(tmp_path) == before, "something was written before validation"


@pytest.mark.parametrize("overrides,key", CASES, ids=_ids())
def test_bad_evaluate_config_is_one_line_naming_the_key(overrides, key, tmp_path, capsys):
    overrides = [overrides] if isinstance(overrides, str) else overrides
    before = _listing(tmp_path)
    rc = evaluate.main(["--policy", "scripted", "--episodes", "1", "--out", str(tmp_path / "out"),
                        "--config", *BASE, *overrides])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and key in err[0], err
    assert _listing(tmp_path) == before


ROOT = Path(__file__).resolve().parent.parent


def test_training_threads_stay_within_this_machine(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    more = (os.cpu_count() or 1) + 1
    assert train.main([*BASE, f"train.threads={more}", "--run-dir", str(tmp_path / "run"),
                       "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "train.threads" in err[0] and "CPUs of this machine" in err[0]
    assert not list(tmp_path.iterdir())


def _cli(module, args, cwd):
    """``python -m module args`` in ``cwd``, importing this checkout's package."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONPATH": str(ROOT)}
    env.pop("PYTHONWARNINGS", None)
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


def test_command_lines_print_one_line_and_write_nothing(tmp_path):
    """The real entry points (their import-time warnings included): one line, nothing written."""
    for module, args, key in (
            ("ahrm_stack.train", [*BASE, "task.episode.physics_timestep=1e-9"], "task.episode.physics_timestep"),
            ("ahrm_stack.evaluate", ["--policy", "scripted", "--config", "train.threads=1000"], "train.threads")):
        result = _cli(module, args, tmp_path)
        err = result.stderr.strip().splitlines()
        assert result.returncode != 0
        assert len(err) == 1 and key in err[0], result.stderr
        assert not list(tmp_path.iterdir())


def test_resume_with_a_bad_override_changes_nothing(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(load_raw()))
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    assert train.main(["--resume", str(run), "train.threads=1000", "--no-progress"]) == 2
    assert "train.threads" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before


def test_good_config_still_loads_with_its_profile():
    load_config()
    load_config(["profile=paper"])
    load_config(BASE)


# ---------------------------------------------------------------------------- action shapes


def test_joint_actions_of_the_wrong_shape_are_refused_not_broadcast():
    limits = np.array([1.0, 2.0, 3.0, 4.0])
    commanded = (0, 1, 2)
    np.testing.assert_array_equal(action_to_command(np.array([0.5, -1.0, 1.0]), limits, commanded),
                                  [0.5, -2.0, 3.0, 0.0])
    for bad in (np.array([0.5]), np.array(0.5), np.zeros(2), np.zeros(4), np.zeros((1, 3))):
        with pytest.raises(ValueError, match=r"must have shape \(3,\), got"):
            action_to_command(bad, limits, commanded)


@pytest.mark.parametrize("mode", ["joint", "cartesian"])
def test_environment_refuses_wrong_shaped_actions(mode):
    config = load_config([f"task.action.mode={mode}", "task.episode.duration=1"])
    env = PushOffEnv(config.task, config.safety, seed=0)
    td = env.reset()
    size = env.action_spec.shape[-1]
    for shape in ((1,), (), (size + 1,)):
        with pytest.raises(ValueError, match=rf"action.mode {mode}: the action must have shape \({size},\)"):
            env.step(td.clone().set("action", torch.zeros(shape)))
    env.step(td.clone().set("action", torch.zeros(size)))  # the right shape still steps


def test_config_error_is_raised_for_the_same_cases_by_load_config():
    """The library entry (load_config) refuses the same values as the command line."""
    for overrides, key in CASES:
        overrides = [overrides] if isinstance(overrides, str) else overrides
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            load_config([*BASE, *overrides])
