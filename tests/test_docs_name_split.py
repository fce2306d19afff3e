"""Every page of docs/ (and the README) that reports success counts says which seeds they are on:
the ``validation`` split, the sealed ``test`` split, or another named seed range of
configs/seeds.yaml (``robustness``, the demonstration seeds). Pages written before the split
existed (2026-12-04) carry the legacy line :data:`LEGACY_LINE` (issue 42, item 1)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: A table row with a count "k/n" in it: a success figure.
_COUNT_ROW = re.compile(r"^\|.*\b\d+/\d+\b.*\|\s*$", re.M)
#: What naming the seeds looks like.
_NAMES_SEEDS = re.compile(r"validation|test split|seeds `robustness`|demonstration seeds", re.I)

LEGACY_LINE = ("Seeds: the validation split of configs/seeds.yaml (written before the test split existed, "
               "2026-12-04, when this range, then called `evaluation`, was the only one).")


def pages_without_split(root: Path = ROOT) -> list[str]:
    pages = [*sorted((root / "docs").rglob("*.md")), root / "README.md"]
    return [str(p.relative_to(root)) for p in pages
            if _COUNT_ROW.search(p.read_text()) and not _NAMES_SEEDS.search(p.read_text())]


def test_every_page_with_success_counts_names_its_seeds() -> None:
    missing = pages_without_split()
    assert not missing, f"pages with success counts that name no split: {missing}"


def test_the_check_sees_a_page_without_a_split(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("no figures\n")
    (tmp_path / "docs" / "a.md").write_text("| policy | 39/40 |\n")
    (tmp_path / "docs" / "b.md").write_text(LEGACY_LINE + "\n\n| policy | 39/40 |\n")
    (tmp_path / "docs" / "c.md").write_text("| time | 2.5 s |\n")
    assert pages_without_split(tmp_path) == ["docs/a.md"]
