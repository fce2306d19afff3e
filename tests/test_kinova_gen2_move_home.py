"""Homing you can stop (issue 58, item 2): Kinova's ``MoveHome`` blocks until the arm is home, so
``--home`` runs it on a thread of its own and a stop ends it (ahrm_stack/hardware/kinova_gen2/moves.py).

Checked against Kinova's own binary: the vendored ``USBCommandLayerUbuntu.so``'s ``MoveHome``,
disassembled with binutils' ``objdump``, is the sequence the fake runs (the home packet, 40 ms,
``GetGlobalTrajectoryInfo`` every 100 ms while the FIFO holds a point, ``SetAngularControl``, 40 ms,
``SetCartesianControl``), and its packet calls take the library's semaphore (so other threads'
calls interleave). Then, on the fake whose ``MoveHome`` blocks as that binary does: the call
returns only with the arm home and leaves Cartesian control; during a supervised ``MoveHome`` the
positions are read at the poll rate; a Ctrl-C, a stage timeout or the e-stop mid-move stops the arm
(FIFO erased) within one control period of the event (the e-stop: of the status poll that sees it),
``MoveHome`` returns, and ``CloseAPI`` comes after it. Timed against the wall clock: realtime."""

from __future__ import annotations

import re
import shutil
import subprocess
import threading
import time

import numpy as np
import pytest

from ahrm_stack.deploy import load_deploy_settings
from ahrm_stack.hardware.kinova_gen2.home import INTERRUPTED, STOPPED
from ahrm_stack.hardware.kinova_gen2.loader import VENDOR_LIBRARY
from ahrm_stack.hardware.kinova_gen2.moves import RETURN_WITHIN
from ahrm_stack.config import load_config
from ahrm_stack.deploy.world import WorldModel
from test_kinova_gen2_home import FACTORY_HOME, HOME_SPEED, _ends_stopped, _homing

fake_module = pytest.importorskip("fake_kinova_sdk.fake")
SETTINGS = load_deploy_settings(realtime=True, telemetry="")
PERIOD = 1.0 / SETTINGS.rate_hz  # s: one control period
AWAY = FACTORY_HOME + np.array([-30.0, 20.0, 25.0, -40.0, 30.0, 45.0])  # 1.5 s from home at 30 deg/s


@pytest.fixture(scope="module")
def world():
    return WorldModel(load_config().task)


@pytest.fixture
def fake(library):
    sdk = fake_module.FakeSdk(library)
    sdk.reset(position_deg=FACTORY_HOME)
    sdk.set_home(FACTORY_HOME, HOME_SPEED)
    return sdk


def _disassembly() -> dict[str, list[str]]:
    """The vendored library's functions (demangled name -> instruction lines)."""
    text = subprocess.run(["objdump", "-d", "--no-show-raw-insn", "-C", str(VENDOR_LIBRARY)],
                          capture_output=True, text=True, check=True).stdout
    functions = {}
    for block in text.split("\n\n"):
        header = re.match(r"[0-9a-f]+ <(.+)>:$", block.strip().split("\n", 1)[0])
        if header:
            functions[header.group(1)] = block.strip().splitlines()[1:]
    return functions


@pytest.mark.skipif(shutil.which("objdump") is None or not VENDOR_LIBRARY.is_file(),
                    reason="binutils' objdump and the vendored Gen2 SDK are needed")
