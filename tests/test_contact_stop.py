"""The deploy loop's contact stop (ahrm_stack/deploy/contact.py; issue 58 item 4).

The estimator is checked against MuJoCo's own dynamics, not against our beliefs: the simulated arm
(the sim backend, its velocity servos holding it) is loaded by a known generalised force
(``qfrc_applied``, which MuJoCo integrates like any external load), and the estimate from the
feedback the deploy loop reads (20 Hz positions, velocities, actuator torques) must find it. The
loop is checked with a physical push on the tool mid-run (100 N sideways): it e-stops on contact,
and the same run without the push does not.
"""

from __future__ import annotations

import dataclasses
import logging

import mujoco
import numpy as np
import pytest

from ahrm_stack.config import load_config
from ahrm_stack.deploy.contact import ContactStop, ExternalTorqueEstimator, arm_dofs
from ahrm_stack.deploy.session import DeploySession
from ahrm_stack.deploy.settings import load_deploy_settings
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.hardware.wrapper import ArmWrapper
from ahrm_stack.sim_arm import SimArm

PERIOD = 0.05  # s, the deploy loop's period at 20 Hz


def _held_arm() -> tuple[SimArm, np.ndarray]:
    """The sim backend at the task's start, connected and commanded to hold still; its arm dofs."""
    config = load_config()
    sim = SimArm(config.task, seed=0, clock=FastClock())
    sim.connect()
    model = sim.physics.model.ptr
    return sim, arm_dofs(model, sim._arm_qpos)


@pytest.mark.parametrize("joint, torque", [(1, 15.0), (2, -10.0), (0, 8.0)])
def test_the_estimate_finds_a_known_external_torque(joint, torque):
    sim, dofs = _held_arm()
    model, data = sim.physics.model.ptr, sim.physics.data.ptr
    estimator = ExternalTorqueEstimator(model, dofs, sim._arm_qpos, gain=10.0, period=PERIOD)
    sim.send_joint_speeds(np.zeros(sim.num_joints))
    for _ in range(20):  # settle, unloaded: the estimate is the model's error alone
        frame = sim.refresh_feedback()
        estimator.update(frame.position, frame.velocity, frame.torque)
        sim.clock.sleep(PERIOD)
    unloaded = estimator.estimate.copy()
    data.qfrc_applied[dofs[joint]] = torque  # the load, from now on
    for _ in range(40):  # 2 s: the servo takes the load, the low-pass settles (K = 10/s)
        frame = sim.refresh_feedback()
        estimate = estimator.update(frame.position, frame.velocity, frame.torque)
        sim.clock.sleep(PERIOD)
    # the model is exact but for the joints' dry friction (a constraint force, no model term:
    # MuJoCo's frictionloss, 1-2 N·m here), which the estimate sees as external, as on an arm
    friction = model.dof_frictionloss[dofs] + 0.1
    assert (np.abs(unloaded) <= friction).all(), unloaded
    assert estimate[joint] == pytest.approx(torque, abs=friction[joint] + 0.05 * abs(torque))
    others = np.delete(estimate - unloaded, joint)
    assert (np.abs(others) <= np.delete(friction, joint) + 0.1 * abs(torque)).all(), estimate
    sim.disconnect()


def test_contact_stop_needs_consecutive_readings_and_names_the_joint():
    sim, dofs = _held_arm()
    stop = ContactStop.on_model(sim.physics.model.ptr, sim._arm_qpos, [5.0] * 6, readings=3, gain=20.0,
                                period=PERIOD)
    frame = sim.refresh_feedback()
    assert stop.observe(frame.position, frame.velocity, frame.torque) is None  # the first reading: zeros
    # an external torque of 30 N·m on joint 2 seen by the estimate: a measured torque 30 below the model's
    reasons = [stop.observe(frame.position, frame.velocity, frame.torque - np.eye(6)[2] * 30.0) for _ in range(4)]
    assert reasons[0] is None and reasons[1] is None  # over the threshold on 1, then 2 readings
    assert reasons[2] is not None and reasons[2].startswith("contact: joint 2 external torque")
    assert "on 3 consecutive readings" in reasons[2]
    assert stop.peak[2] > 5.0
    stop.reset()
    assert stop.peak.max() == 0.0 and stop.observe(frame.position, frame.velocity, frame.torque) is None
    with pytest.raises(ValueError, match="5 contact thresholds for an arm of 6 joints"):
        ContactStop(stop.estimator, [1.0] * 5, readings=1)
    with pytest.raises(ValueError, match="gain x period"):
        ExternalTorqueEstimator(sim.physics.model.ptr, dofs, sim._arm_qpos, gain=40.0, period=PERIOD)
    sim.disconnect()


