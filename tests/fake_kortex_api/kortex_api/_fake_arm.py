"""The simulated arm behind the fake transport (test-only; not part of Kinova's API).

Kinematics only: each joint follows its commanded speed exactly (deg/s, integrated against
``time.perf_counter``), and a joint-speed command holds until the next one — Kortex's
``JointSpeed.duration`` is not implemented by the arm, so speeds never expire. ``Feedback.frame_id``
is client-set on the real arm (it echoes the last ``BaseCyclic.Command``'s; Kinova's
api_python/examples/108-Gen3_torque_control sets it itself): nothing here sends a cyclic command, so
it stays 0. Torques, motor currents, voltages and temperatures carry sensor noise (a seeded
generator), as a powered arm's do. Positions are reported as Kortex does: continuous joints in
[0, 360) deg, limited joints in (-180, 180] deg. The arm also answers GetProductConfiguration
(``product``: model, DoF), GetAllJointsSpeedHardLimitation (its velocity limit, deg/s) and
ReadAllProtectionZones (``zones``, plain values as ahrm_stack.hardware.kortex.vendor_link returns them)
and ControlConfig's GetAllKinematicSoftLimits (``soft_limits``: ``{"control_mode": name,
"joint_speed": [deg/s], "joint_acceleration": [deg/s^2]}`` per mode; default: the four joystick and
trajectory modes at the speed hard limits, acceleration not reported).

**Actions.** ``ExecuteAction`` of a ``reach_joint_angles`` action moves the arm along a straight
joint-space line to the target (each joint to the target's equivalent nearest to where it is, so a
continuous joint goes the short way round), every joint arriving together, the fastest at the
action's ``JOINT_CONSTRAINT_SPEED`` (or ``action_speed_deg_s`` without one), capped by each joint's
ANGULAR_TRAJECTORY soft limit and hard limit; a thread of the arm advances it on the wall clock
(actions need the wall clock). The action topic's subscribers (``OnNotificationActionTopic``)
get ``ACTION_START``, then ``ACTION_END`` at the target, or ``ACTION_ABORT`` on ``Stop``,
``ApplyEmergencyStop``, a fault, the e-stop button (:meth:`press_estop`), a servoing mode change or
a lost link, each on a thread of the fake's (as the vendor's router thread calls them). A test
schedules an event mid-move with :meth:`after_action` (``estop``, ``fault``, ``lose_connection``,
``latency``, ``drop``, ``abort``); :attr:`injected` records each with its time, :attr:`notified`
every notification sent. ``long_way``: actions take continuous joints the long way round (a
hazard the homing's path check must catch).

In a child process (``ahrm_stack.hardware.kortex.child_link``) the test cannot reach the arm object: there
:meth:`at` builds the arm from ``$FAKE_KORTEX_ARM`` (JSON: the constructor's arguments, plus
``events``: ``[call number, action, argument]`` with action ``lose_connection``, ``drop`` (the
argument names the RPC), ``hang`` or ``exit``; ``move_events``: ``[seconds, action, argument]``
scheduled on each ExecuteAction (:meth:`after_action`); ``latency``: ``{RPC name: s}`` every such
call takes; and ``log``: a file each call is appended to, one JSON line with its name, timeout and
``t``, ``time.monotonic()``; an injected event is a line with ``event`` and ``t``).

A test drives the faults: :meth:`delay_next` (an RPC that takes longer; past its timeout it raises
``concurrent.futures.TimeoutError`` like the vendor's ``future.result(timeout)``),
:meth:`drop_next` (the next such RPC fails with a transport error, the link itself holds),
:meth:`freeze_next`
(the next feedback repeats the previous frame), :meth:`lag_next` (the next feedback is a frame
measured ``lag`` s ago), :meth:`nan_next`, :meth:`fault`, :meth:`lose_connection`,
:meth:`press_estop`, :meth:`set_latency` (every call of an RPC takes longer, until reset). Every RPC
is recorded in :attr:`calls` with the timeout its options carried (None: no options passed).
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import json
import os
import queue
import threading
import time

import numpy as np
from kortex_api.autogen.messages import (Base_pb2, BaseCyclic_pb2, Common_pb2, ControlConfig_pb2,
                                         Errors_pb2, ProductConfiguration_pb2)
from kortex_api.Exceptions.KClientException import KClientException
from kortex_api.Exceptions.KServerException import KServerException


@dataclasses.dataclass
class Call:
    name: str
    timeout_ms: float | None  # None: the call carried no RouterClientSendOptions
    time: float  # the arm clock's now() when it started


class _Wall:
    """The wall clock: ``now`` is ``time.perf_counter``, ``sleep`` really sleeps."""

    @staticmethod
    def now() -> float:
        return time.perf_counter()

    @staticmethod
    def sleep(seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class FakeArm:
    """The simulated arm. ``clock``: an object with ``now()`` (s) and ``sleep(s)``; the wall clock
    by default, or the adapter's virtual clock (ahrm_stack.hardware.protocol.FastClock) for a deterministic
    run whose time moves only when slept on."""

    _registry: dict[tuple[str, int], "FakeArm"] = {}

    def __init__(self, positions_deg, continuous, *, clear_delay_s: float = 0.05,
                 velocity_limit_deg_s=None, clock=None,
                 product: dict | None = None, zones: list | None = None,
                 speed_hard_limit_deg_s=None, seed: int = 0, events=(), log: str = "",
                 soft_limits: list | None = None, action_speed_deg_s: float = 30.0,
                 move_events=(), latency: dict | None = None, long_way: bool = False) -> None:
        self._lock = threading.RLock()
        self.clock = clock if clock is not None else _Wall()
        self.positions = np.asarray(positions_deg, dtype=float).copy()  # deg, unwrapped
        self.continuous = np.asarray(continuous, dtype=bool)
        self.speeds = np.zeros_like(self.positions)  # deg/s, held until the next command
        # N·m per actuator, what BaseCyclic reports (plus a 0.02 N·m sensor noise): the fake has no
        # dynamics, so a test that needs a held arm's torques sets them (set_torques)
        self.torques = np.full(len(self.positions), 0.5)
        self.velocity_limit = (None if velocity_limit_deg_s is None
                               else np.asarray(velocity_limit_deg_s, dtype=float))
        self.violations = 0  # commands that reached the joints beyond the velocity limit
        self.clear_delay_s = clear_delay_s
        self._last = self.clock.now()
        self.mode = Base_pb2.SINGLE_LEVEL_SERVOING
        self.estopped = False
        self.actuator_banks = np.zeros(self.positions.size, dtype=int)
        self.base_bank_a = 0
        self._clear_at: float | None = None
        self.lost = False
        self.sessions = 0
        self.session_info = None
        self.login_error: Exception | None = None
        self.calls: list[Call] = []
        self.speed_log: list[tuple[float, np.ndarray]] = []  # (time, speeds deg/s) at each change
        self._delays: dict[str, float] = {}
        self._freeze = self._nan = False
        self._lag = 0.0
        self._history: list[tuple[float, np.ndarray]] = []  # (time, positions) for lagged frames
        self._previous: BaseCyclic_pb2.Feedback | None = None
        self.product = dict(product or {"model": 1, "dof": int(self.positions.size)})
        self.zones = list(zones or [])
        hard = (speed_hard_limit_deg_s if speed_hard_limit_deg_s is not None
                else velocity_limit_deg_s if velocity_limit_deg_s is not None
                else np.full(self.positions.size, 1000.0))
        self.speed_hard_limit = np.asarray(hard, dtype=float)
        self._rng = np.random.default_rng(seed)
        self._drops: set[str] = set()
        self.events = {int(n): (action, arg) for n, action, arg in events}
        self.log = log
        self.soft_limits = soft_limits if soft_limits is not None else [
            {"control_mode": mode, "joint_speed": self.speed_hard_limit.tolist(), "joint_acceleration": []}
            for mode in ("ANGULAR_JOYSTICK", "CARTESIAN_JOYSTICK", "ANGULAR_TRAJECTORY",
                         "CARTESIAN_TRAJECTORY")]
        self.action_speed = float(action_speed_deg_s)
        self.move_events = [tuple(e) for e in move_events]
        self.latency = {str(k): float(v) for k, v in (latency or {}).items()}
        self.long_way = bool(long_way)  # actions take continuous joints the long way round
        self._move: dict | None = None  # the action running: start, delta, began, duration
        self._subscribers: dict[int, object] = {}  # handle identifier -> callback
        self._handles = 0
        self._outbox: queue.Queue = queue.Queue()  # notifications to deliver, on the fake's thread
        self._dispatcher: threading.Thread | None = None
        self.notified: list[tuple[str, float]] = []  # (ActionEvent name, time) of each sent
        self.injected: list[tuple[str, float]] = []  # (event, time) of each after_action event
        self.actions: list[dict] = []  # each ExecuteAction: target (deg), speed (deg/s), time

    # ------------------------------------------------------------------ registry
    @classmethod
    def register(cls, address: str, port: int, arm: "FakeArm") -> "FakeArm":
        cls._registry[(address, int(port))] = arm
        return arm

    @classmethod
    def at(cls, address: str, port: int) -> "FakeArm":
        arm = cls._registry.get((address, int(port)))
        spec = os.environ.get("FAKE_KORTEX_ARM")
        if arm is None and spec:  # in a child process: the arm the test described
            arm = cls.register(address, port, cls(**json.loads(spec)))
        if arm is None:
            raise KClientException(2, f"connection refused: no arm at {address}:{port}")
        arm.lost = False  # a new connection: the link is back
        return arm

    @classmethod
    def unregister(cls, address: str, port: int) -> None:
        cls._registry.pop((address, int(port)), None)

    # ------------------------------------------------------------------ test controls
    def delay_next(self, name: str, seconds: float) -> None:
        """The next ``name`` RPC takes ``seconds`` (past its timeout: TimeoutError)."""
        with self._lock:
            self._delays[name] = float(seconds)

    def drop_next(self, name: str) -> None:
        """The next ``name`` RPC fails with a transport error (KClientException); the link holds."""
        with self._lock:
            self._drops.add(name)

    def set_latency(self, name: str, seconds: float) -> None:
        """Every ``name`` RPC takes ``seconds`` from now on (0: as before; past its timeout:
        TimeoutError)."""
        with self._lock:
            self.latency[name] = float(seconds)

    def set_torques(self, newton_metres) -> None:
        """The actuators' torques (N·m) the feedback reports from now on (a contact: a change of them)."""
        with self._lock:
            self.torques = np.asarray(newton_metres, dtype=float).copy()

    def press_estop(self) -> None:
        """The arm's e-stop button: it stops, aborts its action and is in fault until reset."""
        with self._lock:
            self._advance()
            self._set_speeds(np.zeros_like(self.speeds))
            self.estopped = True
            self._clear_at = None
            self._abort()

    def after_action(self, seconds: float, action: str, arg=None) -> None:
        """On each ExecuteAction from now on, ``action`` runs ``seconds`` later: ``estop``
        (:meth:`press_estop`), ``fault``, ``lose_connection``, ``latency`` (``arg``: [RPC name, s],
        :meth:`set_latency`), ``drop`` (``arg``: the RPC) or ``abort`` (the action ends short of
        its target on the arm's side: ACTION_ABORT, no fault)."""
        with self._lock:
            self.move_events.append((float(seconds), action, arg))

    def _inject(self, action: str, arg) -> None:
        with self._lock:
            self.injected.append((action, self.clock.now()))
            if self.log:
                with open(self.log, "a") as file:
                    file.write(json.dumps({"event": action, "t": time.monotonic()}) + "\n")
            if action == "estop":
                self.press_estop()
            elif action == "fault":
                self.fault()
            elif action == "lose_connection":
                self.lose_connection()
            elif action == "latency":
                self.set_latency(str(arg[0]), float(arg[1]))
            elif action == "drop":
                self._drops.add(str(arg))
            elif action == "abort":  # the action ends on the arm's side (e.g. the Web App's stop)
                self._advance()
                self._abort()
            else:
                raise ValueError(f"unknown move event {action!r}")

    def freeze_next(self) -> None:
        """The next RefreshFeedback returns the previous frame again (same frame_id)."""
        with self._lock:
            self._freeze = True

    def lag_next(self, seconds: float) -> None:
        """The next RefreshFeedback returns the frame measured ``seconds`` ago."""
        with self._lock:
            self._lag = float(seconds)

    def nan_next(self) -> None:
        with self._lock:
            self._nan = True

    def fault(self, actuator: int = 0, bank: int = 1) -> None:
        """An actuator fault: the arm stops itself and enters fault."""
        with self._lock:
            self._advance()
            self.actuator_banks[actuator] = bank
            self._set_speeds(np.zeros_like(self.speeds))
            self._abort()

    def lose_connection(self) -> None:
        """The link drops: the arm stops itself; every call fails until a new connection."""
        with self._lock:
            self._advance()
            self._abort(notify=False)  # no notification over a lost link
            self.lost = True
            self._set_speeds(np.zeros_like(self.speeds))

    @property
    def moving_action(self) -> bool:
        """An action is running."""
        with self._lock:
            return self._move is not None

    @property
    def in_fault(self) -> bool:
        return self.estopped or bool(self.actuator_banks.any()) or bool(self.base_bank_a)

    @property
    def command(self) -> np.ndarray:
        """The joint speeds the arm holds now, deg/s."""
        with self._lock:
            return self.speeds.copy()

    def read_positions(self) -> np.ndarray:
        """Joint positions now, deg (unwrapped)."""
        with self._lock:
            self._advance()
            return self.positions.copy()

    # ------------------------------------------------------------------ the wire
    def rpc(self, name: str, options, *args):
        start = self.clock.now()
        timeout_s = None if options is None else options.getTimeoutInSecond()
        with self._lock:
            self.calls.append(Call(name, None if options is None else options.timeout_ms, start))
            delay = self._delays.pop(name, 0.0) or self.latency.get(name, 0.0)
            self._scripted(name, None if options is None else options.timeout_ms)
            if name in self._drops:
                self._drops.discard(name)
                raise KClientException(2, f"{name}: connection reset (transport error)")
        if delay:
            limit = 10.0 if timeout_s is None else timeout_s
            self.clock.sleep(min(delay, limit))
            if delay > limit:
                raise concurrent.futures.TimeoutError()
        with self._lock:
            if self.lost:
                raise KClientException(2, f"{name}: connection lost (transport error)")
            self._advance()
            return getattr(self, "_" + name)(*args)

    def _scripted(self, name: str, timeout_ms) -> None:
        """The child-process controls: log the call, then run the event of its number."""
        if self.log:
            with open(self.log, "a") as file:
                file.write(json.dumps({"name": name, "timeout_ms": timeout_ms,
                                       "t": time.monotonic()}) + "\n")
        action, arg = self.events.pop(len(self.calls), (None, None))
        if action == "lose_connection":
            self.lose_connection()
        elif action == "drop":
            self._drops.add(arg)
        elif action == "hang":
            time.sleep(3600)
        elif action == "exit":
            os._exit(3)

    # ------------------------------------------------------------------ services
    def _CreateSession(self, info):
        if self.login_error is not None:
            raise self.login_error
        self.session_info = info
        self.sessions += 1

    def _CloseSession(self):
        self.sessions = max(0, self.sessions - 1)

    def _state(self) -> int:
        if self.in_fault:
            return Common_pb2.ARMSTATE_IN_FAULT
        if self.mode == Base_pb2.LOW_LEVEL_SERVOING:
            return Common_pb2.ARMSTATE_SERVOING_LOW_LEVEL
        return Common_pb2.ARMSTATE_SERVOING_READY

    def _frame(self, when: float, positions: np.ndarray) -> BaseCyclic_pb2.Feedback:
        frame = BaseCyclic_pb2.Feedback()
        frame.frame_id = 0  # client-set (the last cyclic command's): none was sent
        frame.base.active_state = self._state()
        frame.base.fault_bank_a = self.base_bank_a
        frame.base.arm_voltage = 24.0 + float(self._rng.normal(0.0, 0.05))
        frame.base.arm_current = 1.2 + float(self._rng.normal(0.0, 0.01))
        reported = np.where(self.continuous, np.mod(positions, 360.0),
                            180.0 - np.mod(180.0 - positions, 360.0))  # (-180, 180]
        for i, (position, speed) in enumerate(zip(reported, self.speeds)):
            actuator = BaseCyclic_pb2.ActuatorFeedback()
            actuator.position = float(position)
            actuator.velocity = float(speed)
            actuator.torque = float(self.torques[i]) + float(self._rng.normal(0.0, 0.02))
            actuator.current_motor = 0.3 + float(self._rng.normal(0.0, 0.005))
            actuator.voltage = 24.0 + float(self._rng.normal(0.0, 0.05))
            actuator.temperature_core = 35.0 + float(self._rng.normal(0.0, 0.1))
            actuator.fault_bank_a = int(self.actuator_banks[i])
            actuator.command_id = 0
            frame.actuators.append(actuator)
        return frame

    def _RefreshFeedback(self):
        now = self.clock.now()
        if self._freeze and self._previous is not None:
            self._freeze = False
            return copy.deepcopy(self._previous)
        if self._lag:
            lag, self._lag = self._lag, 0.0
            when = now - lag
            past = [p for t, p in self._history if t <= when]
            frame = self._frame(when, past[-1] if past else self.positions)
        else:
            frame = self._frame(now, self.positions)
        if self._nan:
            self._nan = False
            frame.actuators[0].velocity = float("nan")
        self._previous = copy.deepcopy(frame)
        return frame

    def _refuse_motion(self) -> None:
        """Motion is refused in fault and outside single-level servoing, as the arm does."""
        if self.in_fault:
            sub = (Errors_pb2.ROBOT_IN_EMERGENCY_STOP if self.estopped
                   else Errors_pb2.ROBOT_IN_FAULT)
            raise KServerException(Errors_pb2.ERROR_DEVICE, sub,
                                   Errors_pb2.SubErrorCodes.Name(sub))
        if self.mode != Base_pb2.SINGLE_LEVEL_SERVOING:
            raise KServerException(Errors_pb2.ERROR_DEVICE, Errors_pb2.WRONG_SERVOING_MODE,
                                   "Wrong servoing mode")

    def _SendJointSpeedsCommand(self, message):
        self._refuse_motion()
        self._abort()  # a joint speed command ends the action running
        speeds = np.zeros_like(self.speeds)
        for item in message.joint_speeds:
            speeds[item.joint_identifier] = item.value
        self._set_speeds(speeds)

    def _Stop(self):
        self._set_speeds(np.zeros_like(self.speeds))
        self._abort()

    def _ApplyEmergencyStop(self):
        self._set_speeds(np.zeros_like(self.speeds))
        self.estopped = True
        self._clear_at = None
        self._abort()

    def _ClearFaults(self):
        self._clear_at = self.clock.now() + self.clear_delay_s

    def _SetServoingMode(self, info):
        self.mode = info.servoing_mode
        self._set_speeds(np.zeros_like(self.speeds))
        self._abort()

    def _GetProductConfiguration(self):
        config = ProductConfiguration_pb2.CompleteProductConfiguration()
        config.model = int(self.product["model"])
        config.degree_of_freedom = int(self.product["dof"])
        return config

    def _GetAllJointsSpeedHardLimitation(self):
        limits = Base_pb2.JointsLimitationsList()
        for i, value in enumerate(self.speed_hard_limit):
            item = limits.joints_limitations.add()
            item.joint_identifier, item.type, item.value = i, Base_pb2.VELOCITY_LIMITATION, float(value)
        return limits

    def _ReadAllProtectionZones(self):
        out = Base_pb2.ProtectionZoneList()
        for values in self.zones:
            zone = out.protection_zones.add()
            zone.name, zone.is_enabled = values["name"], values["enabled"]
            shape = zone.shape
            shape.shape_type = values["shape_type"]
            shape.origin.x, shape.origin.y, shape.origin.z = values["origin"]
            rows = (shape.orientation.row1, shape.orientation.row2, shape.orientation.row3)
            for row, got in zip(rows, values.get("orientation", np.eye(3).tolist())):
                row.column1, row.column2, row.column3 = got
            shape.dimensions.extend(values["dimensions"])
            shape.envelope_thickness = values["envelope"]
        return out

    def _GetAllKinematicSoftLimits(self):
        out = ControlConfig_pb2.KinematicLimitsList()
        for values in self.soft_limits:
            item = out.kinematic_limits_list.add()
            item.control_mode = ControlConfig_pb2.ControlMode.Value(values["control_mode"])
            item.joint_speed_limits = [float(v) for v in values["joint_speed"]]
            item.joint_acceleration_limits = [float(v) for v in values.get("joint_acceleration", [])]
        return out

    def _OnNotificationActionTopic(self, callback):
        self._handles += 1
        self._subscribers[self._handles] = callback
        handle = Common_pb2.NotificationHandle()
        handle.identifier = self._handles
        return handle

    def _Unsubscribe(self, handle):
        self._subscribers.pop(int(handle.identifier), None)

    def _trajectory_cap(self) -> np.ndarray:
        """deg/s per joint an action may reach: the ANGULAR_TRAJECTORY soft limit and the hard limit."""
        cap = self.speed_hard_limit.copy()
        for values in self.soft_limits:
            if values["control_mode"] == "ANGULAR_TRAJECTORY" and len(values["joint_speed"]) >= cap.size:
                cap = np.minimum(cap, np.asarray(values["joint_speed"][:cap.size], dtype=float))
        return cap

    def _ExecuteAction(self, action):
        self._refuse_motion()
        if action.WhichOneof("action_parameters") != "reach_joint_angles":
            raise KServerException(Errors_pb2.ERROR_DEVICE, 0, "the fake runs reach_joint_angles only")
        reach = action.reach_joint_angles
        goal = self.positions.copy()
        for angle in reach.joint_angles.joint_angles:
            goal[angle.joint_identifier] = angle.value
        delta = (goal - self.positions + 180.0) % 360.0 - 180.0  # to the nearest equivalent
        if self.long_way:
            delta = np.where(self.continuous & (delta != 0.0), delta - np.sign(delta) * 360.0, delta)
        speed = (reach.constraint.value if reach.constraint.type == Base_pb2.JOINT_CONSTRAINT_SPEED
                 else self.action_speed)
        speed = np.minimum(float(speed), self._trajectory_cap())
        duration = float(np.max(np.abs(delta) / speed)) if np.any(delta) else 0.0
        self._abort()  # a new action replaces the one running
        now = self.clock.now()
        self.actions.append({"target": goal.tolist(), "speed": float(np.max(speed)), "time": now})
        move = {"start": self.positions.copy(), "delta": delta, "began": now, "duration": duration}
        self._move = move
        self._notify("ACTION_START")
        threading.Thread(target=self._run_action, args=(move,), daemon=True,
                         name="fake-kortex-action").start()
        for seconds, what, arg in self.move_events:
            timer = threading.Timer(float(seconds), self._inject, (what, arg))
            timer.daemon = True
            timer.start()

    def _run_action(self, move: dict) -> None:
        """Advance the action until it ends (the arm's own trajectory, not driven by the client)."""
        while True:
            with self._lock:
                if self._move is not move:
                    return
                self._advance()
                if self._move is not move:
                    return
            time.sleep(0.002)

    def _abort(self, notify: bool = True) -> None:
        """End the running action short of its target (ACTION_ABORT to the subscribers)."""
        if self._move is None:
            return
        self._move = None
        self._set_speeds(np.zeros_like(self.speeds))
        if notify:
            self._notify("ACTION_ABORT")

    def _notify(self, name: str) -> None:
        self.notified.append((name, self.clock.now()))
        if self._dispatcher is None:
            self._dispatcher = threading.Thread(target=self._dispatch, daemon=True,
                                                name="fake-kortex-notifications")
            self._dispatcher.start()
        self._outbox.put((Base_pb2.ActionEvent.Value(name), list(self._subscribers.values())))

    def _dispatch(self) -> None:
        while True:
            event, callbacks = self._outbox.get()
            for callback in callbacks:
                notification = Base_pb2.ActionNotification()
                notification.action_event = event
                callback(notification)

    def _GetServoingMode(self):
        info = Base_pb2.ServoingModeInformation()
        info.servoing_mode = self.mode
        return info

    # ------------------------------------------------------------------ physics
    def _set_speeds(self, speeds: np.ndarray) -> None:
        speeds = np.asarray(speeds, dtype=float)
        if self.velocity_limit is not None and not (
                np.isfinite(speeds).all() and (np.abs(speeds) <= self.velocity_limit + 1e-9).all()):
            self.violations += 1
        if not np.array_equal(speeds, self.speeds):
            self.speed_log.append((self.clock.now(), speeds.copy()))
        self.speeds = speeds.copy()

    def _advance(self) -> None:
        now = self.clock.now()
        if self._clear_at is not None and now >= self._clear_at:
            self._clear_at = None
            self.estopped = False
            self.actuator_banks[:] = 0
            self.base_bank_a = 0
        move = self._move
        if move is None:
            self.positions = self.positions + self.speeds * (now - self._last)
        else:  # an action: along its straight line, the joints arriving together
            done = move["duration"] <= 0.0 or now - move["began"] >= move["duration"]
            share = 1.0 if done else (now - move["began"]) / move["duration"]
            self.positions = move["start"] + move["delta"] * share
            if done:
                self._move = None
                self._set_speeds(np.zeros_like(self.speeds))
                self._notify("ACTION_END")
            else:
                self.speeds = move["delta"] / move["duration"]  # what the velocity feedback reads
        self._last = now
        self._history.append((now, self.positions.copy()))
        del self._history[:-200]
