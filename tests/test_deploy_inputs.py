"""What deploy accepts: its safety settings come from configs/safety.yaml and a checkpoint can only
tighten them (each difference printed); bad settings, command lines, checkpoints and pickles get a
one-line error before anything is written; a run that breaks after start still ends in a recorded
stop and summary (exit status 3)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
from pathlib import Path

import pytest
import torch
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.config import load_config
from ahrm_stack.deploy import DeployConfigError, load_controller_config, merge_safety, safety_directions
from ahrm_stack.deploy import main as deploy
from ahrm_stack.evaluate import main as evaluate

TRAINED = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0"
PROG = "python -m ahrm_stack.deploy: error:"


@pytest.fixture(scope="module")
def ours():
    return load_config().safety


def _run(tmp_path: Path, safety: dict | None = None, policy: Path | None = None) -> Path:
    """A copy of the committed trained run, its config's safety section updated with ``safety``
    and its policy.pt replaced by ``policy``."""
    run = tmp_path / "run"
    run.mkdir()
    raw = yaml.safe_load((TRAINED / "config.yaml").read_text())
    raw["safety"].update(safety or {})
    (run / "config.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    shutil.copy(policy or TRAINED / "policy.pt", run / "policy.pt")
    return run


# --------------------------------------------------------------------------- merging safety


#: The issue's run folder: no obstacle rows, table and workspace rows off, zero margins,
#: 1000 rad/s^2, and the filter off.
WEAK = {"max_obstacle_rows": 0, "table_rows": False, "workspace_rows": False,
        "table_distance_rows": False, "position_margin": 0.0, "velocity_margin": 0.0,
        "table_margin": 0.0, "wrist_table_margin": 0.0, "acceleration_limit": [1000.0] * 6,
        "enabled": False, "braking_horizon": False}


def test_a_weaker_checkpoint_changes_nothing_and_each_key_is_named(ours):
    weak = dataclasses.replace(ours, **{k: tuple(v) if isinstance(v, list) else v
                                        for k, v in WEAK.items()})
    merged, notes = merge_safety(ours, weak)
    assert merged == ours
    assert {n.key for n in notes} == set(WEAK) and all(n.kind == "weaker" for n in notes)
    note = next(n for n in notes if n.key == "max_obstacle_rows")
    assert note.text == ("safety.max_obstacle_rows: the checkpoint's 0 is weaker than deploy's 8: "
                         "ignored, using 8")


def test_a_stricter_checkpoint_tightens_entry_by_entry(ours):
    assert ours.acceleration_limit == (4.0, 4.0, 4.0, 6.0, 6.0, 6.0)  # configs/robots/jaco.yaml
    theirs = dataclasses.replace(
        ours, position_margin=0.1, acceleration_limit=(3.0, 4.0, 5.0, 6.0, 6.0, 2.0),
        workspace_upper=(0.5, 1.2, 1.4), obstacle_rows=True, max_obstacle_rows=12,
        solver="osqp" if ours.solver == "daqp" else "daqp", osqp_max_iter=10)
    merged, notes = merge_safety(ours, theirs)
    # By hand: the larger margin and row count, the smaller limit per entry, the box's
    # intersection, the rows on; solver numerics stay deploy's.
    assert merged == dataclasses.replace(
        ours, position_margin=0.1, acceleration_limit=(3.0, 4.0, 4.0, 6.0, 6.0, 2.0),
        workspace_upper=(0.5, 1.0, 1.4), obstacle_rows=True, max_obstacle_rows=12)
    kinds = {n.key: n.kind for n in notes}
    assert kinds == {"position_margin": "stricter", "acceleration_limit": "weaker",
                     "workspace_upper": "weaker", "obstacle_rows": "stricter",
                     "max_obstacle_rows": "stricter", "solver": "other", "osqp_max_iter": "other"}
    text = next(n.text for n in notes if n.key == "acceleration_limit")
    assert "in entries [2] (ignored there) and stricter in entries [0, 5]" in text


def test_contradictory_or_non_finite_checkpoint_values(ours):
    with pytest.raises(DeployConfigError, match="workspace"):
        merge_safety(ours, dataclasses.replace(ours, workspace_lower=(0.9, -0.8, 0.0),
                                               workspace_upper=(1.0, 1.0, 1.4)))
    with pytest.raises(DeployConfigError, match="obstacle_activation_distance"):  # unvalidated
        merge_safety(ours, dataclasses.replace(ours, obstacle_safe_distance=0.5,
                                               obstacle_activation_distance=0.4))
    merged, notes = merge_safety(ours, dataclasses.replace(ours, position_margin=math.nan,
                                                           table_margin=math.inf))
    assert merged == ours and {n.key: n.kind for n in notes} == {"position_margin": "weaker",
                                                                 "table_margin": "weaker"}
    with pytest.raises(DeployConfigError, match="safety.enabled"):
        merge_safety(dataclasses.replace(ours, enabled=False), ours)


def _perturbed(ours, draw):
    changes = {}
    for field in dataclasses.fields(ours):
        value = getattr(ours, field.name)
        if not draw(st.booleans()):
            continue
        if isinstance(value, bool):
            changes[field.name] = draw(st.booleans())
        elif isinstance(value, int):
            changes[field.name] = draw(st.integers(0, 2 * value + 2))
        elif isinstance(value, float):
            changes[field.name] = value * draw(st.floats(0.5, 1.5))
        elif isinstance(value, tuple):
            changes[field.name] = tuple(v + draw(st.floats(-0.3, 0.3)) for v in value)
    safe = changes.get("obstacle_safe_distance", ours.obstacle_safe_distance)
    if changes.get("obstacle_activation_distance", math.inf) <= safe:
        changes.pop("obstacle_activation_distance")
    return dataclasses.replace(ours, **changes)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_merged_settings_are_as_strict_as_both(ours, data):
    theirs = _perturbed(ours, data.draw)
    try:
        merged, notes = merge_safety(ours, theirs)
    except DeployConfigError:
        return  # a contradiction is refused, never half-applied
    changed = {n.key for n in notes}
    for key, direction in safety_directions().items():
        m, a, b = (getattr(x, key) for x in (merged, ours, theirs))
        vec = (lambda v: v) if isinstance(a, tuple) else (lambda v: (v,))
        if direction == "higher":
            assert all(x == max(y, z) for x, y, z in zip(vec(m), vec(a), vec(b))), key
        elif direction == "lower":
            assert all(x == min(y, z) for x, y, z in zip(vec(m), vec(a), vec(b))), key
        elif direction == "on":
            assert m == (a or b), key
        else:
            assert m == a, key  # no stricter direction: deploy's value
        assert (key in changed) == (a != b), key


# --------------------------------------------------------------------------- the command line


def test_the_issue_checkpoint_runs_with_deploys_safety_and_says_so(tmp_path, capsys, caplog, ours):
    run = _run(tmp_path, WEAK)
    config, _ = load_controller_config(run)
    assert config.safety == ours  # the filter gets deploy's settings, untouched
    telemetry = tmp_path / "t.jsonl"
    with caplog.at_level(logging.INFO, logger="ahrm_stack.deploy"):
        code = deploy(["--backend", "sim", "--fast", "--duration", "1", "--checkpoint", str(run),
                       "--telemetry", str(telemetry)])
    assert code in (0, 1), capsys.readouterr()
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    for key in WEAK:
        assert any(f"safety.{key}: the checkpoint's" in m and "weaker" in m for m in warned), key
    events = [json.loads(line) for line in telemetry.read_text().splitlines()]
    assert {e["key"] for e in events if e.get("event") == "safety setting"} == set(WEAK)
    assert "summary" in events[-1]


@pytest.mark.parametrize("argv, key", [
    (["--rate", "1e-9"], "deploy.rate_hz"),  # 0 ticks: refused, not a silent empty run
    (["--rate", "0.4"], "connection_inactivity_timeout_ms"),  # 2.5 s between commands
    (["--duration", "0.001"], "no control period"),
    (["--rate", "nan"], "deploy.rate_hz"),
    (["--seed", "-1"], "deploy.seed"),
    (["safety.enabled=false"], "safety.enabled"),
    (["safety.position_margin=-1"], "safety.position_margin"),
])
def test_bad_settings_are_one_line_errors(argv, key, capsys, tmp_path):
    telemetry = tmp_path / "t.jsonl"
    assert deploy(["--backend", "sim", "--fast", "--telemetry", str(telemetry), *argv]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith(PROG)]
    assert len(lines) == 1 and key in lines[0] and "Traceback" not in err, err
    assert not telemetry.exists()  # nothing written before validation


def test_bad_paths_are_one_line_errors(capsys, tmp_path):
    (tmp_path / "dir").mkdir()
    cases = [(["--telemetry", str(tmp_path / "dir")], "deploy.telemetry"),
             (["--checkpoint", str(tmp_path / "missing")], "config.yaml"),
             (["--config", str(tmp_path / "missing.yaml")], "missing.yaml")]
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.yaml").write_text((TRAINED / "config.yaml").read_text())
    cases.append((["--checkpoint", str(empty)], "policy.pt"))
    broken = _run(tmp_path)
    (broken / "config.yaml").write_text("safety: [unclosed")
    cases.append((["--checkpoint", str(broken)], "config.yaml"))
    policy = TRAINED / "policy.pt"
    cases += [(["--policy-file", str(policy)], "--checkpoint"),  # whose config?
              (["--checkpoint", str(TRAINED), "--policy-file", str(tmp_path / "gone.pt")], "gone.pt")]
    for argv, key in cases:
        assert deploy(["--backend", "sim", "--fast", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and key in err and "Traceback" not in err, (argv, err)


class Payload:
    """Unpickling this would run ``touch MARKER``."""

    marker: Path

    def __reduce__(self):
        import os
        return (os.system, (f"touch {self.marker}",))


def test_a_malicious_pickle_is_refused_in_one_line(tmp_path, capsys):
    marker = tmp_path / "pwned"
    Payload.marker = marker
    evil = tmp_path / "evil.pt"
    torch.save({"actor": Payload(), "observation_dim": 1, "action_dim": 1}, evil)
    run = _run(tmp_path, policy=evil)
    telemetry = tmp_path / "t.jsonl"
    assert deploy(["--backend", "sim", "--fast", "--checkpoint", str(run),
                   "--telemetry", str(telemetry)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(PROG), err
    assert "refused to load" in err and "posix.system" in err and "policy.pt" in err
    assert evaluate([str(run), "--episodes", "1", "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused to load" in err, err
    assert not marker.exists() and not telemetry.exists() and not (tmp_path / "eval").exists()


# --------------------------------------------------------------------------- faults end to end


def test_a_nan_policy_stops_the_run_with_a_fault(tmp_path, capsys):
    saved = torch.load(TRAINED / "policy.pt", weights_only=True)
    saved["actor"] = {k: torch.full_like(v, math.nan) if v.is_floating_point() else v
                      for k, v in saved["actor"].items()}
    nan_policy = tmp_path / "nan.pt"
    torch.save(saved, nan_policy)
    run = _run(tmp_path, policy=nan_policy)
    telemetry = tmp_path / "t.jsonl"
    assert deploy(["--backend", "sim", "--fast", "--duration", "2", "--checkpoint", str(run),
                   "--telemetry", str(telemetry)]) == 3
    out, err = capsys.readouterr()
    assert "deploy summary" in out and "controller fault: non-finite request" in err
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    stop, summary = lines[-2], lines[-1]["summary"]
    assert stop["event"] == "stop" and "non-finite request" in stop["reason"]
    assert summary["fault"] == stop["reason"] and summary["ticks"] == 1


@pytest.mark.parametrize("where", ["world model", "perception at start-up"])
def test_a_start_up_fault_is_recorded(where, tmp_path, capsys, monkeypatch):
    import ahrm_stack.deploy as deploy_module
    from ahrm_stack.sim_arm import SimArm

    def crash(*args, **kwargs):
        raise RuntimeError("boom")

    if where == "world model":
        monkeypatch.setattr(deploy_module.WorldModel, "__init__", crash)
    else:
        monkeypatch.setattr(SimArm, "perception", crash)
    telemetry = tmp_path / "t.jsonl"
    assert deploy(["--backend", "sim", "--fast", "--telemetry", str(telemetry)]) == 3
    out, err = capsys.readouterr()
    assert "deploy summary" in out and "start-up fault: RuntimeError: boom" in err
    lines = [json.loads(line) for line in telemetry.read_text().splitlines()]
    assert lines[-2]["event"] == "stop" and "start-up fault" in lines[-2]["reason"]
    assert lines[-1]["summary"]["fault"] == lines[-2]["reason"]
