"""The link to ``kortex_api``: the fake API through a child process (this interpreter, the fake on
its path), a lost link (Stop, then disconnect, the reason recorded), a dead or hung child, and the
child stopping the arm when the adapter's process dies. The fake arm in the child logs every call
it receives to a file (tests/fake_kortex_api/kortex_api/_fake_arm.py), which is what these tests
read: the calls the arm saw, not what the adapter meant to send."""

from __future__ import annotations

import json
import logging
import os
import platform
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from fake_kortex_api.rig import HERE, PASSWORD, make_child, make_for, options
from ahrm_stack.hardware.kortex import ChildLink, KortexNotInstalledError, LinkError
from ahrm_stack.hardware.protocol import ConnectionLostError

ROOT = Path(__file__).resolve().parent.parent
CONNECT_CALLS = 8  # CreateSession, RefreshFeedback, the four reads, SetServoingMode, Stop


@pytest.fixture(scope="module")
def robot():
    from ahrm_stack.robot import describe, make_arm

    return describe("jaco", make_arm("jaco"))


def _calls(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()]


def _speeds(value: float) -> np.ndarray:
    return np.array([value, 0.0, 0.0, 0.0, 0.0, 0.0])


def test_the_fake_api_works_through_the_child_process(robot, monkeypatch, tmp_path):
    log = tmp_path / "calls.jsonl"
    adapter = make_child(robot, monkeypatch, log=str(log),
                         opts=options(watchdog_timeout=60.0, watchdog_poll=1.0))
    adapter.connect()
    try:
        assert adapter.link.pid not in (None, os.getpid())
        assert adapter.link.hello["python"] == platform.python_version()  # kortex.python: null
        assert "kortex_api" not in sys.modules  # this process never imported it
        first = adapter.refresh_feedback()
        adapter.send_joint_speeds(_speeds(0.2))
        time.sleep(0.1)
        later = adapter.refresh_feedback()
        moved = later.position[0] - first.position[0]
        assert later.frame_id == first.frame_id + 1 and first.healthy and later.healthy
        assert 0.2 * 0.1 <= moved < 0.2 * 0.5  # integrated by the arm in the other process
        adapter.stop()
        assert adapter.arm_description == "MODEL_ID_L53 (Gen3), 6 DoF"
    finally:
        adapter.disconnect()
    seen = _calls(log)
    names = [c["name"] for c in seen]
    assert names[:3] == ["CreateSession", "RefreshFeedback", "GetProductConfiguration"]
    assert names[-2:] == ["Stop", "CloseSession"]
    assert all(c["timeout_ms"] is not None for c in seen)  # never the vendor's 10 s default


def test_a_lost_link_sends_stop_then_disconnects(robot, caplog):
    """A connection error on a command while the arm moves: the adapter sends Stop (with the short
    lost-link timeout), closes the session, records why, and raises ConnectionLostError. The fake
    arm keeps its speeds on a dropped call (as the real one would until its 2 s inactivity
    timeout): only the Stop brings it to rest."""
    adapter, arm = make_for(robot)
    adapter.connect()
    adapter.send_joint_speeds(_speeds(0.2))
    arm.drop_next("RefreshFeedback")
    with caplog.at_level(logging.INFO), pytest.raises(ConnectionLostError, match="RefreshFeedback"):
        adapter.refresh_feedback()
    after = arm.calls[-3:]
    assert [c.name for c in after] == ["RefreshFeedback", "Stop", "CloseSession"]
    assert after[1].timeout_ms == after[2].timeout_ms == options().lost_link_stop_timeout_ms
    np.testing.assert_array_equal(arm.command, 0.0)
    assert not adapter.is_connected and arm.sessions == 0
    assert "RefreshFeedback" in adapter.lost_reason and "connection reset" in adapter.lost_reason
    assert any("LINK LOST" in r.getMessage() for r in caplog.records)
    adapter.connect()  # a new session
    assert adapter.refresh_feedback().healthy and adapter.lost_reason == ""
    adapter.disconnect()


def test_a_lost_link_through_the_child_sends_stop_then_disconnects(robot, monkeypatch, tmp_path):
    log = tmp_path / "calls.jsonl"
    command = CONNECT_CALLS + 1
    adapter = make_child(robot, monkeypatch, log=str(log),
                         events=[[command + 1, "drop", "RefreshFeedback"]])
    adapter.connect()
    adapter.send_joint_speeds(_speeds(0.2))  # call number `command`
    with pytest.raises(ConnectionLostError):
        adapter.refresh_feedback()
    assert not adapter.is_connected and adapter.link.pid is None  # the child was ended
    seen = _calls(log)[command - 1:]
    assert [c["name"] for c in seen] == ["SendJointSpeedsCommand", "RefreshFeedback", "Stop",
                                         "CloseSession"]
    assert seen[2]["timeout_ms"] == options().lost_link_stop_timeout_ms


