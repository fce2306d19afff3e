"""Seed ranges (configs/seeds.yaml): disjoint, a validation and a test range per evaluation family,
used where they are named. The test split's seal is tested in test_sealed_split.py."""

import numpy as np
import pytest
import yaml

from ahrm_stack.config import ConfigError
from ahrm_stack.env.layout_catalog import load_layouts
from ahrm_stack.learning.demonstrations import DEMO_SEED_OFFSET
from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET
from ahrm_stack.seeds import evaluation_range, load_seed_table, seed_table, training_seeds


def test_ranges_are_pairwise_disjoint():
    """Every range, both evaluation splits of every set included."""
    ranges = seed_table().every_range()
    assert len(ranges) == len(seed_table().ranges) + 2 * len(seed_table().evaluation)
    for i, a in enumerate(ranges):  # every pair, not only neighbours in start order
        for b in ranges[i + 1:]:
            assert a.stop <= b.start or b.stop <= a.start, (a, b)


def test_every_family_has_a_validation_and_a_test_range_of_its_own():
    table = seed_table()
    assert set(table.evaluation) == set(load_layouts()) | {"run"}  # no family without, no stale entry
    starts = {}
    for name, family in load_layouts().items():
        splits = table.evaluation[name]
        assert family.seed_offset == splits.validation.start == evaluation_range(name).start
        assert splits.validation.stop <= splits.test.start or splits.test.stop <= splits.validation.start
        starts[name] = (splits.validation.start, splits.test.start)
    assert len({s for pair in starts.values() for s in pair}) == 2 * len(starts)
    demo, train = table["demonstrations"], table["training"]
    run = table.evaluation["run"]
    for name in starts:
        for family in (table.evaluation[name].validation, table.evaluation[name].test):
            for other in (demo, train, run.validation, run.test):
                assert family.stop <= other.start or other.stop <= family.start


def test_validation_keeps_the_numbers_of_the_former_evaluation_range():
    """Committed results stay reproducible: the run's own validation seeds are the former
    `evaluation` range, and each family's validation range its former range."""
    table = seed_table()
    run = table.evaluation["run"].validation
    assert (run.start, run.size) == (2_000_000, 1_000_000)
    assert table.evaluation["heldout"].validation.start == 3_600_000
    assert table.evaluation["toward_arm"].validation.start == 4_000_000


def test_the_code_uses_the_table():
    table = seed_table()
    assert DEMO_SEED_OFFSET == table["demonstrations"].start
    assert VALIDATION_SEED_OFFSET == table.evaluation["run"].validation.start
    assert training_seeds(3, 2) == [3, 3 + table.env_stride]
    # the demonstrations of the default budget and of a large one stay inside their range
    assert DEMO_SEED_OFFSET + 10_000 < table["demonstrations"].stop


def test_training_seeds_outside_the_range_are_refused():
    table = seed_table()
    with pytest.raises(ConfigError, match="train.seed must be in"):
        training_seeds(table.env_stride, 1)
    with pytest.raises(ConfigError, match="leaves the training seed range"):
        training_seeds(0, table["training"].size // table.env_stride + 1)


LEDGER = {"test_ledger": "l.jsonl"}  # the file's one non-range key


def test_overlapping_ranges_fail_naming_both(tmp_path):
    path = tmp_path / "seeds.yaml"
    run = {"run": {"validation": [1000, 10], "test": [2000, 10]}}
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {
        "training": [0, 100], "demonstrations": [50, 100]}, "evaluation": run, **LEDGER}))
    with pytest.raises(ConfigError, match="'training' .* and 'demonstrations' .* overlap"):
        load_seed_table(path)
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {"training": [0, -1]}, "evaluation": run, **LEDGER}))
    with pytest.raises(ConfigError, match="training size must be an integer >= 1"):
        load_seed_table(path)
    # a family's test range inside another family's validation range
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {"training": [0, 100], "demonstrations": [100, 100]},
                                    "evaluation": {**run, "a": {"validation": [3000, 10], "test": [3005, 10]}},
                                    **LEDGER}))
    with pytest.raises(ConfigError, match=r"'a \(validation\)' .* and 'a \(test\)' .* overlap"):
        load_seed_table(path)
    path.write_text(yaml.safe_dump({"env_stride": 10, "ranges": {"training": [0, 100], "demonstrations": [100, 100]},
                                    "evaluation": {**run, "a": {"validation": [3000, 10]}}, **LEDGER}))
    with pytest.raises(ConfigError, match="evaluation.a.test"):
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
    starts = {r.start for r in seed_table().every_range() if r.start > 1_000_000}
    found = []
    for folder in ("ahrm_stack", "benchmarks"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Constant) and type(node.value) is int and node.value in starts:
                    found.append(f"{path.relative_to(root)}:{node.lineno}: {node.value}")
    assert not found, found
