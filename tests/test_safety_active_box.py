"""The filter's per-call report of the active hard bounds (``SafetyFilter._active_box``, in plain
floats) names exactly what the general routine ``_active_bounds`` names, in the same order, on
random boxes with ties between families and commands on, near and off the bounds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.config import load_config
from ahrm_stack.env.control_step import make_task_filter
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.safety.constraints import JointBounds
from ahrm_stack.safety.filter import ACTIVE_TOLERANCE


@pytest.fixture(scope="module")
def safety():
    config = load_config()
    changes = dict(table_distance_rows=False, self_collision_rows=False, obstacle_rows=False)
    return make_task_filter(PushOffTask(config.task), dataclasses.replace(config.safety, **changes))


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_active_box_names_what_active_bounds_names(safety, seed):
    rng = np.random.default_rng(seed)
    nv = safety.num_joints
    box = safety._box
    saved = box.copy()
    try:
        # three families' bounds (family, joint): some equal to another family's on the same
        # joint (ties: both are named), some position bounds infinite (continuous joints)
        lows = rng.uniform(-2.0, -0.1, (3, nv))
        highs = rng.uniform(0.1, 2.0, (3, nv))
        for bounds in (lows, highs):
            for family, joint in zip(*np.nonzero(rng.random((3, nv)) < 0.3)):
                bounds[family, joint] = bounds[(family + rng.integers(1, 3)) % 3, joint]
        lows[0][rng.random(nv) < 0.1] = -np.inf
        highs[0][rng.random(nv) < 0.1] = np.inf
        box[0], box[1] = lows, highs
        lower, upper = np.maximum.reduce(box[0]), np.minimum.reduce(box[1])
        choice = rng.integers(6, size=nv)
        jitter = rng.uniform(-2, 2, nv) * ACTIVE_TOLERANCE
        inside = rng.uniform(np.maximum(lower, -3), np.minimum(upper, 3))
        command = np.select([choice == 0, choice == 1, choice == 2, choice == 3],
                            [lower, upper, lower + jitter, upper + jitter], inside)
        command = np.where(np.isfinite(command), command, inside)
        families = (JointBounds(box[0, 0], box[1, 0]), JointBounds(box[0, 1], box[1, 1]),
                    JointBounds(box[0, 2], box[1, 2]))  # position, velocity, acceleration
        got = safety._active_box(command, lower, upper)
        assert got == safety._active_bounds(command, lower, upper, families)
    finally:
        box[...] = saved
