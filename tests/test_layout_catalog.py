"""Named evaluation layouts (configs/layouts.yaml) and ``evaluate --layout``."""

import json

import pytest
import yaml

from ahrm_stack.config import ConfigError, load_raw
from ahrm_stack.env.layout_catalog import apply_layout, load_layouts
from ahrm_stack.evaluation import evaluate
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET


def test_default_is_the_tasks_fixed_layout():
    task = load_raw()["task"]
    default = load_layouts()["default"]
    assert [list(xy) for xy in default.obstacles] == task["obstacles"]["fixed_layout"]
    assert list(default.cube) == task["cube"]["position"]


def test_every_named_layout_passes_the_placement_rules():
    for name in load_layouts():
        apply_layout(load_raw(), name)  # raises on a broken rule


def test_held_out_layouts_use_reserved_seeds_and_their_own_range():
    layouts = load_layouts()
    offsets = {layouts[n].seed_offset for n in ("heldout", "heldout_far")}
    assert VALIDATION_SEED_OFFSET not in offsets and len(offsets) == 2
    raw = load_raw()
    training_range = raw["task"]["layout"]["radial_range"]
    apply_layout(raw, "heldout_far")
    assert raw["task"]["layout"]["mode"] == "random"
    assert raw["task"]["layout"]["radial_range"] != training_range
    assert raw["task"]["layout"]["radial_range"][0] >= training_range[1]   # disjoint distances


def test_applying_a_fixed_layout_sets_cube_and_obstacles():
    raw = load_raw()
    apply_layout(raw, "offset_cube")
    assert raw["task"]["cube"]["position"] == [0.0, 0.1]
    assert raw["task"]["obstacles"]["fixed_layout"][0] == [0.15, 0.15]


def test_bad_layouts_fail_with_the_file_and_the_name(tmp_path):
    with pytest.raises(ConfigError, match="known layouts"):
        apply_layout(load_raw(), "nowhere")
    path = tmp_path / "layouts.yaml"
    path.write_text(yaml.safe_dump({"three": {"mode": "fixed", "cube": [0, 0],
                                              "obstacles": [[0.2, 0.2], [-0.2, 0.2], [0.2, -0.2]]}}))
    with pytest.raises(ConfigError, match="'three' has 3 obstacles; the run has 4"):
        apply_layout(load_raw(), "three", path)
    path.write_text(yaml.safe_dump({"overlap": {"mode": "fixed", "cube": [0, 0],
                                                "obstacles": [[0.01, 0], [0.2, 0.2], [-0.2, 0.2], [0.2, -0.2]]}}))
    with pytest.raises(ConfigError, match="layout 'overlap': .*obstacle 0 .* overlaps cube"):
        apply_layout(load_raw(), "overlap", path)
    path.write_text(yaml.safe_dump({"typo": {"mode": "fixed", "cubes": [0, 0]}}))
    with pytest.raises(ConfigError, match=r"unknown config key 'typo\.cubes'; allowed keys here: .*'cube'"):
        load_layouts(path)
    path.write_text(yaml.safe_dump({"mixed": {"mode": "random", "obstacles": [[0.2, 0.2]]}}))
    with pytest.raises(ConfigError, match="fixed layouts only"):
        load_layouts(path)
    for key, value in (("cube_region", [[0.2, 0.1], [0, 0.1]]), ("start_region", [[0, 0.1], [0.3, 0.0], [0.6, 0.7]]),
                       ("cube_mass_scale", [2.0, 1.0]), ("radial_range", [0.3, 0.2])):
        path.write_text(yaml.safe_dump({"bad": {"mode": "random", key: value}}))
        with pytest.raises(ConfigError, match=rf"^bad\.{key} must be \[lo, hi\] with lo <= hi"):
            load_layouts(path)
    path.write_text(yaml.safe_dump({"bad": {"mode": "random", "cube_friction_scale": [0.0, 1.0]}}))
    with pytest.raises(ConfigError, match=r"bad\.cube_friction_scale\[0\] must be > 0"):
        load_layouts(path)


def test_scripted_evaluation_on_the_mirrored_layout(tmp_path):
    result = evaluate(None, 1, layout="mirrored", out=tmp_path, quiet=True)
    assert result["layout"] == "mirrored" and result["layout_mode"] == "fixed"
    assert result["successes"] == 1 and result["touched_episodes"] == 0
    assert json.loads((tmp_path / "evaluation.json").read_text())["seed_offset"] == \
        load_layouts()["mirrored"].seed_offset


