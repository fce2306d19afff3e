"""Named evaluation layouts (configs/layouts.yaml) and ``evaluate --layout``."""

import json

import pytest
import yaml

from ahrm_stack.config import ConfigError, load_raw
from ahrm_stack.env.layout_catalog import apply_layout, load_layouts
from ahrm_stack.evaluate import evaluate
from ahrm_stack.learning.rollouts import EVAL_SEED_OFFSET


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
    assert EVAL_SEED_OFFSET not in offsets and len(offsets) == 2
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


def test_scripted_evaluation_on_the_mirrored_layout(tmp_path):
    result = evaluate(None, 1, layout="mirrored", out=tmp_path, quiet=True)
    assert result["layout"] == "mirrored" and result["layout_mode"] == "fixed"
    assert result["successes"] == 1 and result["touched_episodes"] == 0
    assert json.loads((tmp_path / "evaluation.json").read_text())["seed_offset"] == \
        load_layouts()["mirrored"].seed_offset


def test_the_suite_is_every_family_marked_suite_and_evaluates_with_the_scripted_row(tmp_path):
    from ahrm_stack.env.layout_catalog import suite_names
    from ahrm_stack.evaluate import evaluate_suite

    names = suite_names()
    assert "fixed" not in names and "random" not in names
    assert {"default", "heldout", "heldout_far", "edge_plus_x", "edge_minus_x", "toward_arm"} <= set(names)
    # the committed policy (an older run folder: its missing keys keep the old behaviour)
    suite = evaluate_suite("docs/policies/ahrm-default-seed0", 1, tmp_path, families=["default", "mirrored"],
                           quiet=True)
    assert set(suite["results"]) == set(suite["scripted"]) == {"default", "mirrored"}
    assert suite["scripted"]["default"]["successes"] == 1
    for family in ("default", "mirrored"):  # the same episodes for the policy and the controller
        assert suite["results"][family]["seed_offset"] == suite["scripted"][family]["seed_offset"] \
            == load_layouts()[family].seed_offset
    table = (tmp_path / "suite.md").read_text()
    assert "| default | 1/1 | 0 |" in table and "scripted successes" in table
    assert json.loads((tmp_path / "suite.json").read_text())["families"] == ["default", "mirrored"]