def test_the_vendored_move_home_blocks_as_the_fake_does():
    """The binary's MoveHome: calls and sleeps in this order, the poll looping while the first
    field of TrajectoryFIFO (TrajectoryCount) is not 0; its USB packets pass Kinova's semaphore."""
    functions = _disassembly()
    lines = functions["MoveHome"]
    steps = []
    for line in lines:
        call = re.search(r"call\s+\w+ <([^@(>]+)", line)
        if call and not call.group(1).startswith("std::"):
            steps.append(call.group(1))
        sleep = re.search(r"mov\s+\$0x([0-9a-f]+),%edi", line)
        if sleep:
            steps.append(f"usleep({int(sleep.group(1), 16)})")
    steps = [s for s in steps if s != "usleep"]
    assert steps[:9] == ["PrepareSetPacket", "SendSetCommand", "usleep(40000)", "GetGlobalTrajectoryInfo",
                         "GetGlobalTrajectoryInfo", "usleep(100000)", "SetAngularControl",
                         "usleep(40000)", "SetCartesianControl"], steps
    loop = "\n".join(lines)
    assert re.search(r"test\s+%eax,%eax\n.*jne", loop)  # while (info.TrajectoryCount != 0)
    for packet_call in ("SendSetCommand(std::vector<Packet, std::allocator<Packet> >)",
                        "SendGetCommand(Packet&, std::vector<unsigned char, std::allocator<unsigned char> >&)"):
        body = "\n".join(functions[packet_call])
        assert "sem_wait" in body and "sem_post" in body, packet_call
    source = (fake_module.SOURCE).read_text()
    home = source.split("int MoveHome(void) {", 1)[1].split("\n}\n", 1)[0]
    assert [m for m in re.findall(r"(home_packet|GetGlobalTrajectoryInfo|sleep_s\([\d.]+\)|"
                                  r"SetAngularControl|SetCartesianControl)", home)] == [
        "home_packet", "sleep_s(0.040)", "GetGlobalTrajectoryInfo", "GetGlobalTrajectoryInfo",
        "sleep_s(0.100)", "SetAngularControl", "sleep_s(0.040)", "SetCartesianControl"]


def test_the_fake_move_home_returns_only_at_home_in_cartesian_control(fake):
    lib = fake.lib
    fake.set_position(AWAY)
    assert lib.InitAPI() == 1
    lib.StartControlAPI(), lib.StopControlAPI(), lib.StartControlAPI(), lib.SetAngularControl()
    began = time.perf_counter()
    assert lib.MoveHome() == 1
    took = time.perf_counter() - began
    need = np.max(np.abs(AWAY - FACTORY_HOME)) / HOME_SPEED
    assert need <= took <= need + 1.0, (need, took)  # its polls and sleeps on a loaded machine
    q, dq = fake.state()
    np.testing.assert_allclose(q, FACTORY_HOME, atol=1e-3)
    assert not fake.angular  # MoveHome leaves Cartesian control
    polls = fake.calls(function="GetGlobalTrajectoryInfo")
    gaps = np.diff([c.start for c in polls])
    assert len(polls) >= need / 0.1 and np.all(gaps[1:] >= 0.095), gaps
    lib.CloseAPI()


def test_positions_are_read_while_move_home_runs(fake, library, world):
    fake.set_position(AWAY)
    homing, arm, lines, asked = _homing(library, world, "home")
    outcome = homing.run()
    calls = fake.calls()
    packet = next(c for c in calls if c.function == "MoveHome")
    cartesian = next(c for c in calls if c.function == "SetCartesianControl")
    reads = [c for c in calls if c.function == "GetAngularPosition" and packet.t < c.t < cartesian.start]
    assert cartesian.t - packet.t > 1.0
    assert len(reads) >= 0.8 * (cartesian.t - packet.t) * homing.home.poll_rate_hz, len(reads)
    after = [c.function for c in calls if c.start > cartesian.t]
    assert after.index("SetAngularControl") < after.index("SendAdvanceTrajectory")  # angular again
    assert outcome.status == 0, outcome


def _stop_after(calls, event: float):
    erase = [c for c in calls if c.function == "EraseAllTrajectories" and c.start >= event]
    assert erase, "the FIFO was never erased"
    return erase[0].t - event


def _move_home_ended_before_close(fake):
    calls = fake.calls()
    cartesian = [c.t for c in calls if c.function == "SetCartesianControl"]
    close = [c.start for c in calls if c.function == "CloseAPI"]
    assert cartesian and close and cartesian[-1] < close[-1]  # MoveHome returned, then CloseAPI


