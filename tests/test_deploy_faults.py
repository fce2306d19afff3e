"""Every way a deploy run can fail ends in a recorded stop.

Each scenario below breaks one thing in a running loop (or at start-up): every fault the sim
adapter offers (:class:`~ahrm_stack.sim_arm.InjectedFault`), an adapter call that raises, perception
that raises or returns the wrong number of obstacles or a NaN pose, a controller that raises,
returns the wrong size or NaN (the scripted one wrapped, and a policy whose action is NaN or
infinite), a safety filter that raises, and faults during start-up. For each run it measures:
the fault detected (the stop reason names it), the arm commanded to zero within one control
period of the first moment the loop could see the fault (the start of the tick that meets it; the
command deadline for a delayed command), a stop event in the telemetry, the summary as
the telemetry's last line, :class:`~ahrm_stack.deploy.DeployFault` raised for a software fault,
and no limit violation in the simulated arm.

In CI every scenario runs once on a :class:`~ahrm_stack.hardware.protocol.FastClock`. The full measurement,
paced to the wall clock, is ``python tests/test_deploy_faults.py --realtime --repeats 10``.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import os
import sys
from typing import Callable

os.environ.setdefault("MUJOCO_GL", "egl")
if __name__ == "__main__":  # run as a script: this checkout's packages, not an installed copy
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.deploy import (DeployFault, DeployLoop, PolicyController,  # noqa: E402
                               ScriptedController, WorldModel, load_deploy_settings)
from ahrm_stack.hardware.protocol import (FastClock, FeedbackTimeoutError, HardwareError,  # noqa: E402
                               WallClock)
from ahrm_stack.sim_arm import InjectedFault, SimArm  # noqa: E402

RATE_HZ = 20.0
WARM_TICKS = 5  # healthy ticks before the fault
DURATION = 3.0  # s; the fault comes long before


class Trigger:
    """Armed by a scenario; the faulty part fires it when the fault takes effect, recording the
    start of the tick that first sees it (clock s)."""

    def __init__(self) -> None:
        self.armed = False
        self.fault_time: float | None = None
        self.loop: DeployLoop | None = None

    def fire(self) -> bool:
        if not self.armed:
            return False
        if self.fault_time is None:
            self.fault_time = self.loop.tick_time  # this tick's start
        return True


class FaultyController:
    """Wraps a controller; once armed: ``raise`` (an exception), ``nan``, ``size`` (4 entries),
    or ``reset`` (its reset raises: a start-up fault)."""

    def __init__(self, inner, trigger: Trigger, mode: str | None) -> None:
        self.inner, self.trigger, self.mode = inner, trigger, mode
        self.cartesian = getattr(inner, "cartesian", False)

    @property
    def stage(self) -> str:
        return self.inner.stage

    def reset(self) -> None:
        if self.mode == "reset" and self.trigger.fire():
            raise RuntimeError("the planner found no plan")
        self.inner.reset()

    def __call__(self) -> np.ndarray:
        u = self.inner()
        if self.mode in ("raise", "nan", "size") and self.trigger.fire():
            if self.mode == "raise":
                raise ZeroDivisionError("float division by zero in the controller")
            if self.mode == "nan":
                u = np.array(u, dtype=float)
                u[1] = np.nan
            else:
                u = u[:4]
        return u


class NaNPolicy:
    """Stand-in for the policy's forward pass (the PolicyController's NumpyPolicy): action 0 until
    armed, then ``value`` (NaN or inf) in entry 0."""

    def __init__(self, trigger: Trigger, dim: int, value: float) -> None:
        self.trigger, self.dim, self.value = trigger, dim, value

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        action = np.zeros(self.dim, dtype=np.float32)
        if self.trigger.fire():
            action[0] = self.value
        return action


def _nan_policy_controller(world: WorldModel, config, trigger: Trigger, dim: int, value: float) -> PolicyController:
    """A PolicyController (a real, tiny actor) whose forward pass is :class:`NaNPolicy`."""
    from torch import nn

    from ahrm_stack.learning.ppo import GaussianHead, LeanActor, RunningNorm

    actor = LeanActor(RunningNorm(4, 10.0), nn.Sequential(nn.Sequential(nn.Linear(4, dim)),
                                                          GaussianHead(dim, 0.5, True)))
    controller = PolicyController(world, actor, config)
    controller._numpy = NaNPolicy(trigger, dim, value)
    return controller


@dataclasses.dataclass
class Rig:
    arm: SimArm
    world: WorldModel
    loop: DeployLoop
    telemetry: io.StringIO
    trigger: Trigger


def _rig(realtime: bool, controller: str | None = None, policy: tuple | None = None,
         seed: int = 0) -> Rig:
    mode = policy[0] if policy else "cartesian"
    config = load_config([f"task.action.mode={mode}"])
    settings = load_deploy_settings(rate_hz=RATE_HZ, realtime=realtime, telemetry="")
    clock = WallClock() if realtime else FastClock()
    arm = SimArm(config.task, seed=seed, clock=clock, command_delay=settings.sim.command_delay)
    world = WorldModel(config.task, seed=seed)
    trigger = Trigger()
    if policy:
        dim = 3 if mode == "cartesian" else len(world.robot.commanded_joints)
        inner = _nan_policy_controller(world, config, trigger, dim, policy[1])
    else:
        inner = ScriptedController(world, config)
    arm.connect()
    telemetry = io.StringIO()
    loop = DeployLoop(arm, world, FaultyController(inner, trigger, controller), config.safety,
                      settings, telemetry)
    trigger.loop = loop
    return Rig(arm, world, loop, telemetry, trigger)


def _adapter_fault(fault: InjectedFault) -> Callable[[Rig], None]:
    def arm(rig: Rig) -> None:
        # The next tick's refresh (or command) sees it; a delayed command is a fault only from
        # the command deadline on (before it, a slow command is on time).
        rig.trigger.fault_time = rig.loop.next_tick_time
        if fault == InjectedFault.DELAYED_COMMAND:
            rig.trigger.fault_time += rig.loop.settings.watchdog.command_deadline * rig.loop.period
        rig.arm.inject(fault)
    return arm


def _patch_arm(method: str, make: Callable) -> Callable[[Rig], None]:
    """Replace ``rig.arm.<method>`` by ``make(original, rig)`` once the trigger fires."""
    def arm(rig: Rig) -> None:
        original = getattr(rig.arm, method)
        faulty = make(original, rig)

        def patched(*args):
            return faulty(*args) if rig.trigger.fire() else original(*args)
        setattr(rig.arm, method, patched)
        rig.trigger.armed = True
    return arm


def _raise(error: Exception) -> Callable:
    def make(original, rig):
        def faulty(*args):
            raise error
        return faulty
    return make


def _fewer_obstacles(original, rig):
    def faulty():
        poses = original()
        return dataclasses.replace(poses, obstacle_positions=poses.obstacle_positions[:-1],
                                   obstacle_quaternions=poses.obstacle_quaternions[:-1],
                                   obstacle_velocities=poses.obstacle_velocities[:-1])
    return faulty


def _nan_pose(original, rig):
    def faulty():
        poses = original()
        position = poses.cube_position.copy()
        position[2] = np.nan
        return dataclasses.replace(poses, cube_position=position)
    return faulty


def _arm_trigger(rig: Rig) -> None:
    rig.trigger.armed = True


def _filter_raises(rig: Rig) -> None:
    solve = rig.loop._solve

    def faulty(*args, **kwargs):
        if rig.trigger.fire():
            raise np.linalg.LinAlgError("singular matrix in the QP")
        return solve(*args, **kwargs)
    rig.loop._solve = faulty
    rig.trigger.armed = True


@dataclasses.dataclass(frozen=True)
class Scenario:
    expect: str  # in the stop reason
    arm: Callable[[Rig], None]  # breaks the rig
    software_fault: bool  # run() raises DeployFault
    start_up: bool = False  # armed before start(): the fault hits start-up
    controller: str | None = None  # FaultyController mode
    policy: tuple | None = None  # (action mode, the action's bad value) for a NaN policy


SCENARIOS: dict[str, Scenario] = {
    **{f"adapter: {fault.value}": Scenario(expect, _adapter_fault(fault), False)
       for fault, expect in [
           (InjectedFault.STALE_FEEDBACK, "stale feedback"),
           (InjectedFault.DROPPED_FEEDBACK, "feedback dropped"),
           (InjectedFault.DELAYED_COMMAND, "missed deadline"),
           (InjectedFault.NAN_READING, "non-finite feedback"),
           (InjectedFault.FAULT_FLAG, "arm fault"),
           (InjectedFault.LOST_CONNECTION, "connection lost")]},
    "adapter: command raises HardwareError": Scenario(
        "adapter error", _patch_arm("send_joint_speeds", _raise(HardwareError("bus error"))),
        False),
    "adapter: command raises RuntimeError": Scenario(
        "command fault: RuntimeError", _patch_arm("send_joint_speeds",
                                                  _raise(RuntimeError("driver bug"))), True),
    "perception raises": Scenario(
        "perception fault: RuntimeError: camera",
        _patch_arm("perception", _raise(RuntimeError("camera driver crashed"))), True),
    "perception: wrong obstacle count": Scenario(
        "perception fault: ValueError: perception gave", _patch_arm("perception", _fewer_obstacles),
        True),
    "perception: NaN pose": Scenario(
        "non-finite perception", _patch_arm("perception", _nan_pose), False),
    "controller raises": Scenario(
        "controller fault: ZeroDivisionError", _arm_trigger, True, controller="raise"),
    "controller: NaN request": Scenario(
        "controller fault: non-finite request", _arm_trigger, True, controller="nan"),
    "controller: wrong size": Scenario(
        "controller fault: request", _arm_trigger, True, controller="size"),
    "policy (cartesian): NaN action": Scenario(
        "controller fault: non-finite request", _arm_trigger, True, policy=("cartesian", np.nan)),
    "policy (joint): NaN action": Scenario(
        "controller fault: non-finite request", _arm_trigger, True, policy=("joint", np.nan)),
    "policy (joint): inf action": Scenario(
        "controller fault: non-finite request", _arm_trigger, True, policy=("joint", np.inf)),
    "safety filter raises": Scenario(
        "safety filter fault: LinAlgError", _filter_raises, True),
    "start-up: perception raises": Scenario(
        "start-up fault: RuntimeError: camera",
        _patch_arm("perception", _raise(RuntimeError("camera driver crashed"))), True,
        start_up=True),
    "start-up: controller reset raises": Scenario(
        "start-up fault: RuntimeError: the planner", _arm_trigger, True, start_up=True,
        controller="reset"),
    "start-up: feedback times out": Scenario(
        "start-up fault: adapter error FeedbackTimeoutError",
        _patch_arm("refresh_feedback", _raise(FeedbackTimeoutError("no frame"))), True,
        start_up=True),
}


@dataclasses.dataclass
class Outcome:
    detected: bool  # the stop reason names the fault
    latency: float  # s, from the first moment the loop could see the fault (the start of the tick
    # whose refresh, perception, controller or filter meets it; the command deadline for a
    # delayed command; the call to run() at start-up) to the stop command
    period: float
    zero: bool  # the simulated actuators hold zero velocity
    stop_event: bool  # a stop / emergency stop event with the reason in the telemetry
    summary: bool  # the telemetry's last line is the summary, with the stop reason
    raised: bool  # run() raised DeployFault
    violations: int
    reason: str


class Unhealthy(RuntimeError):
    """The loop stopped before the fault (e.g. a deadline missed on a loaded machine)."""


def run_scenario(name: str, realtime: bool = False, seed: int = 0) -> Outcome:
    scenario = SCENARIOS[name]
    rig = _rig(realtime, scenario.controller, scenario.policy, seed)
    loop = rig.loop
    if not scenario.start_up:
        loop.start()
        for _ in range(WARM_TICKS):
            if not loop.tick():
                raise Unhealthy(loop.stop_reason)
    else:
        rig.trigger.fault_time = rig.arm.clock.now()
    scenario.arm(rig)
    try:
        summary, raised = loop.run(DURATION), False
    except DeployFault as fault:
        summary, raised = fault.summary, True
        assert fault.summary.fault == loop.stop_reason == str(fault)
    lines = [json.loads(line) for line in rig.telemetry.getvalue().splitlines()]
    stops = [line for line in lines if line.get("event") in ("stop", "emergency stop")]
    fault_time = rig.trigger.fault_time
    outcome = Outcome(
        detected=loop.halted and scenario.expect in loop.stop_reason,
        latency=(loop.stopped_at - fault_time) if fault_time is not None and loop.stopped_at
        is not None else float("inf"),
        period=loop.period,
        zero=bool(np.all(rig.arm.command == 0.0)),
        stop_event=any(scenario.expect in line["reason"] for line in stops),
        summary=bool(lines) and "summary" in lines[-1]
        and lines[-1]["summary"]["stop_reason"] == summary.stop_reason == loop.stop_reason,
        raised=raised, violations=rig.arm.violations, reason=loop.stop_reason)
    if rig.arm.is_connected:
        rig.arm.disconnect()
    return outcome


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_every_fault_ends_in_a_recorded_stop(name):
    outcome = run_scenario(name)
    scenario = SCENARIOS[name]
    assert outcome.detected, outcome.reason
    assert 0.0 <= outcome.latency <= outcome.period, outcome
    assert outcome.zero and outcome.violations == 0
    assert outcome.stop_event and outcome.summary
    assert outcome.raised == scenario.software_fault


def _measure(repeats: int, realtime: bool) -> int:
    rows, totals = [], dict(runs=0, detected=0, within=0, zero=0, stop=0, summary=0, raised=0,
                            violations=0, redone=0)
    worst = 0.0
    for name, scenario in SCENARIOS.items():
        latencies = []
        for seed in range(repeats):
            for _ in range(10):  # a wall-clock run may miss a deadline before the fault: redo it
                try:
                    o = run_scenario(name, realtime, seed)
                    break
                except Unhealthy as error:
                    totals["redone"] += 1
                    print(f"{name}: redone ({error})", file=sys.stderr)
            else:
                raise RuntimeError(f"{name}: no healthy start in 10 tries")
            totals["runs"] += 1
            totals["detected"] += o.detected
            totals["within"] += 0.0 <= o.latency <= o.period
            totals["zero"] += o.zero
            totals["stop"] += o.stop_event
            totals["summary"] += o.summary
            totals["raised"] += o.raised == scenario.software_fault
            totals["violations"] += o.violations
            latencies.append(o.latency)
        worst = max(worst, max(latencies))
        rows.append(f"{name:40s} stop after {1e3 * np.median(latencies):7.3f} ms median, "
                    f"{1e3 * max(latencies):7.3f} ms max")
    print("\n".join(rows))
    n = totals["runs"]
    clock = "wall clock" if realtime else "fast clock"
    print(f"{len(SCENARIOS)} scenarios x {repeats} runs ({clock}, {RATE_HZ:g} Hz, period {1e3 / RATE_HZ:.0f} ms): detected {totals['detected']}/{n}, "
          f"zero velocity within one period {totals['within']}/{n} (worst {1e3 * worst:.3f} ms), "
          f"arm at zero {totals['zero']}/{n}, stop event {totals['stop']}/{n}, summary "
          f"{totals['summary']}/{n}, DeployFault as expected {totals['raised']}/{n}, "
          f"limit violations {totals['violations']} ({totals['redone']} runs redone: the loop "
          "stopped before the fault)")
    ok = all(totals[k] == n for k in ("detected", "within", "zero", "stop", "summary", "raised"))
    return 0 if ok and totals["violations"] == 0 else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=10, help="runs per scenario (seeds 0..)")
    parser.add_argument("--realtime", action="store_true", help="pace to the wall clock")
    args = parser.parse_args()
    import logging
    logging.disable(logging.CRITICAL)
    sys.exit(_measure(args.repeats, args.realtime))
