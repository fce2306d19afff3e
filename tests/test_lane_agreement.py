"""Issue 42: the planner-free profile (profile=scratch-own-lane) and the lane agreement every
evaluation reports (ahrm_stack/lane_agreement.py)."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import ahrm_stack.env.layout as layout_module
import ahrm_stack.env.scripted as scripted_module
import ahrm_stack.env.task as task_module
from ahrm_stack.config import ConfigError, load_config, profile_overrides
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.evaluation import evaluate
from ahrm_stack.evaluate import main as evaluate_cli
from ahrm_stack.lane_agreement import LaneOutcome, LaneTable, taken_lane
from ahrm_stack.learning.trainer import Trainer

PLANNER_RUN = Path(__file__).parents[1] / "docs/scratch-study/round13/runs/margin02-ahrm-init01-seed0"
TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=64", "ppo.mini_batch_size=32"]
# profile=scratch as it was before issue 42 (planner-assisted): its runs must stay as they were
SCRATCH = ["task.action.cartesian_max_speed=0.5", "task.arm.near_cube.bearing=behind",
           "task.rewards.time_reference=success", "mechanism.priority_rule=violation", "ppo.bc_coeff=0.0",
           "ppo.bc_coeff_final=0.0", "ppo.init_std=0.25", "ppo.learning_rate=0.0003", "ppo.clip_epsilon=0.2",
           "ppo.gamma=0.99", "ppo.frames_per_batch=2048", "ppo.mini_batch_size=256", "ppo.epochs=5",
           "ppo.target_kl=0.0", "ppo.reward_scale=0.05", "ppo.lane_frame=mirror_no_joints",
           "ppo.normalize_advantage=true", "ppo.update_normalizer=true", "train.warm_start=none",
           "train.num_envs=4", "train.frames=2000000", "train.time_limit=5.0",
           "train.start_curriculum=near_cube", "train.eval_every_frames=100000"]


def test_taken_lane_is_the_sign_of_the_cubes_x_shift():
    assert taken_lane([0.1, 0.0], [0.6, 0.3], 0.02) == "+x"
    assert taken_lane([0.1, 0.0], [-0.5, -0.1], 0.02) == "-x"
    assert taken_lane([0.1, 0.0], [0.11, 0.4], 0.02) is None  # moved along y, not along a lane
    with pytest.raises(ValueError, match="finite"):
        taken_lane([0.1, 0.0], [np.nan, 0.0], 0.02)


def test_a_hand_made_disagreeing_episode_counts_as_one():
    outcomes = [LaneOutcome("+x", "+x", False), LaneOutcome("-x", "-x", True),
                LaneOutcome("+x", "-x", True),  # the wrong lane, and an obstacle touched
                LaneOutcome("-x", None, False)]  # not pushed: neither agreeing nor disagreeing
    table = LaneTable.from_outcomes(outcomes)
    assert (table.episodes, table.pushed, table.agreeing, table.disagreeing) == (4, 3, 2, 1)
    assert (table.touched_agreeing, table.touched_disagreeing) == (1, 1)
    assert table.agreement == pytest.approx(2 / 3)
    assert [o.row()["lane_agrees"] for o in outcomes] == [True, True, False, ""]
    assert "after a wrong lane 1/1" in str(table)


def test_the_scripted_controller_leaves_by_its_planned_lane(tmp_path):
    assert evaluate_cli(["--policy", "scripted", "--episodes", "4", "--out", str(tmp_path)]) == 0
    lanes = json.loads((tmp_path / "evaluation.json").read_text())["lanes"]
    assert lanes["episodes"] == lanes["pushed"] == lanes["agreeing"] == 4 and lanes["agreement"] == 1.0
    with open(tmp_path / "evaluation.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["lane_agrees"] for row in rows] == ["True"] * 4
    assert all(row["planned_lane"] == row["cube_lane"] in ("+x", "-x") for row in rows)


def test_a_policy_is_measured_against_the_plan_of_the_same_episodes(tmp_path):
    """A trained policy's planned lanes are the scripted controller's on the same episodes (the
    plan is made at the same first state), and the report carries its agreement."""
    mine = evaluate(PLANNER_RUN, 3, out=tmp_path / "policy", quiet=True)
    theirs = evaluate(PLANNER_RUN, 3, out=tmp_path / "scripted", quiet=True, scripted=True)
    planned = [[row["planned_lane"] for row in csv.DictReader(open(tmp_path / name / "evaluation.csv"))]
               for name in ("policy", "scripted")]
    assert planned[0] == planned[1] and len(planned[0]) == 3
    assert mine["lanes"]["episodes"] == theirs["lanes"]["episodes"] == 3
    assert 0 <= mine["lanes"]["agreeing"] <= mine["lanes"]["pushed"] <= 3


def test_the_planner_free_profile_has_no_planner_input():
    config = load_config(["profile=scratch-own-lane"])
    assert not config.task.observation.lane_choice
    assert config.ppo.lane_frame == "none" and config.task.arm.near_cube.bearing == "any"
    assert config.train.start_curriculum == "near_cube" and config.train.warm_start == "none"
    assert "lane_choice" not in PushOffTask(config.task).observation_order
    assert profile_overrides("scratch-own-lane")[:len(SCRATCH)] == SCRATCH  # built on profile=scratch


def test_the_planner_assisted_profile_is_unchanged():
    assert profile_overrides("scratch") == SCRATCH
    config = load_config(["profile=scratch"])
    assert config.task.observation.lane_choice and config.ppo.lane_frame == "mirror_no_joints"
    assert "lane_choice" in PushOffTask(config.task).observation_order


def _forbid_the_planner(monkeypatch):
    def planner(*args, **kwargs):
        raise AssertionError("choose_lane was called")
    for module in (task_module, scripted_module, layout_module):
        monkeypatch.setattr(module, "choose_lane", planner)


@pytest.mark.parametrize("frame", ["none", "cube_side_no_joints", "tip_side_no_joints"])
def test_the_planner_free_training_never_asks_the_planner(monkeypatch, frame):
    """A batch of the planner-free profile's training (near-cube curriculum starts, level 0), in
    the world frame and in the cube-side frame, with choose_lane made to raise; the
    planner-assisted profile, the control, does call it."""
    _forbid_the_planner(monkeypatch)
    trainer = Trainer(load_config(["profile=scratch-own-lane", f"ppo.lane_frame={frame}", *TINY]))
    assert trainer.envs[0].task.near_cube_share == 1.0
    result = trainer.iteration()
    assert trainer.frames == 64 and all(row["steps"] <= 100 for row in result.episodes)  # 5 s episodes
    trainer.close()
    with pytest.raises(AssertionError, match="choose_lane was called"):
        Trainer(load_config(["profile=scratch", *TINY])).iteration()


def test_a_profile_built_on_itself_names_the_loop(tmp_path):
    folder = tmp_path / "profiles"
    folder.mkdir()
    (folder / "a.yaml").write_text("profile: b\nppo:\n  epochs: 3\n")
    (folder / "b.yaml").write_text("profile: a\n")
    with pytest.raises(ConfigError, match=r"profile=a: its 'profile' key comes back to itself \(a -> b -> a\)"):
        profile_overrides("a", tmp_path)
    (folder / "b.yaml").write_text("ppo:\n  epochs: 2\n  gamma: 0.9\n")
    assert profile_overrides("a", tmp_path) == ["ppo.epochs=2", "ppo.gamma=0.9", "ppo.epochs=3"]
