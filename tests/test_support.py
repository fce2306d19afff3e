"""Training support (ahrm_stack/env/support.py): each randomised quantity of an evaluation against the
training config's, worked out by hand."""

import dataclasses

import pytest

from ahrm_stack.config import config_from_dict, load_raw
from ahrm_stack.env.support import as_dict, box_status, combine, training_support, verdict


@pytest.fixture(scope="module")
def task():
    """configs/task.yaml: random layouts, cube_region [[-0.2, 0.2], [-0.05, 0.15]], radial_range
    [0.14, 0.22], random starts, realism ideal (cube mass and friction x 1)."""
    return config_from_dict(load_raw()).task


def _with(task, **sections):
    """``task`` with fields of its sections replaced: ``layout={"radial_range": (0.1, 0.2)}``."""
    return dataclasses.replace(task, **{name: dataclasses.replace(getattr(task, name), **values)
                                        for name, values in sections.items()})


def _status(training, evaluation):
    return {r.quantity: r.status for r in training_support(training, evaluation)}


def test_boxes_by_hand():
    assert box_status([(0.0, 0.1)], [(-0.2, 0.2)]) == "inside"
    assert box_status([(0.2, 0.25)], [(-0.2, 0.2)]) == "outside"        # shares one edge only
    assert box_status([(0.1, 0.3)], [(-0.2, 0.2)]) == "partly outside"
    assert box_status([(0.5, 0.5)], [(0.0, 1.0)]) == "inside"           # a point inside
    assert box_status([(1.0, 1.0)], [(0.5, 2.0)]) == "inside"           # the nominal factor in a range
    assert box_status([(0.5, 2.0)], [(1.0, 1.0)]) == "outside"          # a range around an ideal point
    assert box_status([(0.0, 0.1), (0.5, 0.6)], [(-1, 1), (0.0, 0.4)]) == "outside"  # one axis out: all out
    assert combine(["inside", "partly outside"]) == "partly outside"
    assert combine(["partly outside", "outside"]) == "outside"


def test_the_training_distribution_is_inside_itself_and_each_quantity_moves_alone(task):
    assert set(_status(task, task).values()) == {"inside"}
    beyond = _with(task, layout={"cube_region": ((0.2, 0.25), (-0.05, 0.15))})
    assert _status(task, beyond) == {"cube": "outside", "obstacles": "inside", "start": "inside",
                                     "cube_mass": "inside", "cube_friction": "inside"}
    assert _status(task, _with(task, layout={"radial_range": (0.1, 0.18)}))["obstacles"] == "partly outside"
    assert _status(task, _with(task, arm={"start_region": ((-0.2, 0.2), (0.0, 0.3), (0.76, 0.86))}))["start"] \
        == "outside"
    heavy = _with(task, realism={"cube_mass_scale": (2.5, 4.0)})
    assert _status(task, heavy)["cube_mass"] == "outside"
    rows = training_support(task, heavy)
    assert verdict(rows) == "outside: cube_mass"
    assert as_dict(rows)["quantities"]["cube_mass"] == {"status": "outside", "evaluation": "× [2.5, 4]",
                                                         "training": "× 1"}


def test_a_fixed_layout_against_random_training_by_the_obstacles_distances(task):
    # cube at the origin jittered +-0.01 m: an obstacle at (0.18, 0) is 0.17-0.19 m away (inside
    # 0.14-0.22); one at (0.215, 0) is 0.205-0.2253 m away (partly beyond 0.22)
    fixed = _with(task, layout={"mode": "fixed"}, cube={"position": (0.0, 0.0), "jitter": 0.01},
                  obstacles={"fixed_layout": ((0.18, 0.0), (0.0, 0.18), (-0.18, 0.0), (0.0, -0.18))})
    assert _status(task, fixed)["obstacles"] == "inside"
    partly = _with(fixed, obstacles={"fixed_layout": ((0.215, 0.0), (0.0, 0.18), (-0.18, 0.0), (0.0, -0.18))})
    assert _status(task, partly)["obstacles"] == "partly outside"
    far = _with(fixed, obstacles={"fixed_layout": ((0.3, 0.0), (0.0, 0.18), (-0.18, 0.0), (0.0, -0.18))})
    assert _status(task, far)["obstacles"] == "outside"  # every episode has that obstacle beyond 0.22 m
    # trained on that one fixed layout: random obstacles lie outside it, the random cube region covers
    # its jitter box and more (partly outside), the same layout is inside
    assert _status(fixed, task)["obstacles"] == "outside" and _status(fixed, task)["cube"] == "partly outside"
    assert _status(fixed, fixed)["obstacles"] == "inside"
    assert _status(fixed, partly)["obstacles"] == "outside"


def test_home_starts_against_random_starts(task):
    home = _with(task, arm={"start": "home"})
    assert _status(home, home)["start"] == "inside"
    assert _status(home, task)["start"] == "outside"
    assert _status(task, home)["start"] == "outside"
    assert _status(home, _with(home, arm={"joint_jitter": 0.2}))["start"] == "outside"  # wider than trained