def test_ctrl_c_mid_move_home_stops_the_arm_within_a_period(fake, library, world):
    fake.set_position(AWAY)
    raised: list[float] = []

    def sleep(seconds):
        if fake.calls(function="MoveHome") and len(raised) == 0 and \
                time.perf_counter() - fake.calls(function="MoveHome")[0].t > 0.5:
            raised.append(time.perf_counter())
            raise KeyboardInterrupt
        threading.Event().wait(seconds)

    homing, arm, lines, asked = _homing(library, world, "home", sleep=sleep)
    outcome = homing.run()
    assert outcome.status == INTERRUPTED and outcome.moved, outcome
    assert _stop_after(fake.calls(), raised[0]) <= PERIOD
    q, _ = fake.state()
    assert np.max(np.abs(q - FACTORY_HOME)) > 5.0  # stopped short of the factory home
    _move_home_ended_before_close(fake)
    _ends_stopped(fake)


def test_a_timeout_mid_move_home_stops_the_arm_within_a_period(fake, library, world):
    fake.set_position(AWAY)
    timeout = 0.6
    homing, arm, lines, asked = _homing(library, world, "home", timeout=timeout)
    outcome = homing.run()
    assert outcome.status == STOPPED and f"not done after {timeout:g} s" in outcome.reason, outcome
    packet = fake.calls(function="MoveHome")[0]
    # the stage's clock starts after the packet; the deadline is seen at the next poll
    late = _stop_after(fake.calls(), packet.t + timeout)
    assert late <= 1.0 / homing.home.poll_rate_hz + PERIOD, late
    q, _ = fake.state()
    assert np.max(np.abs(q - FACTORY_HOME)) > 5.0
    _move_home_ended_before_close(fake)
    _ends_stopped(fake)


def test_the_e_stop_mid_move_home_ends_the_homing(fake, library, world):
    """The e-stop cuts the actuators' power (the fake's arm stops at once); the status poll sees it
    within one status period, the FIFO (MoveHome's home move, still queued) is erased within a
    control period of that, MoveHome returns, and the arm does not move when the e-stop is released."""
    fake.set_position(AWAY)
    pressed: list[float] = []

    def press_later(prompt):
        def press():
            pressed.append(time.perf_counter())
            fake.set_estop(True)
        threading.Timer(0.5, press).start()
        return "home"

    homing, arm, lines, asked = _homing(library, world, "home")
    homing.ask = press_later
    outcome = homing.run()
    assert outcome.status == STOPPED and outcome.moved, outcome
    status_period = 1.0 / SETTINGS.kinova_gen2.status_rate_hz
    assert _stop_after(fake.calls(), pressed[0]) <= status_period + PERIOD
    _move_home_ended_before_close(fake)
    q_stopped, _ = fake.state()
    fake.set_estop(False)
    threading.Event().wait(0.2)
    q, dq = fake.state()
    np.testing.assert_allclose(q, q_stopped, atol=1e-9)
    assert np.max(np.abs(q - FACTORY_HOME)) > 5.0 and fake.fifo_count() == 0


def test_move_home_not_returning_skips_close_api(fake, library, world, monkeypatch):
    """Were MoveHome still inside the SDK after the FIFO was erased (a binary that polls a lost
    link forever), disconnecting stops the arm and skips CloseAPI rather than close the library
    under it (the thread is a daemon)."""
    from ahrm_stack.hardware.kinova_gen2 import moves

    fake.set_position(AWAY)
    homing, arm, lines, asked = _homing(library, world, "home")
    arm.move_home()
    stuck = threading.Event()
    monkeypatch.setattr(arm._move_home, "join", lambda timeout=RETURN_WITHIN: stuck.is_set())
    monkeypatch.setattr(type(arm._move_home), "running", property(lambda self: not stuck.is_set()))
    with pytest.raises(moves.HardwareError, match="did not return"):
        arm.end_move_home(timeout=0.01)
    arm.disconnect()
    assert "CloseAPI" not in [c.function for c in fake.calls()]
    assert fake.fifo_count() == 0 and not fake.control_on
    threading.Event().wait(RETURN_WITHIN)  # the real MoveHome returns (its FIFO is empty)
    fake.lib.CloseAPI()
