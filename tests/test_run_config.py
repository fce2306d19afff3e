"""A run folder's config.yaml: written with its schema_version, read by one load_run_config (legacy
markers fill keys added since), migrated once; the committed run folders are migrated and every
legacy marker is held to a real old file.

``tests/data/legacy_run_configs/<path>/config.yaml`` are copies of ``docs/<path>/config.yaml`` as
they were before the migration (no schema_version; together they lack every key that has a legacy
marker): each must load to the same configuration as its migrated twin under ``docs/``."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from ahrm_stack.config import SCHEMA_VERSION, Config, ConfigError, config_from_dict, load_config
from ahrm_stack.run_config import (load_run_config, main, migrate_run_config, run_config_dict, run_config_text,
                                   run_folders)
from ahrm_stack.schema import Legacy, fill_legacy, markers, section_fields

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
LEGACY = ROOT / "tests" / "data" / "legacy_run_configs"
OLD_RUNS = sorted(p.parent for p in LEGACY.rglob("config.yaml"))


def _missing(data: dict, cls: type, prefix: str = "") -> set[str]:
    """The dotted keys with a legacy marker that ``data`` (a section's mapping) lacks."""
    out = set()
    sections = section_fields(cls)
    for name, mark in markers(cls, Legacy).items():
        if name not in data and mark is not None:  # filled: its own keys too, where the value lacks them
            out.add(f"{prefix}{name}")
            if name in sections and isinstance(mark.value, dict):
                out |= _missing(mark.value, sections[name], f"{prefix}{name}.")
        elif name in sections and isinstance(data[name], dict):
            out |= _missing(data[name], sections[name], f"{prefix}{name}.")
    return out


def _marked(cls: type, prefix: str = "") -> set[str]:
    """Every dotted key of ``cls`` that carries a legacy marker."""
    out = {f"{prefix}{name}" for name, mark in markers(cls, Legacy).items() if mark is not None}
    for name, sub in section_fields(cls).items():
        out |= _marked(sub, f"{prefix}{name}.")
    return out


# ------------------------------------------------------------------ the committed run folders


def test_every_committed_run_config_is_migrated_and_complete():
    folders = run_folders(DOCS)
    assert len(folders) >= 62
    for folder in folders:
        raw = yaml.safe_load((folder / "config.yaml").read_text())
        assert raw["schema_version"] == SCHEMA_VERSION, folder
        del raw["schema_version"]
        assert fill_legacy(Config, raw) is raw, f"{folder}: keys left to the legacy markers"
        config = load_run_config(folder)
        assert (folder / "config.yaml").read_text() == run_config_text(config), folder


@pytest.mark.parametrize("old", OLD_RUNS, ids=lambda p: str(p.relative_to(LEGACY)))
def test_an_old_run_config_loads_as_its_migrated_twin(old):
    twin = DOCS / old.relative_to(LEGACY)
    assert "schema_version" not in (old / "config.yaml").read_text()
    assert load_run_config(old) == load_run_config(twin)


def test_every_legacy_marker_is_held_to_an_old_file():
    lacking = set().union(*(_missing(yaml.safe_load((old / "config.yaml").read_text()), Config)
                            for old in OLD_RUNS))
    assert lacking == _marked(Config), "a legacy marker that no old file exercises"


def test_a_key_without_a_legacy_marker_is_required():
    data = load_config().to_dict()
    del data["ppo"]["learning_rate"]
    with pytest.raises(ConfigError, match=r"^missing config key 'ppo.learning_rate'"):
        config_from_dict(data)


def test_filling_leaves_the_file_s_mapping_alone():
    raw = yaml.safe_load((OLD_RUNS[0] / "config.yaml").read_text())
    kept = yaml.safe_load((OLD_RUNS[0] / "config.yaml").read_text())
    config_from_dict(raw, runnable=False)
    assert raw == kept


# ------------------------------------------------------------------ writing, reading, migrating


def test_a_run_config_records_its_version_and_reads_back(tmp_path):
    config = load_config(["ppo.epochs=3"])
    assert run_config_dict(config) == {"schema_version": SCHEMA_VERSION, **config.to_dict()}
    (tmp_path / "config.yaml").write_text(run_config_text(config))
    assert load_run_config(tmp_path) == config
    assert config_from_dict(yaml.safe_load(run_config_text(config))) == config


def test_training_writes_the_versioned_file(tmp_path):
    from ahrm_stack.learning.run_folder import write_config

    config = load_config()
    write_config(tmp_path / "run", config)
    assert (tmp_path / "run" / "config.yaml").read_text() == run_config_text(config)
    assert load_run_config(tmp_path / "run") == config


def test_overrides_apply_after_the_legacy_fill(tmp_path):
    old = OLD_RUNS[0]
    config = load_run_config(old, ["task.episode.sleep=true", "ppo.normalizer_min_std=0.01"])
    assert config.task.episode.sleep is True and config.ppo.normalizer_min_std == 0.01
    with pytest.raises(ConfigError, match=r"ppo.learning_rate must be > 0, got -1.0 \(override\)"):
        load_run_config(old, ["ppo.learning_rate=-1"])


@pytest.mark.parametrize("version, text", [(SCHEMA_VERSION + 1, "is not a version this code reads"),
                                           ("one", "is not a version this code reads"),
                                           (-1, "is not a version this code reads")])
def test_an_unknown_schema_version_is_one_line(tmp_path, version, text):
    data = {"schema_version": version, **load_config().to_dict()}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=rf"^schema_version: .* {text} .*\({tmp_path}/config.yaml\)$") as error:
        load_run_config(tmp_path)
    assert "\n" not in str(error.value)


def test_a_missing_or_broken_run_config_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_run_config(tmp_path)
    (tmp_path / "config.yaml").write_text("task: [unclosed")
    with pytest.raises(ConfigError, match=r"config.yaml: not valid YAML"):
        load_run_config(tmp_path)


def test_migration_rewrites_once_and_keeps_the_configuration(tmp_path, capsys):
    run = tmp_path / "docs" / "run"
    run.mkdir(parents=True)
    shutil.copy(OLD_RUNS[0] / "config.yaml", run / "config.yaml")
    (run / "policy.pt").write_bytes(b"")  # marks the folder as a run
    before = load_run_config(run)
    assert main([str(tmp_path / "docs")]) == 0
    assert "1 of 1 run configs rewritten" in capsys.readouterr().out
    assert yaml.safe_load((run / "config.yaml").read_text())["schema_version"] == SCHEMA_VERSION
    assert load_run_config(run) == before
    assert migrate_run_config(run) is False  # already at this version
    assert main([str(tmp_path / "nowhere")]) == 2
    assert "no such folder" in capsys.readouterr().err