def test_ctrl_c_does_not_take_the_child_away(robot, monkeypatch):
    """SIGINT to the child (as a terminal's Ctrl-C would send to a process group) leaves it
    answering: the adapter's loop can still stop the arm through it."""
    adapter = make_child(robot, monkeypatch)
    adapter.connect()
    try:
        os.kill(adapter.link.pid, signal.SIGINT)
        time.sleep(0.1)
        assert adapter.refresh_feedback().healthy
        adapter.stop()
        assert os.getpgid(adapter.link.pid) != os.getpgid(0)  # not in the terminal's group
    finally:
        adapter.disconnect()


def test_a_dead_child_is_a_lost_link(robot, monkeypatch, caplog):
    adapter = make_child(robot, monkeypatch)
    adapter.connect()
    os.kill(adapter.link.pid, signal.SIGKILL)
    with caplog.at_level(logging.ERROR), pytest.raises(ConnectionLostError, match="exited"):
        adapter.refresh_feedback()
    assert not adapter.is_connected and "kortex_api process" in adapter.lost_reason
    texts = [r.getMessage() for r in caplog.records]
    assert any("only guard" in t and "2000 ms" in t for t in texts)  # no Stop could be sent
    adapter.disconnect()  # a no-op now


def test_a_hung_child_is_killed_within_the_calls_timeout_plus_the_margin(robot, monkeypatch):
    opts = options(process_margin_ms=100)
    adapter = make_child(robot, monkeypatch, opts=opts, events=[[CONNECT_CALLS + 1, "hang", None]])
    adapter.connect()
    pid = adapter.link.pid
    start = time.perf_counter()
    with pytest.raises(ConnectionLostError, match="did not answer feedback within 140 ms: killed"):
        adapter.refresh_feedback()
    elapsed = time.perf_counter() - start
    assert (opts.rpc_timeout_ms + opts.process_margin_ms) / 1e3 <= elapsed < 2.0
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # killed and reaped


def test_the_child_stops_the_arm_when_the_adapters_process_dies(robot, tmp_path):
    """The adapter's process (a fresh interpreter, which never imported kortex_api or protobuf)
    exits mid-motion without a word; the child reads the end of its input and sends Stop and
    CloseSession before it exits."""
    log = tmp_path / "calls.jsonl"
    script = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(ROOT / "tests")!r})
        import numpy as np
        from fake_kortex_api.rig import HERE, make_child, options
        from ahrm_stack.robot import describe, make_arm

        class Patch:
            def setenv(self, key, value):
                os.environ[key] = value

        adapter = make_child(describe("jaco", make_arm("jaco")), Patch(), log={str(log)!r},
                             opts=options(watchdog_timeout=60.0, watchdog_poll=1.0))
        adapter.connect()
        adapter.send_joint_speeds(np.array([0.2, 0, 0, 0, 0, 0]))
        loaded = sorted(m for m in sys.modules if m.startswith(("kortex_api", "google.protobuf")))
        print(loaded, flush=True)
        os._exit(0)
    """)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[]"  # that process never imported kortex_api or protobuf
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and [c["name"] for c in _calls(log)][-1] != "CloseSession":
        time.sleep(0.05)
    names = [c["name"] for c in _calls(log)]
    assert names[-3:] == ["SendJointSpeedsCommand", "Stop", "CloseSession"]


def test_without_kortex_api_the_child_says_how_to_install_it(robot, monkeypatch, tmp_path):
    link = ChildLink(None, start_timeout_ms=20000)  # this interpreter, no fake on its path
    with pytest.raises(LinkError) as error:
        link.call("feedback", timeout_ms=40)
    assert error.value.kind == "not_installed" and "kortex.python" in str(error.value)
    from ahrm_stack.hardware.kortex import Credentials, KortexArm

    adapter = KortexArm(robot, "192.0.2.3", Credentials("admin", PASSWORD), options())
    with pytest.raises(KortexNotInstalledError, match="kortex_api is not installed") as refused:
        adapter.connect()
    assert "\n" not in str(refused.value) and not adapter.is_connected


def test_a_missing_interpreter_is_a_one_line_error(robot):
    from ahrm_stack.hardware.kortex import Credentials, KortexArm

    adapter = KortexArm(robot, "192.0.2.3", Credentials("admin", PASSWORD),
                        options(python="/nonexistent/venv/bin/python"), child_path=[HERE])
    with pytest.raises(Exception) as error:
        adapter.connect()
    assert "kortex.python '/nonexistent/venv/bin/python'" in str(error.value)
    assert "\n" not in str(error.value) and not adapter.is_connected
