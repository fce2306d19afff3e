"""The issue-56 tables in docs/ are generated from the committed run data, not typed: each is
regenerated here from its runs/ folder and must equal the committed table.md."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "studies"))

import paper_diagnosis  # noqa: E402
import planner_free  # noqa: E402


@pytest.mark.parametrize("module, folder", [(planner_free, "docs/planner-free"),
                                            (paper_diagnosis, "docs/paper-diagnosis")])
def test_the_committed_table_is_its_data(module, folder, tmp_path):
    source = ROOT / folder
    if not (source / "runs").is_dir():
        pytest.skip(f"{folder} holds no runs yet")
    copy = tmp_path / "out"
    shutil.copytree(source, copy)
    assert module.write_table(copy) == (source / "table.md").read_text()



def test_the_committed_planner_free_test_table_is_its_reads():
    """docs/planner-free/test.md is regenerated from the committed suite-test/ and robustness/
    folders of the frozen recipe's seeds (tools/results_headlines.py, which may name the test
    split: the studies may not), not typed."""
    import importlib.util

    source = ROOT / "docs" / "planner-free" / "test.md"
    if not source.is_file():
        pytest.skip("no planner-free policy has been read on the test split yet")
    spec = importlib.util.spec_from_file_location("results_headlines", ROOT / "tools" / "results_headlines.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("results_headlines", module)
    spec.loader.exec_module(module)
    assert module.planner_free_table(ROOT) == source.read_text()


def test_the_committed_estop_table_is_its_data(tmp_path):
    """The Gen3 e-stop diagnosis (studies/estop_diagnosis.py) is rendered from its committed CSVs."""
    import estop_diagnosis

    source = ROOT / "docs" / "policies" / "gen3-default-seed0" / "robustness"
    copy = tmp_path / "out"
    shutil.copytree(source, copy)
    assert estop_diagnosis.write_tables(copy, "docs/policies/gen3-default-seed0") == (source / "estops.md").read_text()


def test_the_committed_contact_residual_table_is_its_data(tmp_path):
    """docs/contact-residual/table.md (studies/contact_residual.py) is rendered from its rows.csv.gz."""
    import contact_residual

    source = ROOT / "docs" / "contact-residual"
    copy = tmp_path / "out"
    shutil.copytree(source, copy)
    assert contact_residual.render(copy) == (source / "table.md").read_text()


def test_each_arms_contact_thresholds_are_derived_from_the_committed_rows():
    """configs/robots/<arm>.yaml's contact_threshold_nm is 1.25 x the largest external-torque estimate
    held on 2 readings over that arm's normal runs in docs/contact-residual/rows.csv.gz, rounded up to
    the N·m (the rule the files state; a threshold typed by hand would drift from its data)."""
    import math

    import contact_residual

    from ahrm_stack.config import arm_names, load_arm

    rows = contact_residual._read_rows(ROOT / "docs" / "contact-residual")
    for arm in arm_names():
        mine = [r for r in rows if r["robot"] == arm]
        assert mine, f"no contact-residual rows for {arm}"
        joints = len(load_arm(arm).home_deg)
        derived = [math.ceil(1.25 * max(float(r["estimate_held2_max_nm"]) for r in mine if int(r["joint"]) == j))
                   for j in range(joints)]
        assert list(load_arm(arm).contact_threshold_nm) == derived, arm