class _Pushed(ArmWrapper):
    """The sim arm with a push on the pusher from a given tick on: a force (N, world frame) on the
    tool's body, MuJoCo's ``xfrc_applied`` (a person leaning on the tool, an unmodelled obstacle)."""

    def __init__(self, arm: SimArm, at_tick: int | None, force: np.ndarray) -> None:
        super().__init__(arm)
        self.at_tick, self.force, self.reads, self.pushed_at = at_tick, force, 0, None
        model = arm.physics.model.ptr
        self.body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "pusher")
        if self.body < 0:  # the tool's body, by the name the task gives it
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(model.nbody)]
            self.body = next(b for b, n in enumerate(names) if n.endswith("pusher"))

    def refresh_feedback(self):
        self.reads += 1
        if self.at_tick is not None and self.reads == self.at_tick:
            self.arm.physics.data.xfrc_applied[self.body, :3] = self.force
            self.pushed_at = self.reads
        return self.arm.refresh_feedback()


def _run(at_tick: int | None, caplog) -> tuple[object, _Pushed]:
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="", duration=6.0)
    sim = SimArm(config.task, seed=0, clock=FastClock())
    arm = _Pushed(sim, at_tick, np.array([0.0, 100.0, 0.0]))  # 100 N sideways (+y) on the tool
    session = DeploySession.open(arm, config, None, settings, world_seed=0)  # the scripted controller
    session.reset_sim(0, sim)
    with caplog.at_level(logging.WARNING):
        summary, fault = session.run(settings.duration)
    assert fault == ""
    return summary, arm


def test_a_push_on_the_tool_stops_the_run_and_a_run_without_it_does_not(caplog):
    quiet, _ = _run(None, caplog)
    assert not quiet.stop_reason.startswith("contact"), quiet.stop_reason
    pushed, arm = _run(15, caplog)
    assert pushed.stop_reason.startswith("contact: joint"), pushed.stop_reason
    # the loop reads feedback once per tick, and the tick that sees the contact commands the stop:
    # 4 ticks (200 ms) after the push began here (the estimate's low-pass, K = 10/s, and
    # contact.readings = 2). The thresholds sit at the actuators' limits (configs/robots/jaco.yaml):
    # a 60 N push is not sensed, and one that back-drives the arm faster than the velocity alarm's
    # speed (100 N along x, 150 N down) is stopped by that alarm first
    assert arm.pushed_at is not None and arm.reads - arm.pushed_at <= 6, (arm.pushed_at, arm.reads)
    assert pushed.emergency_stops >= 1


def test_contact_stop_is_off_where_torques_are_not_read_with_every_frame(caplog):
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="", duration=1.0)
    sim = SimArm(config.task, seed=0, clock=FastClock())

    class Slow(ArmWrapper):
        torque_every_frame = False  # as the Gen2 backend (status-rate torques)

    session = DeploySession.open(Slow(sim), config, None, settings, world_seed=0)
    with caplog.at_level(logging.WARNING, logger="ahrm_stack.deploy"):
        loop = session.loop()
    assert not loop.contact.active
    assert "contact stop off: Slow does not measure the torques with every feedback frame" in caplog.text
    off = dataclasses.replace(settings, contact=dataclasses.replace(settings.contact, enabled=False))
    assert not DeploySession.open(sim, config, None, off, world_seed=0).loop().contact.active
    assert DeploySession.open(sim, config, None, settings, world_seed=0).loop().contact.active


def test_the_contact_stop_changes_nothing_but_the_stop():
    """A normal run commands the same speeds, tick for tick, with the contact stop on and off (it
    reads the feedback on its own copy of the model's data, never the world's)."""
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="", duration=4.0)
    off = dataclasses.replace(settings, contact=dataclasses.replace(settings.contact, enabled=False))
    class Logged(ArmWrapper):
        def __init__(self, arm):
            super().__init__(arm)
            self.commands: list[np.ndarray] = []

        def send_joint_speeds(self, speeds):
            self.commands.append(np.array(speeds, dtype=float))
            return self.arm.send_joint_speeds(speeds)

    sent = []
    for chosen in (settings, off):
        sim = SimArm(config.task, seed=3, clock=FastClock())
        arm = Logged(sim)
        session = DeploySession.open(arm, config, None, chosen, world_seed=3)
        session.reset_sim(3, sim)
        summary, fault = session.run(chosen.duration)
        assert fault == "" and not summary.stop_reason.startswith("contact")
        sent.append(np.array(arm.commands))
    assert sent[0].shape == sent[1].shape and len(sent[0]) > 20
    assert np.array_equal(sent[0], sent[1])
