"""``python -m ahrm_stack.deploy --backend kortex``: a tiny Gen3 policy (``task.robot=gen3``, trained
here for one batch) runs the deploy loop on the Kortex adapter over the fake ``kortex_api`` (in this
process, so that the test reads the fake arm's call log and every speed it received), its
perception the static scene of ``kortex.scene`` (configs/scenes/default.yaml), as the Gen2 backend's
run does. The loop ticks on the wall clock, every command the arm received is one the safety
filter passed (within the arm's velocity limits, equal to the telemetry's filtered ``u``), the run
ends with ``Base.Stop`` and a recorded stop reason, and the telemetry and its MCAP twin are
written. The committed JACO policy, and a Gen3 policy without a scene, are refused in one line
before anything is contacted or written."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from fake_kortex_api.rig import PASSWORD, fake_api
from held_torques import held_torques
from ahrm_stack.deploy import DEPLOY_CONFIG, main

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "scenes" / "default.yaml"
JACO_POLICY = ROOT / "docs" / "policies" / "ahrm-default-seed0"
DURATION = 3.0  # s of wall-clock run


def checked_run_record(telemetry: Path, output: str) -> list[dict]:
    """The run's tick records, after checking what every Kortex run leaves: at least 10 ticks on
    the arm's feedback, a stop reason in the summary and the printed output, a recorded stop event,
    and a non-empty MCAP twin beside the telemetry."""
    records = [json.loads(line) for line in telemetry.read_text().splitlines()]
    ticks = [r for r in records if "u" in r and "u_nom" in r]
    summary = records[-1]["summary"]
    assert len(ticks) >= 10 and summary["ticks"] >= 10, summary  # the loop ran on the arm's feedback
    assert summary["stop_reason"] and summary["stop_reason"] in output
    assert any(r.get("event") == "stop" and r.get("reason") for r in records)  # a recorded stop
    assert (telemetry.parent / "telemetry.mcap").stat().st_size > 0  # the run's MCAP twin
    return ticks


@pytest.fixture(scope="module")
def gen3_policy(tmp_path_factory) -> Path:
    """A Gen3 policy: one batch of 128 frames, a 16 x 16 network, no demonstrations (only a
    checkpoint is needed, not a good policy)."""
    from ahrm_stack.train import main as train

    run = tmp_path_factory.mktemp("gen3") / "run"
    assert train(["task.robot=gen3", "task.arm.start=home", "ppo.hidden_sizes=[16,16]",
                  "ppo.frames_per_batch=128", "task.episode.duration=2", "train.episodes=2",
                  "train.eval_episodes=0", "train.checkpoint_every=1", "train.warm_start=none",
                  "ppo.bc_coeff=0", "--run-dir", str(run), "--no-progress"]) == 0
    assert (run / "policy.pt").is_file()
    return run


@pytest.fixture
def fake_gen3(monkeypatch):
    """(address, fake arm): a 7-DoF Gen3 (MODEL_ID_L53) at the policy's start, registered in this
    process, its velocity limits the Gen3 description's (commands beyond them are counted); the
    deploy command's adapter is built on the fake ``kortex_api`` in this process."""
    import ahrm_stack.hardware.kortex as kortex
    from ahrm_stack.config import load_config
    from ahrm_stack.robot import describe, make_arm

    robot = describe("gen3", make_arm("gen3"))
    home = np.degrees(load_config(["task.robot=gen3"]).task.arm.home)
    FakeArm = fake_api()["_fake_arm"].FakeArm
    address, port = "192.0.2.251", 10000
    arm = FakeArm.register(address, port, FakeArm(home, ~robot.limited, product={"model": 1, "dof": 7},
                                                  velocity_limit_deg_s=np.degrees(robot.velocity_limit)))
    real = kortex.make_kortex_backend
    monkeypatch.setattr(kortex, "make_kortex_backend",
                        lambda settings, robot, **kwargs: real(settings, robot, api=fake_api(), **kwargs))
    monkeypatch.setenv("KORTEX_USERNAME", "admin")
    monkeypatch.setenv("KORTEX_PASSWORD", PASSWORD)
    yield address, arm, robot
    FakeArm.unregister(address, port)