def test_the_suite_is_every_family_marked_suite_and_evaluates_with_the_scripted_row(tmp_path):
    from ahrm_stack.env.layout_catalog import suite_names
    from ahrm_stack.evaluation import evaluate_suite

    names = suite_names()
    assert "fixed" not in names and "random" not in names
    assert {"default", "heldout", "heldout_far", "edge_plus_x", "edge_minus_x", "toward_arm"} <= set(names)
    # the committed policy (an older run folder: its missing keys keep the old behaviour)
    # the fixed-layout policy: its training support holds the default family ("inside")
    suite = evaluate_suite("docs/policies/ahrm-fixed-layout-seed0", 1, tmp_path, families=["default", "mirrored"],
                           quiet=True)
    assert set(suite["results"]) == set(suite["scripted"]) == {"default", "mirrored"}
    assert suite["scripted"]["default"]["successes"] == 1
    for family in ("default", "mirrored"):  # the same episodes for the policy and the controller
        assert suite["results"][family]["seed_offset"] == suite["scripted"][family]["seed_offset"] \
            == load_layouts()[family].seed_offset
    table = (tmp_path / "suite.md").read_text()
    assert "| default | inside | 1/1 | 0 |" in table and "scripted successes" in table
    # the committed run trained on the fixed default layout: the mirrored obstacles lie outside its support
    assert "| mirrored | outside: obstacles |" in table and "validation split" in table
    assert json.loads((tmp_path / "suite.json").read_text())["families"] == ["default", "mirrored"]


def _support(name):
    """The family's training support against the default training config (configs/)."""
    from ahrm_stack.config import config_from_dict
    from ahrm_stack.env.layout_catalog import evaluation_task
    from ahrm_stack.env.support import as_dict, training_support

    raw = load_raw()
    entry = apply_layout(raw, name)
    return as_dict(training_support(config_from_dict(load_raw()).task,
                                    evaluation_task(config_from_dict(raw).task, entry)))


def test_out_of_distribution_families_lie_outside_in_the_quantity_they_move():
    """Each new family moves one randomised quantity out of the training support, and only that one
    (computed from configs/task.yaml and the family, not written anywhere by hand)."""
    expected = {"beyond_plus_x": "cube", "beyond_minus_x": "cube", "beyond_toward_arm": "cube",
                "obstacles_near": "obstacles", "heldout_far": "obstacles", "start_plus_x": "start",
                "start_high": "start", "start_far": "start", "cube_heavy": "cube_mass", "cube_light": "cube_mass",
                "cube_grippy": "cube_friction", "cube_slippery": "cube_friction"}
    for name, quantity in expected.items():
        support = _support(name)
        assert support["verdict"] == f"outside: {quantity}", (name, support)
        assert not support["inside"]
    for name in ("heldout", "edge_plus_x", "edge_minus_x", "toward_arm", "corridor", "offset_cube"):
        assert _support(name)["verdict"] == "inside", name
    # the task's fixed layout: the obstacle at (-0.15, 0.16) is 0.205-0.233 m from the jittered cube,
    # partly beyond training's 0.22 m
    default = _support("default")
    assert default["verdict"] == "partly outside: obstacles"
    assert "[0.205, 0.233]" in default["quantities"]["obstacles"]["evaluation"]


def test_a_dynamics_family_sets_the_cube_factors_of_an_otherwise_nominal_evaluation():
    from ahrm_stack.config import config_from_dict
    from ahrm_stack.env.layout_catalog import evaluation_task
    from ahrm_stack.realism import RealismConfig

    raw = load_raw()
    entry = apply_layout(raw, "cube_heavy")
    task = evaluation_task(config_from_dict(raw).task, entry)
    assert task.realism.cube_mass_scale == (2.5, 4.0) and task.realism.cube_friction_scale == (1.0, 1.0)
    assert not task.realism.senses and not task.realism.actuates  # no noise, no lag: nominal otherwise
    assert evaluation_task(config_from_dict(load_raw()).task).realism == RealismConfig.ideal()
    raw = load_raw()
    apply_layout(raw, "start_high")
    assert raw["task"]["arm"]["start"] == "random" and raw["task"]["arm"]["start_region"][2] == [0.76, 0.86]


def test_the_scripted_controller_succeeds_on_every_new_family(tmp_path):
    """Two episodes each: every family is solvable by the scripted controller (on 20 validation
    episodes each it scored 19-20/20 with no touching episode; cube_heavy's first episode stalls)."""
    from ahrm_stack.evaluation import evaluate_suite

    families = ["beyond_plus_x", "beyond_minus_x", "beyond_toward_arm", "obstacles_near", "start_plus_x", "start_high",
                "start_far", "cube_heavy", "cube_light", "cube_grippy", "cube_slippery"]
    suite = evaluate_suite(None, 2, tmp_path, families=families, quiet=True)
    assert all(suite["results"][f]["successes"] >= 1 for f in families), suite["results"]
    assert sum(suite["results"][f]["successes"] for f in families) >= 2 * len(families) - 1
    assert sum(suite["results"][f]["touched_episodes"] for f in families) == 0
    table = (tmp_path / "suite.md").read_text()
    assert "validation split" in table and "| cube_light | outside: cube_mass | 2/2 |" in table
