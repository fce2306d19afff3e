"""A training run folder's ``config.yaml``: the one way it is written, read and migrated.

The file is the resolved configuration of the run, ``{schema_version: SCHEMA_VERSION,
**config.to_dict()}`` (:func:`run_config_text`). Every reader of a run's configuration (training's
resume, evaluation, the policy loader of rollouts and deploy, studies, benchmarks) calls
:func:`load_run_config`: the version is checked, keys added since the run was written take their
fields' legacy markers (:func:`ahrm_stack.config.fill_missing`), then the overrides apply and the
result is validated, messages naming the file (or "override").

Migrating rewrites files written by older code at this version with every key explicit, and checks
that each loads to the same :class:`~ahrm_stack.config.Config` as before::

    python -m ahrm_stack.run_config [FOLDER ...]   # default: every run folder under docs/
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable, Sequence

import yaml

from ahrm_stack.atomic import write_atomically
from ahrm_stack.cli import Parser
from ahrm_stack.config import (SCHEMA_VERSION, Config, ConfigError, apply_overrides, config_from_dict, config_source,
                               fill_missing)
from ahrm_stack.schema import read_yaml

RUN_CONFIG = "config.yaml"  # a run folder's resolved configuration
DOCS = Path(__file__).resolve().parent.parent / "docs"  # the committed run folders lie below


def run_config_dict(config: Config) -> dict:
    """What a run folder's ``config.yaml`` holds: the schema version, then ``config.to_dict()``."""
    return {"schema_version": SCHEMA_VERSION, **config.to_dict()}


def run_config_text(config: Config) -> str:
    """The text of a run folder's ``config.yaml`` for ``config`` (YAML, keys in field order)."""
    return yaml.safe_dump(run_config_dict(config), sort_keys=False)


def load_run_config(run_dir: Path | str, overrides: Sequence[str] = (), *, runnable: bool = True,
                    edit: Callable[[dict], None] | None = None) -> Config:
    """The validated configuration of the run in ``run_dir`` (its ``config.yaml``).

    Keys added since the run was written are filled first (their legacy markers), so that
    ``overrides`` (``key=value``, ``profile=NAME``) may set them; ``edit`` then changes the mapping
    in place before validation (evaluation's named layouts). ``runnable``: also refuse
    combinations that cannot run (deploy, which replaces the safety section, reads with False).
    Raises :class:`ConfigError` in one line naming the file: missing, not YAML, an unknown
    ``schema_version``, a bad key or value."""
    path = Path(run_dir) / RUN_CONFIG
    raw = read_yaml(path)  # one-line errors for a missing, broken or non-mapping file
    source = config_source(overrides=overrides, path=path)
    try:
        raw = fill_missing(raw)
    except ConfigError as error:
        raise ConfigError(f"{error} ({path})") from None
    apply_overrides(raw, overrides)
    if edit is not None:
        edit(raw)
    return config_from_dict(raw, runnable, source)


def migrate_run_config(run_dir: Path | str) -> bool:
    """Rewrite ``run_dir/config.yaml`` as :func:`run_config_text` writes it today (this
    ``schema_version``, every key explicit), atomically. Returns whether the file changed. Raises
    :class:`ConfigError` if the file does not load, or if the rewritten file would not load to the
    same :class:`~ahrm_stack.config.Config` (then nothing is written)."""
    path = Path(run_dir) / RUN_CONFIG
    before = config_from_dict(read_yaml(path), runnable=False, source=path)
    text = run_config_text(before)
    if path.read_text() == text:
        return False
    after = config_from_dict(yaml.safe_load(text), runnable=False, source=path)
    if after != before:
        raise ConfigError(f"{path}: the migrated file would load to another configuration; left as it was")
    write_atomically(path, text)
    return True


def run_folders(root: Path | str) -> list[Path]:
    """Every folder at or below ``root`` that holds a ``config.yaml`` of a run (a sibling policy,
    checkpoint folder, evaluation or training log marks it as one), sorted."""
    marks = ("policy.pt", "checkpoints", "evaluation.yaml", "evaluation.json", "episodes.csv", "episodes.csv.gz",
             "batches.csv", "batches.csv.gz", "events.jsonl", "events.jsonl.gz")
    found = [p.parent for p in Path(root).rglob(RUN_CONFIG)]
    return sorted(folder for folder in found if any((folder / mark).exists() for mark in marks))


def main(argv: Sequence[str] | None = None) -> int:
    """Migrate the run folders at or below each given folder (default ``docs/``); prints each
    rewritten file. Exit status 0, or 2 with a one-line error."""
    parser = Parser(prog="python -m ahrm_stack.run_config", description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="*", type=Path, default=[DOCS], help="default: docs/")
    args = parser.parse_args(argv)
    changed = total = 0
    try:
        for root in args.folders:
            if not root.is_dir():
                raise ConfigError(f"{root}: no such folder")
            for folder in run_folders(root):
                total += 1
                if migrate_run_config(folder):
                    changed += 1
                    print(f"migrated {folder / RUN_CONFIG}")
    except ConfigError as error:
        print(f"python -m ahrm_stack.run_config: error: {error}", file=sys.stderr)
        return 2
    print(f"{changed} of {total} run configs rewritten at schema_version {SCHEMA_VERSION}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
