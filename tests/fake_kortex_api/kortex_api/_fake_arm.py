"""The simulated arm behind the fake transport (test-only; not part of Kinova's API).

Kinematics only: each joint follows its commanded speed exactly (deg/s, integrated against
``time.perf_counter``), and a joint-speed command holds until the next one — Kortex's
``JointSpeed.duration`` is not implemented by the arm, so speeds never expire. The arm counts its
cyclic frames in ``Feedback.frame_id`` at ``tick_s`` (1 ms: the base's 1 kHz loop) modulo
``frame_modulus``. Positions are reported as Kortex does: continuous joints in [0, 360) deg,
limited joints in (-180, 180] deg.

A test drives the faults: :meth:`delay_next` (an RPC that takes longer; past its timeout it raises
``concurrent.futures.TimeoutError`` like the vendor's ``future.result(timeout)``),
:meth:`freeze_next`
(the next feedback repeats the previous frame), :meth:`lag_next` (the next feedback is a frame
measured ``lag`` s ago), :meth:`nan_next`, :meth:`fault`, :meth:`lose_connection`. Every RPC is
recorded in :attr:`calls` with the timeout its options carried (None: no options passed).
"""

from __future__ import annotations

import concurrent.futures
import copy
import dataclasses
import threading
import time

import numpy as np
from kortex_api.autogen.messages import Base_pb2, BaseCyclic_pb2, Common_pb2, Errors_pb2
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
    by default, or the adapter's virtual clock (hardware.protocol.FastClock) for a deterministic
    run whose time moves only when slept on."""

    _registry: dict[tuple[str, int], "FakeArm"] = {}

    def __init__(self, positions_deg, continuous, *, tick_s: float = 1e-3,
                 frame_modulus: int = 65536, clear_delay_s: float = 0.05,
                 frame_start: int = 0, velocity_limit_deg_s=None, clock=None) -> None:
        self._lock = threading.RLock()
        self.clock = clock if clock is not None else _Wall()
        self.positions = np.asarray(positions_deg, dtype=float).copy()  # deg, unwrapped
        self.continuous = np.asarray(continuous, dtype=bool)
        self.speeds = np.zeros_like(self.positions)  # deg/s, held until the next command
        self.velocity_limit = (None if velocity_limit_deg_s is None
                               else np.asarray(velocity_limit_deg_s, dtype=float))
        self.violations = 0  # commands that reached the joints beyond the velocity limit
        self.tick_s, self.frame_modulus, self.clear_delay_s = tick_s, frame_modulus, clear_delay_s
        self._t0 = self.clock.now() - frame_start * tick_s
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

    # ------------------------------------------------------------------ registry
    @classmethod
    def register(cls, address: str, port: int, arm: "FakeArm") -> "FakeArm":
        cls._registry[(address, int(port))] = arm
        return arm

    @classmethod
    def at(cls, address: str, port: int) -> "FakeArm":
        arm = cls._registry.get((address, int(port)))
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

    def lose_connection(self) -> None:
        """The link drops: the arm stops itself; every call fails until a new connection."""
        with self._lock:
            self._advance()
            self.lost = True
            self._set_speeds(np.zeros_like(self.speeds))

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
            delay = self._delays.pop(name, 0.0)
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
        frame.frame_id = int((when - self._t0) / self.tick_s) % self.frame_modulus
        frame.base.active_state = self._state()
        frame.base.fault_bank_a = self.base_bank_a
        reported = np.where(self.continuous, np.mod(positions, 360.0),
                            180.0 - np.mod(180.0 - positions, 360.0))  # (-180, 180]
        for i, (position, speed) in enumerate(zip(reported, self.speeds)):
            actuator = BaseCyclic_pb2.ActuatorFeedback()
            actuator.position = float(position)
            actuator.velocity = float(speed)
            actuator.torque = 0.5
            actuator.fault_bank_a = int(self.actuator_banks[i])
            actuator.command_id = frame.frame_id
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

    def _SendJointSpeedsCommand(self, message):
        if self.in_fault:
            sub = (Errors_pb2.ROBOT_IN_EMERGENCY_STOP if self.estopped
                   else Errors_pb2.ROBOT_IN_FAULT)
            raise KServerException(Errors_pb2.ERROR_DEVICE, sub,
                                   Errors_pb2.SubErrorCodes.Name(sub))
        if self.mode != Base_pb2.SINGLE_LEVEL_SERVOING:
            raise KServerException(Errors_pb2.ERROR_DEVICE, Errors_pb2.WRONG_SERVOING_MODE,
                                   "Wrong servoing mode")
        speeds = np.zeros_like(self.speeds)
        for item in message.joint_speeds:
            speeds[item.joint_identifier] = item.value
        self._set_speeds(speeds)

    def _Stop(self):
        self._set_speeds(np.zeros_like(self.speeds))

    def _ApplyEmergencyStop(self):
        self._set_speeds(np.zeros_like(self.speeds))
        self.estopped = True
        self._clear_at = None

    def _ClearFaults(self):
        self._clear_at = self.clock.now() + self.clear_delay_s

    def _SetServoingMode(self, info):
        self.mode = info.servoing_mode
        self._set_speeds(np.zeros_like(self.speeds))

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
        self.positions = self.positions + self.speeds * (now - self._last)
        self._last = now
        self._history.append((now, self.positions.copy()))
        del self._history[:-200]
