"""The vendor side of the link: the only module that calls ``kortex_api``, in plain values.

:class:`VendorLink` turns each call the adapter needs into the vendor's RPC and its answer into
plain values (numbers, strings, lists, dicts: degrees, metres, as the vendor reports them), and
every vendor exception into a :class:`LinkError` of one kind (``timeout``, ``fault``,
``connection``, ``other``). It runs either inside the adapter's process (tests pass a fake API) or,
the default, in a process of its own (:func:`serve`, started by
:class:`ahrm_stack.hardware.kortex.child_link.ChildLink`) under an interpreter that may be another virtual
environment: ``kortex_api`` 2.6.0 needs ``protobuf`` 3.x, which breaks tensorboard and ray here, so
that pin lives in the child's environment only.

This module uses the standard library alone (the child's environment need hold nothing but
``kortex_api`` and its protobuf). The RPCs and message fields are those of Kinova's reference
(Kinovarobotics/Kinova-kortex2_Gen3_G3L, api_python/doc/markdown): ``BaseCyclic.RefreshFeedback``
(messages/BaseCyclic/Feedback.md, ActuatorFeedback.md, BaseFeedback.md),
``Base.GetProductConfiguration`` (messages/ProductConfiguration/CompleteProductConfiguration.md),
``Base.GetAllJointsSpeedHardLimitation`` (messages/Base/JointsLimitationsList.md),
``Base.ReadAllProtectionZones`` (messages/Base/ProtectionZone.md, ZoneShape.md; used as in
api_python/examples/100-Overview/02-protection_zones_configuration.py),
``ControlConfig.GetAllKinematicSoftLimits`` (summary_pages/ControlConfig.md,
messages/ControlConfig/KinematicLimitsList.md, KinematicLimits.md, enums/ControlConfig/ControlMode.md),
and for ``--home`` ``Base.OnNotificationActionTopic`` / ``Base.ExecuteAction`` / ``Base.Unsubscribe``
with an ``Action`` whose ``reach_joint_angles`` holds the target (messages/Base/Action.md,
ConstrainedJointAngles.md, JointTrajectoryConstraint.md, enums/Base/ActionEvent.md; used as in
api_python/examples/102-Movement_high_level/01-move_angular_and_cartesian.py, whose wait for
ACTION_END / ACTION_ABORT is a ``threading.Event``: here the notifications are queued instead and
read with :meth:`VendorLink.call` ``("action_events")``, so that nothing waits on them).
"""

from __future__ import annotations

import importlib
import json
import os
import signal
import sys
import threading
import time
from typing import Any, Callable

#: The vendor modules the backend uses, keyed as the link reads them.
KORTEX_MODULES = {
    "TCPTransport": "kortex_api.TCPTransport",
    "RouterClient": "kortex_api.RouterClient",
    "SessionManager": "kortex_api.SessionManager",
    "BaseClientRpc": "kortex_api.autogen.client_stubs.BaseClientRpc",
    "BaseCyclicClientRpc": "kortex_api.autogen.client_stubs.BaseCyclicClientRpc",
    "ControlConfigClientRpc": "kortex_api.autogen.client_stubs.ControlConfigClientRpc",
    "Base_pb2": "kortex_api.autogen.messages.Base_pb2",
    "ControlConfig_pb2": "kortex_api.autogen.messages.ControlConfig_pb2",
    "Common_pb2": "kortex_api.autogen.messages.Common_pb2",
    "Session_pb2": "kortex_api.autogen.messages.Session_pb2",
    "Errors_pb2": "kortex_api.autogen.messages.Errors_pb2",
    "KServerException": "kortex_api.Exceptions.KServerException",
    "KClientException": "kortex_api.Exceptions.KClientException",
}

INSTALL_HINT = (
    "kortex_api is not installed. It is not on PyPI: download Kinova's wheel "
    "kortex_api-2.6.0.post3-py3-none-any.whl from Kinova's Artifactory "
    "(https://artifactory.kinovaapps.com:443/artifactory/generic-public/kortex/API/2.6.0/"
    "kortex_api-2.6.0.post3-py3-none-any.whl) and run `python3 -m pip install "
    "kortex_api-2.6.0.post3-py3-none-any.whl`. That wheel pins protobuf==3.5.1, which fails to "
    "import on Python >= 3.10; there, Kinova's workaround is `pip install protobuf==3.20 "
    "deprecated==1.2.7` then `pip install kortex_api-2.6.0.post3-py3-none-any.whl --no-deps` "
    "(Kinovarobotics/Kinova-kortex2_Gen3_G3L issue 191). Do this in a virtual environment of its "
    "own and name its interpreter in configs/deploy.yaml kortex.python (protobuf 3.20 breaks "
    "tensorboard and ray in ours). See docs/kortex.md.")

