"""Resume never loses or repeats an episode and says what it did: the states a kill can leave
(0-byte logs before the first checkpoint, rows logged after the last checkpoint, a row cut off
mid-line, a torn checkpoint, only torn checkpoints) rebuilt by hand, then resumed; the log repair
checked against hand-written files. ``test_train.py`` kills a real run with SIGKILL."""

import csv
import importlib.util
import shutil
import sys
from pathlib import Path

import pytest
import yaml

from ahrm_stack.config import apply_overrides, load_raw
from ahrm_stack.learning.run_folder import EPISODE_FIELDS, repair_csv, repair_events
from ahrm_stack.train import main

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("resume_kill", ROOT / "benchmarks" / "resume_kill.py")
resume_kill = sys.modules.setdefault("resume_kill", importlib.util.module_from_spec(_spec))
_spec.loader.exec_module(resume_kill)

TINY = [*resume_kill.TINY, "train.keep_checkpoints=10"]


def _episodes(run: Path) -> list[int]:
    with open(run / "episodes.csv", newline="") as handle:
        return [int(row["episode"]) for row in csv.DictReader(handle)]


def _finished_ok(run: Path) -> int:
    episodes, problems = resume_kill.check_finished(run)
    assert problems == [], problems
    assert _episodes(run) == list(range(1, episodes + 1))
    return episodes


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """One complete tiny run, a checkpoint after every batch (copied by each test)."""
    run = tmp_path_factory.mktemp("finished") / "run"
    assert main([*TINY, "--run-dir", str(run), "--no-progress"]) == 0
    return run


def _copy(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    return copy


def test_killed_before_the_first_checkpoint_with_empty_logs_starts_over(tmp_path, capsys):
    """The issue's state: config.yaml written, the logs created but still 0 bytes, no checkpoint."""
    run = tmp_path / "run"
    run.mkdir()
    raw = load_raw()
    apply_overrides(raw, TINY)
    (run / "config.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    for name in ("episodes.csv", "batches.csv", "evaluations.csv", "events.jsonl"):
        (run / name).write_bytes(b"")
    assert main(["--resume", str(run), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "has no checkpoint" in out and "from scratch" in out
    with open(run / "episodes.csv") as handle:
        assert handle.readline().strip() == ",".join(EPISODE_FIELDS)
    assert _finished_ok(run) >= 6


def test_rows_logged_after_the_checkpoint_are_dropped_not_repeated(finished, tmp_path, capsys):
    run = _copy(finished, tmp_path)
    checkpoints = sorted((run / "checkpoints").glob("ckpt-*.pt"))
    assert len(checkpoints) >= 3
    keep = checkpoints[1]  # the kill came after this one; the later rows were already flushed
    import torch
    counted = torch.load(keep, weights_only=True)["counters"]["episodes"]
    for later in checkpoints[2:]:
        later.unlink()
    (run / "policy.pt").unlink()
    with open(run / "episodes.csv", "a") as handle:
        handle.write('99,640,40,2.0,False,nan,0,0.0,"[0, 4')  # a row cut off mid-line
    assert main(["--resume", str(run), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"resumed {run} from {keep.name}: episode {counted}" in out
    assert "dropped the rows logged after it" in out
    _finished_ok(run)


def test_a_torn_checkpoint_is_named_and_the_previous_one_used(finished, tmp_path, capsys):
    run = _copy(finished, tmp_path)
    checkpoints = sorted((run / "checkpoints").glob("ckpt-*.pt"))
    newest = checkpoints[-1]
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])
    (run / "policy.pt").unlink()
    assert main(["--resume", str(run), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert f"torn or truncated checkpoint {newest}" in captured.err
    assert f"moved aside to {newest.name}.corrupt" in captured.err
    assert f"from {checkpoints[-2].name}" in captured.out
    assert (newest.parent / f"{newest.name}.corrupt").is_file()
    _finished_ok(run)


def test_only_torn_checkpoints_is_an_error_not_a_restart(finished, tmp_path, capsys):
    run = _copy(finished, tmp_path)
    for path in (run / "checkpoints").glob("ckpt-*.pt"):
        path.write_bytes(path.read_bytes()[:100])
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert main(["--resume", str(run), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "can be read" in err[0] and str(run / "checkpoints") in err[0]
    assert "not restarting from scratch" in err[0]
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


def test_a_fresh_run_into_a_folder_with_checkpoints_is_refused(finished, tmp_path, capsys):
    run = _copy(finished, tmp_path)
    assert main([*TINY, "--run-dir", str(run), "--no-progress"]) == 2
    assert f"use --resume {run}" in capsys.readouterr().err


# ---------------------------------------------------------------------------- the repair, by hand


def test_repair_restores_the_header_drops_late_torn_and_repeated_rows(tmp_path):
    path = tmp_path / "log.csv"
    # written by a run that resumed before this fix: no header, episodes 2-3 logged twice (the
    # second time by the run that continued), a row past the checkpoint, a row cut off
    path.write_text("1,a\n2,b\n3,c\n2,B\n3,C\n4,D\n5,E\n6,F")
    assert repair_csv(path, ["episode", "x"], "episode", 4) == (4, 4)
    assert path.read_bytes() == b"episode,x\r\n1,a\r\n2,B\r\n3,C\r\n4,D\r\n"  # csv's line ends
    # idempotent, and a missing file gets its header
    assert repair_csv(path, ["episode", "x"], "episode", 4) == (4, 0)
    assert repair_csv(tmp_path / "new.csv", ["episode", "x"], "episode", 4) == (0, 0)
    assert (tmp_path / "new.csv").read_bytes() == b"episode,x\r\n"


def test_repair_keeps_an_older_header_s_columns_by_name(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text("x,episode\na,1\nb,2\n")
    assert repair_csv(path, ["episode", "x", "y"], "episode", 1) == (1, 1)
    assert path.read_bytes() == b"episode,x,y\r\n1,a,\r\n"


def test_repair_events_keeps_complete_lines_up_to_the_checkpoint(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_text('{"episode": 1}\n{"episode": 3}\nnot json\n{"episode": 2}\n{"epi')
    assert repair_events(path, 2) == (2, 3)
    assert path.read_text() == '{"episode": 1}\n{"episode": 2}\n'


def test_a_flipped_bit_is_caught_by_the_checksum(tmp_path):
    """torch.load itself loads a checkpoint with a flipped bit in a tensor without complaint."""
    import torch

    from ahrm_stack.learning.checkpoint import CheckpointError, CheckpointManager

    manager = CheckpointManager(tmp_path, keep=2)
    state = {"actor": {"w": torch.arange(1000, dtype=torch.float32)}, "critic": {}, "optimizer": {},
             "mechanism": {}, "time_objective": [], "torch_rng": torch.get_rng_state(), "env_rng": [],
             "counters": {"episodes": 3, "frames": 64, "batches": 1}}
    path = manager.save(state, 1)
    assert manager.restore().state["counters"]["episodes"] == 3
    data = bytearray(path.read_bytes())
    data[data.find(torch.tensor([500.0]).numpy().tobytes())] ^= 0xFF
    path.write_bytes(bytes(data))
    assert torch.load(path, weights_only=True)["actor"]["w"][500] != 500  # silently wrong
    with pytest.raises(CheckpointError, match=r"ckpt-0000001\.pt .*SHA-256 .* differs"):
        manager.restore()
