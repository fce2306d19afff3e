"""The test ledger (ahrm_stack.test_ledger): every read of the sealed test split is recorded, keyed by
the policy file's hash; a policy's second read of a set is refused before anything runs or is
written unless a reason is given, and the reason is recorded; the committed ledger holds every
committed test-split output, each at the test seeds configs/seeds.yaml names for its set."""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import pytest
import torch

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.evaluate import main as evaluate_cli
from ahrm_stack.evaluation import evaluate, evaluate_suite
from ahrm_stack.learning.ppo import make_modules
from ahrm_stack.run_config import run_config_text
from ahrm_stack.seeds import seed_table
from ahrm_stack.test_ledger import LEDGER_ENV, RereadError, ledger_path, policy_key, reads
from ahrm_stack.test_ledger import main as ledger_cli

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from backfill_test_ledger import signature  # noqa: E402
SHORT = ["task.episode.duration=0.5"]  # 10 control steps: the ledger, not the policy, is under test


def _run(tmp_path: Path, name: str = "run") -> Path:
    """A run folder with a config and an (untrained) policy saved as training saves one."""
    config = load_config(SHORT)
    run_dir = tmp_path / name
    run_dir.mkdir()
    (run_dir / "config.yaml").write_text(run_config_text(config))
    env = PushOffEnv(config.task, config.safety, seed=0)
    dims = int(env.observation_spec["observation"].shape[-1]), int(env.action_spec.shape[-1])
    modules = make_modules(config.ppo, *dims)
    torch.save({"actor": modules.actor.state_dict(), "observation_dim": dims[0], "action_dim": dims[1]},
               run_dir / "policy.pt")
    return run_dir


def test_a_policys_first_read_is_recorded_and_its_second_refused_without_a_reason(tmp_path, capsys):
    run = _run(tmp_path)
    first = evaluate(run, 2, layout="default", out=tmp_path / "first", quiet=True, split="test")
    [read] = reads()
    assert read.key == "sha256:" + hashlib.sha256((run / "policy.pt").read_bytes()).hexdigest()
    assert (read.evaluation_set, read.episodes, read.reason) == ("default", 2, "")
    assert read.seed_offset == first["seed_offset"] == seed_table().evaluation["default"].test.start
    assert read.result["successes"] == first["successes"]
    assert read.time and read.policy == str(run)
    # the same bytes in another folder are the same policy: refused, before anything is written
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    with pytest.raises(RereadError, match="already read for this policy"):
        evaluate(copy, 2, layout="default", out=tmp_path / "second", quiet=True, split="test")
    assert not (tmp_path / "second").exists() and len(reads()) == 1
    assert evaluate_cli([str(copy), "--episodes", "2", "--layout", "default", "--split", "test",
                         "--out", str(tmp_path / "cli")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--reason" in err and not (tmp_path / "cli").exists()
    # another set is another read; validation is never recorded
    evaluate(run, 1, layout="mirrored", out=tmp_path / "mirrored", quiet=True, split="test")
    evaluate(run, 1, layout="default", out=tmp_path / "validation", quiet=True)
    assert [r.evaluation_set for r in reads()] == ["default", "mirrored"]
    # with a reason: read, and the reason recorded
    assert evaluate_cli([str(copy), "--episodes", "2", "--layout", "default", "--split", "test",
                         "--reason", "the first read's folder was lost", "--out", str(tmp_path / "cli")]) == 0
    assert reads()[-1].reason == "the first read's folder was lost"
    assert reads()[-1].command.startswith("python")


def test_the_scripted_controller_is_recorded_and_never_refused(tmp_path):
    for out in ("a", "b"):
        evaluate(None, 1, layout="default", out=tmp_path / out, quiet=True, split="test", overrides=SHORT)
    assert [r.policy for r in reads()] == ["scripted controller"] * 2
    assert reads()[0].key == reads()[1].key and reads()[0].key.startswith("scripted-sha256:")


def test_a_suite_is_refused_before_its_first_family_when_one_was_read(tmp_path):
    run = _run(tmp_path)
    evaluate(run, 1, layout="mirrored", out=tmp_path / "one", quiet=True, split="test")
    with pytest.raises(RereadError, match="'mirrored'"):
        evaluate_suite(run, 1, tmp_path / "suite", with_scripted=False, quiet=True, split="test",
                       families=["default", "mirrored"])
    assert not (tmp_path / "suite").exists() and len(reads()) == 1


def test_a_bad_ledger_line_is_one_line_naming_the_file_and_line(tmp_path, monkeypatch, capsys):
    bad = tmp_path / "ledger.jsonl"
    bad.write_text('{"key": "sha256:0"}\nnot json\n')
    monkeypatch.setenv(LEDGER_ENV, str(bad))
    with pytest.raises(ConfigError, match=r"ledger.jsonl:1: not a test-split read"):
        reads()
    assert ledger_cli([]) == 2
    assert "ledger.jsonl:1" in capsys.readouterr().err


def test_reason_without_the_test_split_is_refused(capsys):
    with pytest.raises(SystemExit):
        evaluate_cli(["--policy", "scripted", "--reason", "x"])
    assert "--reason is for a re-read" in capsys.readouterr().err


def test_the_ledger_command_lists_a_policys_reads(tmp_path, capsys):
    run = _run(tmp_path)
    evaluate(run, 1, layout="default", out=tmp_path / "a", quiet=True, split="test")
    assert ledger_cli(["--policy", str(run / "policy.pt")]) == 0
    out = capsys.readouterr().out
    assert "1 reads" in out and "| default | 1 |" in out


def test_the_committed_ledger_holds_every_committed_test_output_at_its_registered_seeds(monkeypatch):
    """Every ``evaluation.json`` under docs/ with ``split: test`` is a read in docs/test-ledger.jsonl
    (those written before the ledger backfilled from them), and each read's first seed is the test
    start configs/seeds.yaml gives its evaluation set (a protocol that names other seeds is wrong)."""
    monkeypatch.delenv(LEDGER_ENV)
    assert ledger_path() == ROOT / "docs" / "test-ledger.jsonl"
    committed = reads()
    table = seed_table()
    for read in committed:
        assert read.seed_offset == table.evaluation[read.evaluation_set].test.start, read
    outputs = [p for p in sorted((ROOT / "docs").rglob("evaluation.json"))
               if json.loads(p.read_text()).get("split") == "test"]
    assert len(outputs) >= 100
    recorded = {signature(r.evaluation_set, r.seed_offset, r.result) for r in committed}
    missing = []
    for path in outputs:
        header = json.loads(path.read_text())
        evaluation_set = header.get("evaluation_set") or next(
            r.evaluation_set for r in committed if r.result.get("output") == str(path.parent.relative_to(ROOT)))
        if signature(evaluation_set, header["seed_offset"], header) not in recorded:
            missing.append(str(path.relative_to(ROOT)))
    assert not missing, missing[:5]
    policies = [r for r in committed if not r.scripted and r.key.startswith("sha256:")]
    assert policies  # the committed frozen policies are keyed by their files' hashes


def test_a_policy_key_is_its_files_hash(tmp_path):
    f = tmp_path / "p.pt"
    f.write_bytes(b"abc")
    assert policy_key(f) == "sha256:" + hashlib.sha256(b"abc").hexdigest()
