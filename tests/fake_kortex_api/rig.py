"""Build a :class:`~ahrm_stack.hardware.kortex.KortexArm` on the fake ``kortex_api`` and its simulated arm.

The fake is imported from this folder only for the tests: :func:`fake_api` puts the folder on
``sys.path`` just long enough to import it, then removes it (and the ``kortex_api`` entries of
``sys.modules``), so ``import kortex_api`` elsewhere still fails as without the vendor library.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import itertools
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PASSWORD = "s3cr3t-Pa55word!"
_addresses = itertools.count(1)


@functools.lru_cache(maxsize=1)
def fake_api() -> dict:
    """The fake vendor modules, keyed like :func:`ahrm_stack.hardware.kortex.import_kortex_api`."""
    from ahrm_stack.hardware.kortex import KORTEX_MODULES

    names = {**KORTEX_MODULES, "_fake_arm": "kortex_api._fake_arm"}
    sys.path.insert(0, str(HERE))
    try:
        modules = {key: importlib.import_module(name) for key, name in names.items()}
    finally:
        sys.path.remove(str(HERE))
        for name in [m for m in sys.modules if m == "kortex_api" or m.startswith("kortex_api.")]:
            del sys.modules[name]
    return modules


@functools.lru_cache(maxsize=1)
def _configured():
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.hardware.kortex import kortex_options

    return kortex_options(load_deploy_settings())


def test_models() -> dict:
    """Test-only ``kortex.models``: the project's (Gen2) descriptions taken as 6-DoF Gen3 arms, so
    that the adapter can connect to a fake arm that reports itself as one (configs/deploy.yaml
    maps none: no description in the project is a Kortex arm)."""
    from ahrm_stack.hardware.kortex import KortexModel

    return {name: KortexModel("MODEL_ID_L53", 6) for name in ("jaco", "j2s6s200")}


def options(**changes):
    """The backend's numbers from configs/deploy.yaml (20 Hz; read once), with :func:`test_models`
    and ``changes``."""
    return dataclasses.replace(_configured(), **{"models": test_models(), **changes})


def standin_frame(actuators: int):
    """A BaseCyclic feedback frame for hand-made stand-ins of the vendor API: ``actuators`` at
    rest, the arm ready (the fake's message classes)."""
    api = fake_api()
    frame = api["_fake_arm"].BaseCyclic_pb2.Feedback()
    frame.base.active_state = api["Common_pb2"].ARMSTATE_SERVOING_READY
    for _ in range(actuators):
        frame.actuators.append(api["_fake_arm"].BaseCyclic_pb2.ActuatorFeedback())
    return frame


def standin_reply(name: str, actuators: int):
    """The answer of a stand-in Base RPC ``name`` for a ``actuators``-joint Gen3 (model 1, no
    protection zones, 1000 deg/s hard limits); None for the others (Stop, SetServoingMode...)."""
    arm = fake_api()["_fake_arm"].FakeArm(np.zeros(actuators), np.zeros(actuators, dtype=bool),
                                           product={"model": 1, "dof": actuators})
    method = getattr(arm, "_" + name, None)
    if name in ("GetProductConfiguration", "GetAllJointsSpeedHardLimitation",
                "ReadAllProtectionZones", "GetAllKinematicSoftLimits"):
        return method()
    return None


def standin_control_config(actuators: int = 6) -> dict:
    """The ControlConfig entries of a hand-made stand-in vendor API: a client answering as
    :func:`standin_reply` does, and the fake's ``ControlConfig_pb2``."""
    import types

    class ControlConfig:
        def __init__(self, router) -> None:
            pass

        def __getattr__(self, name):
            return lambda *args, **options: standin_reply(name, actuators)

    return {"ControlConfigClientRpc": types.SimpleNamespace(ControlConfigClient=ControlConfig),
            "ControlConfig_pb2": fake_api()["ControlConfig_pb2"]}


def start_degrees(robot) -> np.ndarray:
    """A posture inside every limit: the centre of each limited joint's range, 0 elsewhere, deg."""
    limited = robot.limited
    centre = 0.5 * (np.where(limited, robot.position_lower, 0.0)
                    + np.where(limited, robot.position_upper, 0.0))
    return np.degrees(np.where(limited, centre, 0.0))


def make(robot, *, positions_deg=None, opts=None, password: str = PASSWORD, clock=None,
         **arm_kwargs):
    """(adapter, simulated arm): a :class:`KortexArm` for ``robot`` and a fake arm registered at a
    fresh documentation address (192.0.2.x), not yet connected. ``clock``: shared by both (a
    ``FastClock`` for a deterministic run); default the wall clock."""
    from ahrm_stack.hardware.kortex import Credentials, KortexArm

    api = fake_api()
    FakeArm = api["_fake_arm"].FakeArm
    address = f"192.0.2.{next(_addresses) % 250 + 1}"
    opts = opts or options()
    positions = start_degrees(robot) if positions_deg is None else positions_deg
    arm = FakeArm.register(address, opts.port,
                           FakeArm(positions, ~robot.limited, clock=clock, **arm_kwargs))
    adapter = KortexArm(robot, address, Credentials("admin", password), opts, api=api, clock=clock)
    return adapter, arm


def child_spec(robot, positions_deg=None, **arm_kwargs) -> str:
    """``$FAKE_KORTEX_ARM`` for a fake arm in a child process (plain values; see the fake arm's
    docstring): ``robot``'s start posture, continuous joints and velocity limits."""
    import json

    positions = start_degrees(robot) if positions_deg is None else positions_deg
    spec = {"positions_deg": np.asarray(positions, dtype=float).tolist(),
            "continuous": (~robot.limited).tolist(),
            "velocity_limit_deg_s": np.degrees(robot.velocity_limit).tolist(), **arm_kwargs}
    return json.dumps(spec)


def make_child(robot, monkeypatch, *, opts=None, password: str = PASSWORD, **arm_kwargs):
    """A :class:`KortexArm` whose ``kortex_api`` is the fake, run in a child process (this
    interpreter, the fake on its ``PYTHONPATH``), with the arm ``arm_kwargs`` describe (set in
    ``$FAKE_KORTEX_ARM`` through ``monkeypatch``). Not yet connected."""
    from ahrm_stack.hardware.kortex import Credentials, KortexArm

    monkeypatch.setenv("FAKE_KORTEX_ARM", child_spec(robot, **arm_kwargs))
    address = f"192.0.2.{next(_addresses) % 250 + 1}"
    return KortexArm(robot, address, Credentials("admin", password), opts or options(),
                     child_path=[HERE])


def make_for(robot, **kwargs):
    """:func:`make` with the fake arm's velocity limits set from ``robot`` (violations counted)."""
    return make(robot, velocity_limit_deg_s=np.degrees(robot.velocity_limit), **kwargs)


class DeployRig:
    """A deploy loop (scripted controller, at the config's rate) on a :class:`KortexArm` over the
    fake arm, which starts at the task's initial posture; both on ``clock`` (default a
    ``FastClock``: deterministic, whatever the machine's load). Perception is the layout's initial
    poses, held static (test-only: the fake arm moves no cube). ``inject`` maps the sim backend's
    :class:`~ahrm_stack.sim_arm.InjectedFault` onto the fake arm."""

    def __init__(self, config, seed: int = 0, opts=None, clock=None) -> None:
        import io

        from ahrm_stack.deploy import (DeployLoop, ScriptedController, WorldModel,
                                       load_deploy_settings)
        from ahrm_stack.hardware.protocol import FastClock, ObjectPoses

        settings = load_deploy_settings(telemetry="")
        clock = clock if clock is not None else FastClock()
        world = WorldModel(config.task, seed=seed)
        data = world.physics.data
        at = world.task.addresses  # where the joints sit in the world model's physics
        start = np.degrees(data.qpos[at.arm_qpos])
        self.adapter, self.fake = make_for(world.robot, positions_deg=start, opts=opts, clock=clock)
        qpos, qvel = data.qpos.copy(), data.qvel.copy()

        def perception() -> ObjectPoses:
            return ObjectPoses(
                timestamp=clock.now(), cube_position=qpos[at.cube_qpos[:3]],
                cube_quaternion=qpos[at.cube_qpos[3:]], cube_velocity=np.zeros(3),
                obstacle_positions=qpos[at.obstacle_qpos[:, :3]],
                obstacle_quaternions=qpos[at.obstacle_qpos[:, 3:]],
                obstacle_velocities=np.zeros((len(at.obstacle_qpos), 3)))

        del qvel
        self.adapter.perception = perception  # the static scene (instance attribute)
        self.adapter.connect()
        self.telemetry = io.StringIO()
        controller = ScriptedController(world, config)
        self.loop = DeployLoop(self.adapter, world, controller, config.safety, settings,
                               self.telemetry)
        self.loop.start()

    def inject(self, fault) -> None:
        name = fault.value
        if name == "stale_feedback":
            self.fake.freeze_next()
        elif name == "dropped_feedback":
            self.fake.delay_next("RefreshFeedback", 1.0)  # far past rpc_timeout_ms
        elif name == "delayed_command":
            self.fake.delay_next("SendJointSpeedsCommand", 0.03)
        elif name == "nan_reading":
            self.fake.nan_next()
        elif name == "fault_flag":
            self.fake.fault()
        elif name == "lost_connection":
            self.fake.lose_connection()
        else:
            raise ValueError(name)

    @property
    def command(self) -> np.ndarray:
        """The joint speeds the fake arm holds, rad/s."""
        return np.radians(self.fake.command)

    @property
    def violations(self) -> int:
        return self.fake.violations
