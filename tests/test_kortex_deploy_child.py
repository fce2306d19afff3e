"""``python -m ahrm_stack.deploy --backend kortex`` with ``kortex_api`` in its own process, as deployed
(ahrm_stack/hardware/kortex/child_link.py, ``kortex.python``): tests/test_kortex_deploy.py's run
once more, the tiny Gen3 policy (its module-scoped fixture, trained here once more) on the fake
``kortex_api`` in a child process (this interpreter as ``kortex.python``, the fake on the child's
``PYTHONPATH`` and its arm described by ``$FAKE_KORTEX_ARM``, as tests/test_kortex_check.py arranges
it; ``make_kortex_backend`` itself, not patched). The arm object lives in the child, so what the
arm received is read from this side: the fake's call log (a file the child appends each call to)
and the arm's velocity feedback in the telemetry (the fake reports the joint speeds it holds). The
loop runs on the arm's feedback, every speed the arm held is a tick's filtered command within the
arm's velocity limits, the run ends with ``Base.Stop`` after the last joint-speed command and then
``CloseSession``, the child is shut down, this process never imports ``kortex_api``, and the
telemetry and its MCAP twin are written."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest
import yaml

from fake_kortex_api.rig import HERE, PASSWORD, child_spec
from test_kortex_deploy import DURATION, _config, checked_run_record, gen3_policy  # noqa: F401 - the tiny Gen3 policy fixture
from ahrm_stack.deploy import main


@pytest.fixture
def child_gen3(tmp_path, monkeypatch):
    """(address, call log, robot, child links): a 7-DoF Gen3 (MODEL_ID_L53) at the policy's start,
    its velocity limits the Gen3 description's, built by the fake ``kortex_api`` in the child from
    ``$FAKE_KORTEX_ARM``; each :class:`ChildLink` the adapter makes is kept to be looked at."""
    import ahrm_stack.hardware.kortex.arm as kortex_arm
    from ahrm_stack.config import load_config
    from ahrm_stack.hardware.kortex.child_link import ChildLink
    from ahrm_stack.robot import describe, make_arm

    robot = describe("gen3", make_arm("gen3"))
    home = np.degrees(load_config(["task.robot=gen3"]).task.arm.home)
    log = tmp_path / "calls.jsonl"
    monkeypatch.setenv("FAKE_KORTEX_ARM", child_spec(robot, positions_deg=home, log=str(log),
                                                     product={"model": 1, "dof": 7}))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.setenv("KORTEX_USERNAME", "admin")
    monkeypatch.setenv("KORTEX_PASSWORD", PASSWORD)
    links: list[ChildLink] = []

    class KeptChildLink(ChildLink):
        def __init__(self, *args, **kwargs) -> None:
            # a loaded test machine (make test's workers) can keep the child from answering within
            # the production margin (250 ms past a call's timeout), which kills it by design; the
            # test is of the path, not of this machine's scheduling
            kwargs["margin_ms"] = max(int(kwargs.get("margin_ms", 0)), 5000)
            super().__init__(*args, **kwargs)
            links.append(self)

    monkeypatch.setattr(kortex_arm, "ChildLink", KeptChildLink)
    return "192.0.2.252", log, robot, links


def test_a_gen3_policy_deploys_with_kortex_api_in_a_child_process(gen3_policy, child_gen3, tmp_path,  # noqa: F811
                                                                  capsys):
    address, log, robot, links = child_gen3
    config = _config(tmp_path, address)
    data = yaml.safe_load(config.read_text())
    data["kortex"]["python"] = sys.executable  # kortex.python: the child's interpreter (this one)
    config.write_text(yaml.safe_dump(data))
    telemetry = tmp_path / "out" / "telemetry.jsonl"
    code = main(["--backend", "kortex", "--config", str(config), "--checkpoint", str(gen3_policy),
                 "--duration", str(DURATION), "--telemetry", str(telemetry)])
    captured = capsys.readouterr()
    assert code in (0, 1, 3) and "deploy summary" in captured.out, captured.out + captured.err
    assert PASSWORD not in captured.out + captured.err
    assert "kortex_api process" not in captured.out + captured.err  # the child held for the whole run

    # kortex_api ran in one child process under kortex.python, shut down at the end; never here
    assert len(links) == 1 and links[0].python == sys.executable, links
    assert links[0].hello.get("pid") not in (None, os.getpid()), links[0].hello
    assert links[0].pid is None and links[0].dead_reason == ""  # shut down, not died or killed
    assert not any(name == "kortex_api" or name.startswith("kortex_api.") for name in sys.modules)

    ticks = checked_run_record(telemetry, captured.out)

    # every filtered command is within the arm's velocity limits, and every speed the arm held (its
    # velocity feedback, which the fake reports exactly) is one of them (rad/s, rounded to 1e-6)
    limit = np.array(robot.velocity_limit)
    filtered = np.array([t["u"] for t in ticks])
    assert (np.abs(filtered) <= limit + 1e-6).all()
    held = np.array([t["dq"] for t in ticks])
    assert (np.abs(held) <= limit + 1e-6).all()
    moving = [dq for dq in held if np.any(np.abs(dq) > 1e-9)]
    assert moving, "the policy never moved the arm"
    for dq in moving:
        assert np.min(np.max(np.abs(filtered - dq), axis=1)) < 1e-5, dq

    # the child's call log: one joint-speed command per tick at most, each with kortex.rpc_timeout_ms;
    # the run ended with Base.Stop on the arm after the last of them, then the session closed
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    names = [c["name"] for c in calls if "name" in c]
    sends = [c for c in calls if c.get("name") == "SendJointSpeedsCommand"]
    assert len(moving) <= len(sends) <= len(ticks) + 1, (len(sends), len(ticks))
    assert all(c["timeout_ms"] == data["kortex"]["rpc_timeout_ms"] for c in sends)
    assert names[0] == "CreateSession" and names[-1] == "CloseSession", names[:3] + names[-3:]
    last_send = max(i for i, name in enumerate(names) if name == "SendJointSpeedsCommand")
    assert "Stop" in names[last_send:], names[-6:]
