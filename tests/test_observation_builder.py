"""Deploy's observation builder (ahrm_stack/deploy/world.py) lays the vector out by the task's own
description (env/observation_layout.py) and reproduces the task's flat_observation bit for bit, for
every optional part on or off and both arms; a layout it could not reproduce would fall back to the
task's (slower) path, so these cases must never do so."""

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.deploy.world import WorldModel


@pytest.mark.parametrize("overrides", [
    [],
    ["task.observation.relative=false", "task.observation.lanes=false", "task.observation.lane_choice=false"],
    ["task.observation.lanes=false"],
    ["task.robot=j2s6s200"],
    ["profile=scratch-own-lane"],
])
def test_the_builder_is_used_and_equals_the_tasks_observation(overrides):
    config = load_config(overrides)
    world = WorldModel(config.task, seed=3)
    assert world._builder is not None, "the builder fell back to the task's own observation"
    task, physics = world.task, world.physics
    rng = np.random.default_rng(0)
    for _ in range(3):  # other states: joints and props moved
        physics.data.qpos[:] += rng.normal(0.0, 0.05, physics.data.qpos.shape)
        physics.data.qvel[:] = rng.normal(0.0, 0.1, physics.data.qvel.shape)
        physics.forward()
        built = world._builder.fill().copy()
        task.forget_lane_plan()
        expected = task.flat_observation(physics)
        task.forget_lane_plan()
        np.testing.assert_array_equal(built, expected)
