"""The observation described once (env/observation_layout.py, observation_terms): for every
combination of the optional terms, the layout tiles the flat vector, every term's composer keys are
the observation order, the flat vector equals the declared observables' concatenation, and training's
sensing, the lane frame and the deploy builder read their slices from it."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.env.observation_layout import TASK_TERMS, observation_layout, observation_terms
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask


@pytest.mark.parametrize("relative,lanes,lane_choice", list(itertools.product([False, True], repeat=3)))
def test_one_description_gives_the_layout_the_order_and_the_vector(relative, lanes, lane_choice):
    config = load_config().task
    config = dataclasses.replace(config, observation=dataclasses.replace(
        config.observation, relative=relative, lanes=lanes, lane_choice=lane_choice))
    runner = TaskRunner(PushOffTask(config), seed=3, safety=None)
    runner.reset()
    runner.step_only(np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.0]))
    task = runner.task
    terms = task.observation_terms
    layout = observation_layout(config, task.robot.num_joints, len(task.robot.commanded_joints))
    assert [t.name for t in terms] == list(layout)
    assert [t.size for t in terms] == [s.stop - s.start for s in layout.values()]
    assert [s.start for s in layout.values()][1:] == [s.stop for s in layout.values()][:-1]  # tiled
    assert task.observation_order == [k for t in terms for k in t.keys]
    names = {t.name for t in terms}
    assert set(task.task_observables) == names & set(TASK_TERMS)
    assert {"relative_to_cube", "lane_clearance", "lane_choice"} & names == {
        n for n, on in (("relative_to_cube", relative), ("lane_clearance", lanes), ("lane_choice", lane_choice)) if on}
    observation = runner.observe()
    expected = np.concatenate([np.ravel(observation[k]) for k in task.observation_order])
    flat = runner.flat_observation()
    np.testing.assert_array_equal(flat, expected)
    assert flat.shape == (max(s.stop for s in layout.values()),)
    for term in terms:  # each term's slice holds its keys' values
        np.testing.assert_array_equal(flat[layout[term.name]],
                                      np.concatenate([np.ravel(observation[k]) for k in term.keys]))


def test_the_placeholder_names_only_change_the_keys():
    config = load_config().task
    plain = observation_terms(config, 6, 5)
    props = ("c", *(f"o{i}" for i in range(len(config.obstacles.fixed_layout))))
    named = observation_terms(config, 6, 5, arm="jaco", props=props)
    assert [(t.name, t.size) for t in plain] == [(t.name, t.size) for t in named]