def _config(tmp_path, address: str, scene: Path | None = SCENE) -> Path:
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    data["kortex"].update(address=address, scene=None if scene is None else str(scene))
    # a loaded 2-core machine misses deadlines: the run is not stopped for it here (the Gen2 test's)
    data["watchdog"].update(max_deadline_misses=1000, max_feedback_age=10.0)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_gen3_policy_deploys_through_the_kortex_backend(gen3_policy, fake_gen3, tmp_path, capsys):
    address, arm, robot = fake_gen3
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    code = main(["--backend", "kortex", "--config", str(_config(tmp_path, address)),
                 "--checkpoint", str(gen3_policy), "--duration", str(DURATION),
                 "--telemetry", str(telemetry)])
    captured = capsys.readouterr()
    assert code in (0, 1, 3) and "deploy summary" in captured.out, captured.out + captured.err
    assert PASSWORD not in captured.out + captured.err

    ticks = checked_run_record(telemetry, captured.out)

    # every command the arm received passed the safety filter: within the arm's velocity limits,
    # and each one a tick's filtered command u (rad/s in the telemetry, deg/s on the arm)
    limit = np.degrees(robot.velocity_limit)
    received = [speeds for _, speeds in arm.speed_log]
    assert arm.violations == 0 and all((np.abs(s) <= limit + 1e-9).all() for s in received)
    filtered = np.degrees(np.array([t["u"] for t in ticks]))
    assert all((np.abs(f) <= limit + 1e-9).all() for f in filtered)
    moving = [s for s in received if np.any(s)]
    assert moving, "the policy never moved the arm"
    for speeds in moving:
        assert np.min(np.max(np.abs(filtered - speeds), axis=1)) < 1e-4, speeds  # the telemetry rounds

    # the run ended with Base.Stop on the arm, after its last joint-speed command, then the session closed
    names = [call.name for call in arm.calls]
    assert "SendJointSpeedsCommand" in names and names[-1] == "CloseSession"
    last_send = max(i for i, name in enumerate(names) if name == "SendJointSpeedsCommand")
    assert "Stop" in names[last_send:], names[-6:]
    np.testing.assert_array_equal(arm.speeds, 0.0)


def _refused(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and err.startswith("python -m ahrm_stack.deploy: error: --backend kortex:"), err
    assert "Traceback" not in captured.err and PASSWORD not in captured.err
    return err


def test_the_jaco_policy_is_refused_naming_the_missing_kortex_model(fake_gen3, tmp_path, capsys):
    address, arm, _ = fake_gen3
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    err = _refused(["--backend", "kortex", "--config", str(_config(tmp_path, address)),
                    "--checkpoint", str(JACO_POLICY), "--telemetry", str(telemetry)], capsys)
    assert "the policy's robot 'jaco' has no deploy.kortex.models entry" in err
    assert not telemetry.parent.exists() and arm.calls == [] and arm.sessions == 0


def test_a_gen3_policy_without_a_scene_is_refused_in_one_line(gen3_policy, fake_gen3, tmp_path, capsys):
    address, arm, _ = fake_gen3
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    err = _refused(["--backend", "kortex", "--config", str(_config(tmp_path, address, scene=None)),
                    "--checkpoint", str(gen3_policy), "--telemetry", str(telemetry)], capsys)
    assert "deploy.kortex.scene is not set" in err
    assert not telemetry.parent.exists() and arm.calls == []


@pytest.mark.parametrize("push", [False, True])
def test_an_injected_contact_stops_a_dry_run_on_the_fake_gen3(gen3_policy, fake_gen3, tmp_path, capsys, push):
    """The contact stop on the Kortex backend (issue 58 item 4), with ``kortex.contact_torques``: a
    dry run holds the Gen3 at its start, its actuators reporting what a held Gen3's would (MuJoCo's
    gravity, plus the fake's 0.02 N·m noise); after 10 frames a contact adds 90 N·m on joint 1 (its
    threshold 60): the run e-stops naming the joint (the estimate reads 22.5, 56.3, 73.1, 81.6 N·m:
    the fourth reading with it, 150-200 ms at 20 Hz). Without the contact it runs its duration."""
    from ahrm_stack.config import load_config

    address, arm, robot = fake_gen3
    task = load_config(["task.robot=gen3"]).task
    held = held_torques(task, arm.read_positions())  # the Gen3's Kortex angles are the model's
    arm.set_torques(held)
    path = _config(tmp_path, address)
    data = yaml.safe_load(path.read_text())
    data["kortex"]["contact_torques"] = True
    path.write_text(yaml.safe_dump(data))
    reads: list[int] = []  # RefreshFeedback calls made when the contact began
    done = threading.Event()

    def touch() -> None:
        while sum(call.name == "RefreshFeedback" for call in list(arm.calls)) < 10:
            if done.wait(0.01):
                return
        arm.set_torques(held + np.array([0.0, 90.0, 0, 0, 0, 0, 0]))
        reads.append(len([c for c in list(arm.calls) if c.name == "RefreshFeedback"]))

    toucher = threading.Thread(target=touch, daemon=True)
    if push:
        toucher.start()
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    try:
        code = main(["--backend", "kortex", "--config", str(path), "--checkpoint", str(gen3_policy),
                     "--duration", str(DURATION), "--dry-run", "--telemetry", str(telemetry)])
    finally:
        done.set()
    out = capsys.readouterr().out
    assert code == 1 and "deploy summary" in out, out
    if not push:
        assert "contact" not in out and f"duration of {DURATION:g} s reached" in out, out
        return
    assert "contact: joint 1 external torque" in out and "2 consecutive readings" in out, out
    names = [call.name for call in arm.calls]
    stopped = names.index("ApplyEmergencyStop") if "ApplyEmergencyStop" in names else names.index("Stop")
    seen = names[:stopped].count("RefreshFeedback") - reads[0]  # frames read with the contact
    assert seen == 4, seen
