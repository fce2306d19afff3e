"""Injected faults stop the arm within one control period, with a clear log line and no limit
violation; a long run of random faults and random (often absurd) commands ends with none."""

from __future__ import annotations

import io
import json
import logging

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.deploy import DeployLoop, ScriptedController, WorldModel, load_deploy_settings
from ahrm_stack.hardware.protocol import ArmState, CommandRefusedError, FastClock, Fault
from ahrm_stack.sim_arm import InjectedFault, SimArm

RATE_HZ = 20.0


def _rig(controller_factory=None, seed: int = 0):
    config = load_config()
    settings = load_deploy_settings(rate_hz=RATE_HZ, realtime=False, telemetry="")
    arm = SimArm(config.task, seed=seed, clock=FastClock(),
                 command_delay=settings.sim.command_delay)
    world = WorldModel(config.task, seed=seed)
    controller = (controller_factory or (lambda w: ScriptedController(w, config)))(world)
    arm.connect()
    telemetry = io.StringIO()
    loop = DeployLoop(arm, world, controller, config.safety, settings, telemetry)
    loop.start()
    return arm, loop, telemetry


EXPECTED = {
    InjectedFault.STALE_FEEDBACK: ("stale feedback", False),
    InjectedFault.DROPPED_FEEDBACK: ("feedback dropped", False),
    InjectedFault.DELAYED_COMMAND: ("missed deadline", False),
    InjectedFault.NAN_READING: ("non-finite feedback", True),
    InjectedFault.FAULT_FLAG: ("arm fault", True),
    InjectedFault.LOST_CONNECTION: ("connection lost", False),
}


class _KortexRig:
    """The Kortex backend on the fake arm, shaped like the sim rig: attribute access goes to the
    adapter; ``inject``, ``command`` (rad/s the arm holds) and ``violations`` to the fake arm."""

    def __init__(self) -> None:
        from fake_kortex_api.rig import DeployRig

        self.rig = DeployRig(load_config())

    def __getattr__(self, name):
        return getattr(self.rig.adapter, name)

    def inject(self, fault: InjectedFault) -> None:
        self.rig.inject(fault)

    @property
    def command(self) -> np.ndarray:
        return self.rig.command

    @property
    def violations(self) -> int:
        return self.rig.violations


@pytest.fixture(scope="module", params=["sim", "kortex"])
def rig(request):
    """sim: the simulated arm on a fast clock; kortex: KortexArm over the fake kortex_api, realtime
    at 20 Hz on the wall clock, each injected fault mapped onto the fake arm (a repeated frame, an
    RPC past its timeout, a late command, NaN, an actuator fault, a dropped link)."""
    if request.param == "sim":
        yield _rig()
        return
    kortex = _KortexRig()
    yield kortex, kortex.rig.loop, kortex.rig.telemetry
    kortex.disconnect()


@pytest.mark.parametrize("fault", list(InjectedFault), ids=lambda f: f.value)
def test_each_fault_stops_the_arm_within_one_period(rig, fault, caplog):
    arm, loop, telemetry = rig
    if not arm.is_connected:
        arm.connect()
    if arm.refresh_feedback().faults != Fault.NONE:
        arm.clear_faults()
    loop.resume()
    for _ in range(10):  # moving, healthy
        assert loop.tick(), loop.stop_reason
    assert np.abs(arm.command).max() > 0
    fault_time = loop.next_tick_time
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="ahrm_stack.deploy"):
        arm.inject(fault)
        assert not loop.tick()
    reason, emergency = EXPECTED[fault]
    assert loop.halted and reason in loop.stop_reason
    assert loop.stopped_at - fault_time <= loop.period
    np.testing.assert_array_equal(arm.command, 0.0)  # the arm holds zero velocity
    assert arm.violations == 0
    messages = [r.getMessage() for r in caplog.records]
    assert any(reason in m and ("EMERGENCY STOP" if emergency else "STOP") in m for m in messages), messages
    event = json.loads(telemetry.getvalue().strip().splitlines()[-1])
    assert reason in event["reason"]
    if fault == InjectedFault.LOST_CONNECTION:
        assert not arm.is_connected
    elif emergency:
        frame = arm.refresh_feedback()
        assert frame.arm_state == ArmState.IN_FAULT


class RandomCommands:
    """Nominal commands drawn at random: mostly up to 1.5x the velocity limits, sometimes NaN,
    inf or absurdly large."""

    stage = "random"

    def __init__(self, world: WorldModel, rng: np.random.Generator) -> None:
        self.limit = world.robot.velocity_limit
        self.rng = rng

    def reset(self) -> None:
        pass

    def __call__(self) -> np.ndarray:
        u = self.rng.uniform(-1.5, 1.5, self.limit.size) * self.limit
        roll = self.rng.random()
        if roll < 0.02:
            u[self.rng.integers(u.size)] = np.nan
        elif roll < 0.04:
            u[self.rng.integers(u.size)] = np.inf * self.rng.choice([-1, 1])
        elif roll < 0.06:
            u *= 1e6
        return u


def test_random_faults_and_commands_never_violate_a_limit():
    rng = np.random.default_rng(7)
    arm, loop, _ = _rig(lambda world: RandomCommands(world, rng))
    faults = list(InjectedFault)
    halts, reasons, episodes, refused = 0, set(), 0, 0
    limit = arm.velocity_limit
    for step in range(10_000):
        if rng.random() < 0.02:
            arm.inject(faults[rng.integers(len(faults))])
        if rng.random() < 0.01 and arm.is_connected:  # a command that skipped the filter
            raw = rng.uniform(-1.2, 1.2, limit.size) * limit
            if np.abs(raw).max() > 0 and (np.abs(raw) > limit).any():
                with pytest.raises(CommandRefusedError):
                    arm.send_joint_speeds(raw)
                refused += 1
                assert arm.refresh_feedback().arm_state == ArmState.IN_FAULT
                arm.clear_faults()
                loop.resume()
        if loop.tick():
            continue
        halts += 1
        reasons.add(loop.stop_reason.split(":")[0])
        np.testing.assert_array_equal(arm.command, 0.0)
        if not arm.is_connected:
            arm.connect()
        if loop.success:  # random motion pushed the cube off: a new layout
            episodes += 1
            arm.reset_scene(seed=episodes)
            loop.success = False
        if arm.refresh_feedback().faults != Fault.NONE:
            arm.clear_faults()
        loop.resume()
    assert arm.violations == 0
    assert refused > 0
    assert halts >= 100  # the faults did fire, and every one was caught
    assert {"watchdog", "connection lost"} <= reasons
