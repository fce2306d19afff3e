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


def test_the_committed_planner_free_test_table_is_its_reads(tmp_path):
    """docs/planner-free/test.md is regenerated from the committed suite-test/ folders of the frozen
    recipe's seeds (the one test read per policy), not typed."""
    source = ROOT / "docs" / "planner-free"
    if not (source / "test.md").is_file():
        pytest.skip("no planner-free policy has been read on the test split yet")
    copy = tmp_path / "docs" / "planner-free"
    shutil.copytree(source, copy)
    assert planner_free.write_test_table(copy) == (source / "test.md").read_text()
