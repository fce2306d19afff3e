"""The planner-taught route (issue 56, item 2): a trained planner-assisted policy labels the
states of a planner-free student (``train.expert: policy``, ``train.teacher_run``).

Held to the teacher's own pipeline: its observation, assembled from the student's observation
and the terms the student lacks, is the vector the teacher's own task (its config, its runner)
computes in the same state, step by step; the student's data never holds the planner's lane."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from ahrm_stack.config import load_config
from ahrm_stack.env.observation_layout import observation_layout
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.learning.demonstrations import (DEMO_SEED_OFFSET, _teacher, collect_corrections,
                                                collect_demonstrations)
from ahrm_stack.learning.rollouts import load_policy
from ahrm_stack.run_config import load_run_config
from ahrm_stack.schema import ConfigError

ROOT = Path(__file__).resolve().parent.parent
TEACHER = ROOT / "docs" / "experiment-42" / "data" / "runs" / "ahrm-seed2"  # profile=scratch: planner-assisted
STUDENT = ["profile=planner-free", "train.expert=policy", f"train.teacher_run={TEACHER}"]


@pytest.fixture(scope="module")
def teacher():
    return _teacher(load_config(STUDENT))


def test_the_teacher_sees_what_its_own_task_computes(teacher):
    config = load_run_config(TEACHER)
    assert config.task.observation.lane_choice and not teacher.task.config.observation.lane_choice
    own = TaskRunner(PushOffTask(config.task), seed=DEMO_SEED_OFFSET, safety=config.safety)
    _, policy = load_policy(TEACHER)
    for episode in range(2):
        teacher.reset(episode)
        own.seed(DEMO_SEED_OFFSET + episode)
        own.reset()
        for _ in range(25):
            theirs = own.task.flat_observation(own.physics)
            np.testing.assert_array_equal(teacher.teacher_observation(), theirs)
            expected = policy.act(torch.as_tensor(theirs, dtype=torch.float32)).numpy()
            label = teacher.label()
            np.testing.assert_allclose(label, np.clip(expected, -0.995, 0.995), atol=1e-7)
            teacher.runner.step_action(label)
            own.step_action(label)


def test_the_student_data_holds_no_planner_output(teacher):
    config = teacher.runner.task.config
    robot = teacher.task.robot
    layout = observation_layout(config, robot.num_joints, len(robot.commanded_joints))
    assert "lane_choice" not in layout
    width = max(s.stop for s in layout.values())
    demos = collect_demonstrations(load_config(STUDENT), 2)
    assert demos["observation"].shape[1] == width and demos.shape[0] > 0
    def student(td):  # a student that stands still: the teacher still labels every state it visits
        td["action"] = torch.zeros(3)
        return td

    corrections = collect_corrections(load_config(STUDENT + ["train.dagger_duration=1.0"]), student, 1, 2)
    assert corrections["observation"].shape == (20, width)
    assert torch.all(corrections["action"].abs() <= 0.995)


def test_a_teacher_is_named_exactly_when_the_expert_is_a_policy(tmp_path):
    with pytest.raises(ConfigError, match="train.teacher_run names the teacher's run folder exactly when"):
        load_config(["train.expert=policy"])
    with pytest.raises(ConfigError, match="train.teacher_run names the teacher's run folder exactly when"):
        load_config([f"train.teacher_run={TEACHER}"])
    with pytest.raises(ConfigError, match=r"train.teacher_run: '.*' has no config.yaml or policy.pt"):
        load_config(["train.expert=policy", f"train.teacher_run={tmp_path}"])
    with pytest.raises(ConfigError, match=r"train.teacher_run: .*'s task.action .* is not this run's"):
        load_config(STUDENT + ["task.action.cartesian_max_speed=1.0"])
