"""Seed ranges (configs/seeds.yaml): disjoint, one per evaluation family, used where they are named."""

import numpy as np
import pytest
import yaml

from ahrm_stack.config import ConfigError
from ahrm_stack.env.layout_catalog import load_layouts
from ahrm_stack.learning.demonstrations import DEMO_SEED_OFFSET
from ahrm_stack.learning.rollouts import EVAL_SEED_OFFSET
from ahrm_stack.seeds import load_seed_table, seed_table, training_seeds


def test_ranges_are_pairwise_disjoint():
    ranges = list(seed_table().ranges.values())
    for i, a in enumerate(ranges):  # every pair, not only neighbours in start order
        for b in ranges[i + 1:]:
            assert a.stop <= b.start or b.stop <= a.start, (a, b)


def test_every_family_has_its_own_range_and_no_family_reuses_training_or_demonstrations():
    table = seed_table()
    starts = {}
    for name, family in load_layouts().items():
        assert name in table.ranges
        starts[name] = family.seed_offset
        assert family.seed_offset == table[name].start
    assert len(set(starts.values())) == len(starts)
    demo, train = table["demonstrations"], table["training"]
    for name in starts:
        family = table[name]
        for other in (demo, train, table["evaluation"]):
            assert family.stop <= other.start or other.stop <= family.start


def test_the_code_uses_the_table():
    table = seed_table()
    assert DEMO_SEED_OFFSET == table["demonstrations"].start
    assert EVAL_SEED_OFFSET == table["evaluation"].start
    assert training_seeds(3, 2) == [3, 3 + table.env_stride]
    # the demonstrations of the default budget and of a large one stay inside their range
    assert DEMO_SEED_OFFSET + 10_000 < table["demonstrations"].stop


def test_training_seeds_outside_the_range_are_refused():
    table = seed_table()
    with pytest.raises(ConfigError, match="train.seed must be in"):
        training_seeds(table.env_stride, 1)
    with pytest.raises(ConfigError, match="leaves the training seed range"):
        training_seeds(0, table["training"].size // table.env_stride + 1)


def test_overlapping_ranges_fail_naming_both(tmp_path):
    path = tmp_path / "seeds.yaml"
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {
        "training": [0, 100], "demonstrations": [50, 100], "evaluation": [1000, 10]}}))
    with pytest.raises(ConfigError, match="'training' .* and 'demonstrations' .* overlap"):
        load_seed_table(path)
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {"training": [0, -1]}}))
    with pytest.raises(ConfigError, match="training size must be an integer >= 1"):
        load_seed_table(path)


def test_heldout_does_not_replay_demonstration_layouts():
    """The bug this table fixed: demonstrations and `heldout` shared seed 2,000,000 + i."""
    from ahrm_stack.config import load_raw
    from ahrm_stack.env.layout_catalog import apply_layout
    from ahrm_stack.config import config_from_dict
    from ahrm_stack.env.layout import LayoutSampler

    raw = load_raw()
    heldout = apply_layout(raw, "heldout")
    task = config_from_dict(raw).task
    sampler = LayoutSampler(task.table, task.cube, task.obstacles, task.layout)
    demo = [sampler.sample(np.random.RandomState(DEMO_SEED_OFFSET + i)).cube_xy for i in range(5)]
    held = [sampler.sample(np.random.RandomState(heldout.seed_offset + i)).cube_xy for i in range(5)]
    assert all(not np.allclose(a, b) for a in demo for b in held)


def test_no_range_start_is_written_in_the_code():
    """The ranges are named once: no module of ahrm_stack/, hardware/ or benchmarks/ writes a range's
    start above 1,000,000 as a literal (1,000,000 itself is also a common upper bound); it reads
    seeds.yaml through ahrm_stack.seeds."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    starts = {r.start for r in seed_table().ranges.values() if r.start > 1_000_000}
    found = []
    for folder in ("ahrm_stack", "hardware", "benchmarks"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Constant) and type(node.value) is int and node.value in starts:
                    found.append(f"{path.relative_to(root)}:{node.lineno}: {node.value}")
    assert not found, found