#: Errors_pb2.SubErrorCodes names that mean "the arm is in fault / not accepting motion".
FAULT_SUB_CODES = ("ROBOT_IN_FAULT", "ROBOT_IN_EMERGENCY_STOP", "WRONG_SERVOING_MODE")

#: The methods whose vendor-side durations :meth:`VendorLink.call` ``("timed")`` records (a run's per-tick
#: RPCs: ``BaseCyclic.RefreshFeedback`` and ``Base.SendJointSpeedsCommand``).
TIMED_METHODS = ("feedback", "joint_speeds")

#: The kinds of :class:`LinkError`.
LINK_ERROR_KINDS = ("timeout", "fault", "connection", "other", "dead", "not_installed")


class LinkError(Exception):
    """A call over the link failed. ``kind``: ``timeout`` (no answer within the RPC's timeout),
    ``fault`` (the arm refused it in fault), ``connection`` (the transport or session dropped),
    ``other``, ``dead`` (the kortex_api process is gone or hung) or ``not_installed``. The message
    may echo a secret: the adapter scrubs it."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind if kind in LINK_ERROR_KINDS else "other"
        self.message = message


def import_modules() -> dict:
    """The vendor modules (:data:`KORTEX_MODULES`), or ``LinkError('not_installed', ...)``."""
    try:
        return {key: importlib.import_module(module) for key, module in KORTEX_MODULES.items()}
    except ImportError:
        raise LinkError("not_installed", INSTALL_HINT) from None


def classify(api: dict, error: BaseException) -> str:
    """'timeout', 'fault', 'connection' or 'other' for a vendor exception: ``KServerException``
    by its sub-code (``METHOD_TIMEOUT``; :data:`FAULT_SUB_CODES`), ``KClientException`` (the
    transport) as the link, ``TimeoutError`` (the vendor's ``future.result(timeout)``) as a
    timeout."""
    if isinstance(error, TimeoutError):  # concurrent.futures.TimeoutError since 3.11
        return "timeout"
    server = getattr(api.get("KServerException"), "KServerException", None)
    client = getattr(api.get("KClientException"), "KClientException", None)
    if server is not None and isinstance(error, server):
        try:
            name = api["Errors_pb2"].SubErrorCodes.Name(error.get_error_sub_code())
        except Exception:  # noqa: BLE001 - an unknown code is a plain error
            name = ""
        if name == "METHOD_TIMEOUT":
            return "timeout"
        return "fault" if name in FAULT_SUB_CODES else "other"
    if client is not None and isinstance(error, client):
        return "connection"
    lowered = f"{type(error).__name__}: {error}".lower()
    if "timeout" in lowered:
        return "timeout"
    if "connection" in lowered or "transport" in lowered:
        return "connection"
    return "other"


class VendorLink:
    """The adapter's calls on ``kortex_api``, in plain values; :meth:`call` is the one entry.

    Args:
        api: the vendor modules (default: imported on the first :meth:`call`).
    """

    #: The methods :meth:`call` dispatches to.
    METHODS = ("open", "close", "feedback", "joint_speeds", "stop", "emergency_stop",
               "clear_faults", "set_servoing_mode", "product", "speed_limits", "protection_zones",
               "soft_limits", "subscribe_actions", "execute_joint_angles", "action_events",
               "unsubscribe", "timed")

    def __init__(self, api: dict | None = None) -> None:
        self._api = api
        self._transport: Any = None
        self._session: Any = None
        self._base: Any = None
        self._cyclic: Any = None
        self._control: Any = None
        self._subscription: Any = None  # the action topic's NotificationHandle while subscribed
        self._events: list[dict] = []  # action notifications not yet read (the vendor's thread adds)
        self._events_lock = threading.Lock()
        self._durations: dict[str, list[float]] | None = None  # per TIMED_METHODS, while timing
        self.is_open = False

    @property
    def api(self) -> dict:
        """The vendor modules (imported on first use)."""
        return self.import_api()

    def import_api(self) -> dict:
        """Import the vendor modules unless given; ``LinkError('not_installed')`` without them."""
        if self._api is None:
            self._api = import_modules()
        return self._api

    def call(self, method: str, **args: Any) -> Any:
        """``method(**args)``; a vendor exception becomes a :class:`LinkError` (raised outside the
        handler: the vendor's exception, which may echo the request, is not chained)."""
        if method not in self.METHODS:
            raise LinkError("other", f"unknown link method {method!r}")
        try:
            durations = self._durations
            if durations is None or method not in durations:
                return getattr(self, "_" + method)(**args)
            began = time.perf_counter()
            result = getattr(self, "_" + method)(**args)
            durations[method].append(time.perf_counter() - began)
            return result
        except LinkError:
            raise
        except Exception as error:  # noqa: BLE001 - every vendor failure is classified
            failure = LinkError(classify(self._api or {}, error), f"{type(error).__name__}: {error}")
        raise failure

    def shutdown(self) -> None:
        """Nothing to end in-process (the child link ends its process here)."""

    # ------------------------------------------------------------------ calls
    def _options(self, timeout_ms: int) -> Any:
        options = self.api["RouterClient"].RouterClientSendOptions()
        options.timeout_ms = int(timeout_ms)
        return options

    def _open(self, *, address: str, port: int, username: str, password: str,
              session_inactivity_timeout_ms: int, connection_inactivity_timeout_ms: int,
              timeout_ms: int) -> None:
        api = self.api
        self._transport = api["TCPTransport"].TCPTransport()
        router = api["RouterClient"].RouterClient(self._transport, lambda e: None)
        self._transport.connect(address, int(port))
        info = api["Session_pb2"].CreateSessionInfo()
        info.username = username
        info.password = password
        info.session_inactivity_timeout = int(session_inactivity_timeout_ms)
        info.connection_inactivity_timeout = int(connection_inactivity_timeout_ms)
        self._session = api["SessionManager"].SessionManager(router)
        self._session.CreateSession(info, options=self._options(timeout_ms))
        self._base = api["BaseClientRpc"].BaseClient(router)
        self._cyclic = api["BaseCyclicClientRpc"].BaseCyclicClient(router)
        self._control = api["ControlConfigClientRpc"].ControlConfigClient(router)
        self.is_open = True

    def _close(self, *, timeout_ms: int) -> None:
        """CloseSession, then the transport's disconnect (both tried)."""
        self.is_open = False
        self._subscription = None
        with self._events_lock:
            self._events.clear()
        failure: BaseException | None = None
        try:
            if self._session is not None:
                self._session.CloseSession(options=self._options(timeout_ms))
        except Exception as error:  # noqa: BLE001 - the transport is closed all the same
            failure = error
        if self._transport is not None:
            self._transport.disconnect()
        self._session = self._transport = None
        if failure is not None:
            raise failure

    def _feedback(self, *, timeout_ms: int) -> dict:
        """One BaseCyclic frame: per actuator position (deg), velocity (deg/s), torque (N·m),
        current_motor (A), voltage (V), temperature_core (°C), fault banks; the base's state name,
        fault banks, arm_voltage (V) and arm_current (A); ``frame_id`` as received."""
        raw = self._cyclic.RefreshFeedback(options=self._options(timeout_ms))
        actuators = list(raw.actuators)
        try:
            state = self.api["Common_pb2"].ArmState.Name(raw.base.active_state)
        except ValueError:
            state = "ARMSTATE_UNKNOWN"  # read as in fault
        return {
            "frame_id": int(raw.frame_id),
            "position": [float(a.position) for a in actuators],
            "velocity": [float(a.velocity) for a in actuators],
            "torque": [float(a.torque) for a in actuators],
            "current_motor": [float(a.current_motor) for a in actuators],
            "voltage": [float(a.voltage) for a in actuators],
            "temperature_core": [float(a.temperature_core) for a in actuators],
            "actuator_faults": [int(a.fault_bank_a) | int(a.fault_bank_b) for a in actuators],
            "state": state,
            "base_fault_a": int(raw.base.fault_bank_a),
            "base_fault_b": int(raw.base.fault_bank_b),
            "arm_voltage": float(raw.base.arm_voltage),
            "arm_current": float(raw.base.arm_current),
        }

    def _joint_speeds(self, *, speeds: list, timeout_ms: int) -> None:
        """``Base.SendJointSpeedsCommand``; ``speeds``: entries with ``joint_identifier``,
        ``value`` (deg/s) and ``duration``."""
        message = self.api["Base_pb2"].JointSpeeds()
        for entry in speeds:
            item = message.joint_speeds.add()
            item.joint_identifier = int(entry["joint_identifier"])
            item.value = float(entry["value"])
            item.duration = int(entry["duration"])
        self._base.SendJointSpeedsCommand(message, options=self._options(timeout_ms))

    def _stop(self, *, timeout_ms: int) -> None:
        self._base.Stop(options=self._options(timeout_ms))

    def _emergency_stop(self, *, timeout_ms: int) -> None:
        self._base.ApplyEmergencyStop(options=self._options(timeout_ms))

    def _clear_faults(self, *, timeout_ms: int) -> None:
        self._base.ClearFaults(options=self._options(timeout_ms))

    def _set_servoing_mode(self, *, mode: str, timeout_ms: int) -> None:
        base_pb2 = self.api["Base_pb2"]
        info = base_pb2.ServoingModeInformation()
        info.servoing_mode = getattr(base_pb2, mode)
        self._base.SetServoingMode(info, options=self._options(timeout_ms))

    def _product(self, *, timeout_ms: int) -> dict:
        """``Base.GetProductConfiguration``: ``model`` (a ``ProductConfiguration.ModelId`` value)
        and ``degree_of_freedom``."""
        config = self._base.GetProductConfiguration(options=self._options(timeout_ms))
        return {"model": int(config.model), "dof": int(config.degree_of_freedom)}

    def _speed_limits(self, *, timeout_ms: int) -> list:
        """``Base.GetAllJointsSpeedHardLimitation``: ``joint`` (identifier), ``type``
        (``Base.LimitationType`` value; 3: velocity) and ``value`` (deg/s) per entry."""
        limits = self._base.GetAllJointsSpeedHardLimitation(options=self._options(timeout_ms))
        return [{"joint": int(item.joint_identifier), "type": int(item.type),
                 "value": float(item.value)} for item in limits.joints_limitations]

    def _protection_zones(self, *, timeout_ms: int) -> list:
        """``Base.ReadAllProtectionZones``: per zone its name, ``enabled``, ``shape_type``
        (``Base.ShapeType`` value), ``origin`` (m, base frame), ``orientation`` (3x3 rows),
        ``dimensions`` (m) and ``envelope`` thickness (m)."""
        zones = self._base.ReadAllProtectionZones(options=self._options(timeout_ms))
        out = []
        for zone in zones.protection_zones:
            shape = zone.shape
            rows = (shape.orientation.row1, shape.orientation.row2, shape.orientation.row3)
            out.append({
                "name": str(zone.name), "enabled": bool(zone.is_enabled),
                "shape_type": int(shape.shape_type),
                "origin": [float(shape.origin.x), float(shape.origin.y), float(shape.origin.z)],
                "orientation": [[float(r.column1), float(r.column2), float(r.column3)] for r in rows],
                "dimensions": [float(d) for d in shape.dimensions],
                "envelope": float(shape.envelope_thickness)})
        return out

    def _soft_limits(self, *, timeout_ms: int) -> list:
        """``ControlConfig.GetAllKinematicSoftLimits``: per control mode its name
        (``ControlConfig.ControlMode``), ``joint_speed`` (deg/s per joint) and
        ``joint_acceleration`` (deg/s^2 per joint), each as the arm reports them."""
        limits = self._control.GetAllKinematicSoftLimits(options=self._options(timeout_ms))
        modes = self.api["ControlConfig_pb2"].ControlMode
        out = []
        for item in limits.kinematic_limits_list:
            try:
                name = modes.Name(item.control_mode)
            except ValueError:
                name = f"CONTROL_MODE_{int(item.control_mode)}?"
            out.append({"control_mode": name,
                        "joint_speed": [float(v) for v in item.joint_speed_limits],
                        "joint_acceleration": [float(v) for v in item.joint_acceleration_limits]})
        return out

    # ---------------------------------------------------------------- actions (--home)
    def _on_action(self, notification: Any) -> None:
        """The action topic's callback, on the vendor's thread: queue the event (never raise)."""
        try:
            try:
                name = self.api["Base_pb2"].ActionEvent.Name(notification.action_event)
            except ValueError:
                name = f"ACTION_EVENT_{int(notification.action_event)}?"
            event = {"event": name, "abort_details": int(getattr(notification, "abort_details", 0)),
                     "time": time.monotonic()}
        except Exception as error:  # noqa: BLE001 - a malformed notification is reported, not raised
            event = {"event": "UNREADABLE", "abort_details": 0, "time": time.monotonic(),
                     "error": f"{type(error).__name__}: {error}"}
        with self._events_lock:
            self._events.append(event)

    def _subscribe_actions(self, *, timeout_ms: int) -> int:
        """``Base.OnNotificationActionTopic`` (once; events queued from now on); the handle's
        identifier."""
        with self._events_lock:
            self._events.clear()
        if self._subscription is None:
            options = self.api["Base_pb2"].NotificationOptions()
            self._subscription = self._base.OnNotificationActionTopic(
                self._on_action, options, options=self._options(timeout_ms))
        return int(self._subscription.identifier)

    def _execute_joint_angles(self, *, angles: list, speed_deg_s: float, name: str,
                              timeout_ms: int) -> None:
        """``Base.ExecuteAction`` of an ``Action`` named ``name`` whose ``reach_joint_angles``
        holds ``angles`` (deg, joint identifiers 0..n-1) under a ``JOINT_CONSTRAINT_SPEED`` of
        ``speed_deg_s`` (deg/s, every joint)."""
        base_pb2 = self.api["Base_pb2"]
        action = base_pb2.Action()
        action.name = str(name)
        action.application_data = ""
        reach = action.reach_joint_angles
        for i, value in enumerate(angles):
            angle = reach.joint_angles.joint_angles.add()
            angle.joint_identifier = i
            angle.value = float(value)
        reach.constraint.type = base_pb2.JOINT_CONSTRAINT_SPEED
        reach.constraint.value = float(speed_deg_s)
        self._base.ExecuteAction(action, options=self._options(timeout_ms))

    def _action_events(self, *, timeout_ms: int) -> list:
        """The action notifications received since the last read (``event``: an
        ``Base.ActionEvent`` name, ``abort_details``, ``time``: this process's monotonic clock);
        never waits. ``timeout_ms`` is the child link's only."""
        del timeout_ms
        with self._events_lock:
            events, self._events = self._events, []
        return events

    def _unsubscribe(self, *, timeout_ms: int) -> None:
        """``Base.Unsubscribe`` of the action topic (nothing when not subscribed)."""
        handle, self._subscription = self._subscription, None
        if handle is not None:
            self._base.Unsubscribe(handle, options=self._options(timeout_ms))

    def _timed(self, *, on: bool, timeout_ms: int) -> dict:
        """The durations (s, in this process: the RPC alone) of the :data:`TIMED_METHODS` calls
        since timing was last turned on, by method; then timing on (afresh) or off."""
        del timeout_ms
        recorded = self._durations or {}
        self._durations = {method: [] for method in TIMED_METHODS} if on else None
        return recorded


# ---------------------------------------------------------------------------------------------
# The child process: one JSON line per request and per answer over stdin / stdout
# ---------------------------------------------------------------------------------------------


def _answer(channel, message: dict) -> None:
    channel.write(json.dumps(message) + "\n")
    channel.flush()


def _protobuf_version() -> str:
    """The child environment's protobuf version ('' without one; the real kortex_api needs it)."""
    try:
        from google import protobuf
    except ImportError:
        return ""
    return str(getattr(protobuf, "__version__", "?"))


def serve(read_line: Callable[[], str] | None = None, channel=None) -> int:
    """The child's loop: import ``kortex_api``, say ``ready`` (or why not), then answer each
    request ``{"method": ..., "args": {...}}`` with ``{"result": ...}`` or ``{"error": kind,
    "message": ...}``. ``{"method": "exit"}`` ends it; SIGINT is ignored (the adapter stops the
    arm through the child on Ctrl-C). When the parent goes away (end of input)
    while a session is open, the child sends ``Base.Stop`` and closes the session before it ends:
    a crashed adapter does not leave the arm moving."""
    if channel is None:  # answers go to the real stdout; anything the vendor prints, to stderr
        channel = os.fdopen(os.dup(1), "w")
        os.dup2(2, 1)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the adapter decides when to stop
    read_line = read_line or sys.stdin.readline
    link = VendorLink()
    try:
        link.import_api()
    except LinkError as error:
        _answer(channel, {"error": error.kind, "message": error.message})
        return 1
    _answer(channel, {"ready": True, "pid": os.getpid(), "python": sys.version.split()[0],
                      "protobuf": _protobuf_version()})
    while True:
        line = read_line()
        if not line:  # the parent is gone
            if link.is_open:
                for method in ("stop", "close"):
                    try:
                        link.call(method, timeout_ms=500)
                    except LinkError:
                        pass
            return 0
        try:
            request = json.loads(line)
            method, args = request["method"], dict(request.get("args", {}))
        except (ValueError, KeyError, TypeError) as error:
            _answer(channel, {"error": "other", "message": f"bad request: {error}"})
            continue
        if method == "exit":
            _answer(channel, {"result": None})
            return 0
        try:
            result = link.call(method, **args)
        except LinkError as error:
            _answer(channel, {"error": error.kind, "message": error.message})
        except TypeError as error:  # wrong arguments for the method
            _answer(channel, {"error": "other", "message": f"{method}: {error}"})
        else:
            _answer(channel, {"result": result})


if __name__ == "__main__":
    sys.exit(serve())
