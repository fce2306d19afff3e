"""The deploy loop's velocity e-stop against a real JACO2's noisy velocity feedback (issue 41 item
4, issue 40's dose rows): a reading over (1 + velocity_tolerance) x the limit e-stops only when
``velocity_alarm_ticks`` consecutive readings are over, so white noise of 5 deg/s on a joint
moving at the filter's 95 % of its limit does not fire it, and a runaway (a joint that keeps its
over-speed) still does, within that many ticks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.deploy import DeployLoop, ScriptedController, WorldModel, load_deploy_settings
from ahrm_stack.deploy.loop import _Halt
from ahrm_stack.hardware.protocol import ArmState, Fault, FastClock, Feedback
from ahrm_stack.sim_arm import SimArm

CONFIG = load_config(["task.realism=ideal"])


def _loop():
    settings = load_deploy_settings(realtime=False, telemetry="")
    # the velocity alarm alone: these readings (zero torque, velocities that jump with no motion of
    # the joints) are no physical motion, and the contact stop would read them as a load
    settings = dataclasses.replace(settings, contact=dataclasses.replace(settings.contact, enabled=False))
    arm = SimArm(CONFIG.task, seed=0, clock=FastClock())
    arm.connect()
    world = WorldModel(CONFIG.task)
    loop = DeployLoop(arm, world, ScriptedController(world, CONFIG), CONFIG.safety, settings)
    loop.start()
    return loop, arm, settings


def _reading(loop, arm, velocity: np.ndarray, frame: int) -> Feedback:
    position = arm.task.arm_state(arm.physics)[0]
    return Feedback(timestamp=loop.clock.now(), frame_id=frame, position=position, velocity=velocity,
                    torque=np.zeros_like(velocity), arm_state=ArmState.SERVOING_READY, faults=Fault.NONE)


def test_noise_at_the_limit_does_not_fire_and_a_runaway_does():
    loop, arm, settings = _loop()
    limit = arm.task.robot.velocity_limit
    ticks = settings.watchdog.velocity_alarm_ticks
    assert ticks >= 2
    rng = np.random.default_rng(0)
    frame = 10
    noise = math.radians(5.0)
    for _ in range(3000):  # 150 s at 20 Hz, every joint at 95 % of its limit, 5 deg/s of noise
        frame += 1
        loop._check_feedback(_reading(loop, arm, 0.95 * limit + rng.normal(0, noise, limit.shape), frame))
    assert not loop.halted
    # a single reading far over the alarm, then normal ones: not a runaway
    frame += 1
    loop._check_feedback(_reading(loop, arm, 2.0 * limit, frame))
    frame += 1
    loop._check_feedback(_reading(loop, arm, 0.5 * limit, frame))
    assert not loop.halted
    # a runaway: joint 2 holds 1.4 x its limit; the e-stop fires on the ticks-th reading
    speed = 0.5 * limit
    speed[2] = 1.4 * limit[2]
    for k in range(1, ticks + 1):
        frame += 1
        if k < ticks:
            loop._check_feedback(_reading(loop, arm, speed, frame))
            assert not loop.halted
        else:
            with pytest.raises(_Halt, match=f"joint 2 moving at .* on {ticks} consecutive readings"):
                loop._check_feedback(_reading(loop, arm, speed, frame))
    assert loop.emergency_stops == 1


def test_one_tick_alarm_fires_on_the_first_reading():
    loop, arm, settings = _loop()
    loop.settings = dataclasses.replace(settings, watchdog=dataclasses.replace(settings.watchdog,
                                                                              velocity_alarm_ticks=1))
    with pytest.raises(_Halt, match="joint 0 moving"):
        loop._check_feedback(_reading(loop, arm, 1.3 * arm.task.robot.velocity_limit, 99))


def test_alarm_ticks_must_be_positive():
    from ahrm_stack.deploy import DeployConfigError

    with pytest.raises(DeployConfigError, match="deploy.watchdog.velocity_alarm_ticks must be >= 1"):
        load_deploy_settings(watchdog={**load_deploy_settings().watchdog.to_dict(), "velocity_alarm_ticks": 0})
