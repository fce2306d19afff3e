"""The Kortex adapter: :class:`KortexArm`, a Gen3-family arm behind the link to ``kortex_api``.

The adapter holds the protocol's state (servoing mode, e-stop and fault latches, the command
watchdog, feedback freshness) and talks to the arm through a link with one method, ``call``, in
plain values: :class:`~ahrm_stack.hardware.kortex.child_link.ChildLink` (``kortex_api`` in a process of its
own; the default) or :class:`~ahrm_stack.hardware.kortex.vendor_link.VendorLink` in this process (tests pass
a fake API). See the package docstring (:mod:`ahrm_stack.hardware.kortex`) for the safety of the link.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.hardware.kortex.arm_model import describe_arm, model_refusal, soft_limit_refusal
from ahrm_stack.hardware.kortex.child_link import ChildLink
from ahrm_stack.hardware.kortex.codec import feedback_from_values, joint_speeds_message, servoing_mode_name
from ahrm_stack.hardware.kortex.credentials import Credentials, scrub
from ahrm_stack.hardware.kortex.freshness import FrameFreshness, fingerprint
from ahrm_stack.hardware.kortex.moves import KortexMoves
from ahrm_stack.hardware.kortex.settings import KortexOptions
from ahrm_stack.hardware.kortex.vendor_link import INSTALL_HINT, LinkError, VendorLink
from ahrm_stack.hardware.kortex.watchdog import CommandWatchdog
from ahrm_stack.hardware.kortex.zones import ProtectionZone, zone_report, zones_in_workspace
from ahrm_stack.hardware.protocol import (ArmFaultError, ArmState, ConnectionLostError, DescribedArm, Fault,
                               Feedback, FeedbackTimeoutError, HardwareError, NotConnectedError,
                               ServoingMode, WallClock, range_centres)

log = logging.getLogger("ahrm_stack.hardware.kortex")


class KortexNotInstalledError(HardwareError):
    """The vendor library ``kortex_api`` is missing; the message says how to install it."""


class KortexArm(KortexMoves, DescribedArm):
    """A Gen3-family arm over ``kortex_api`` (TCP transport, router, session, BaseClient,
    BaseCyclicClient).

    Args:
        robot: the arm model the controller was trained on; the arm's model, DoF and joint speed
            limits must match it (:func:`~ahrm_stack.hardware.kortex.arm_model.model_refusal`).
        address: the arm's IP address, required (no default is ever contacted).
        credentials: the login (:func:`~ahrm_stack.hardware.kortex.credentials.load_credentials`).
        options: every number of the link (:class:`~ahrm_stack.hardware.kortex.settings.KortexOptions`).
        api: vendor modules to use in this process (tests pass fakes); default: ``kortex_api`` in
            a child process under ``options.python``.
        clock: the adapter's clock (default :class:`WallClock`: real time); the watchdog and the
            feedback stamps use it. Tests pass a ``FastClock`` shared with a fake arm.
        workspace: the task workspace in the arm's base frame (m; rows x, y, z; columns min, max),
            checked against the arm's protection zones on connect (None: zones reported only).
        child_path: folders for the child's ``PYTHONPATH`` (tests: the fake ``kortex_api``).
        acceleration_limit: the policy's joint acceleration limits (rad/s^2: the safety filter's
            ``safety.acceleration_limit``), checked against the arm's acceleration soft limits
            where it reports them (None: not checked).
    """

    @property
    def torque_every_frame(self) -> bool:
        """``kortex.contact_torques``: BaseCyclic gives each actuator's torque with every frame, but
        their zero and sign against the arm's model are unmeasured on an arm, so the deploy loop's
        contact stop uses them only when told to (off by default; issue 58 item 4)."""
        return self._options.contact_torques

    def __init__(self, robot: RobotDescription, address: str, credentials: Credentials,
                 options: KortexOptions, *, api: dict | None = None,
                 clock: WallClock | None = None, workspace: np.ndarray | None = None,
                 child_path: Sequence[str | Path] = (),
                 acceleration_limit: Sequence[float] | np.ndarray | None = None) -> None:
        if not isinstance(address, str) or not address.strip():
            raise HardwareError("the Kortex backend needs the arm's address explicitly "
                                f"(got {address!r}); there is no default")
        self._robot = robot
        self._address, self._options = address.strip(), options
        self._port = int(options.port)
        self._credentials = credentials
        self._api = api
        self._child_path = tuple(child_path)
        self._link: Any = None
        self._clock = clock if clock is not None else WallClock()
        self._workspace = None if workspace is None else np.asarray(workspace, dtype=float)
        self._acceleration_limit = (None if acceleration_limit is None
                                    else np.asarray(acceleration_limit, dtype=float))
        self._connected = False
        self._mode = ServoingMode.SINGLE_LEVEL_SERVOING
        self._wanted_mode = ServoingMode.SINGLE_LEVEL_SERVOING  # what clear_faults restores
        self._previous: np.ndarray | None = None
        self._freshness = FrameFreshness()
        self._faults = Fault.NONE  # the adapter's own flags (e-stop, refusal); latched until
        self._fault_reason = ""  # clear_faults(), carried by every frame
        self._arm_in_fault = False  # the last feedback (or a refused RPC) reported a fault
        self._arm_faults = Fault.NONE  # that feedback's flags
        self._watchdog_reason = ""  # why the command watchdog stopped the arm (Fault.WATCHDOG)
        self._watchdog = CommandWatchdog(options.watchdog_timeout, options.watchdog_poll,
                                         self._watchdog_expired, clock=self._clock.now)
        self._range_centre = range_centres(robot)
        self.protection_zones: list[ProtectionZone] = []
        self.soft_limits: list[dict] = []  # ControlConfig's kinematic soft limits, once connected
        self.arm_description = ""  # the arm's model and DoF, once connected
        self.lost_reason = ""  # why the link was given up, '' while it holds

    @property
    def watchdog(self) -> CommandWatchdog:
        """The command watchdog (its :attr:`~CommandWatchdog.trips` count stops it made)."""
        return self._watchdog

    @property
    def freshness(self) -> FrameFreshness:
        """Feedback ids and stamps (:attr:`~FrameFreshness.repeats`: repeated frames seen)."""
        return self._freshness

    @property
    def link(self) -> Any:
        """The link in use (None before :meth:`connect`)."""
        return self._link

    def _secret_free(self, text: str) -> str:
        return scrub(text, [self._credentials.password])

    def _require(self) -> None:
        if not self._connected:
            raise NotConnectedError(f"KortexArm({self._address}) is not connected; call connect()")

    # ------------------------------------------------------------------ calls
    def _make_link(self) -> Any:
        if self._api is not None:
            return VendorLink(self._api)
        options = self._options
        return ChildLink(options.python, start_timeout_ms=options.process_start_timeout_ms,
                         margin_ms=options.process_margin_ms, path=self._child_path)

    def _call(self, what: str, method: str, timeout_ms: int, **args: Any) -> Any:
        """``method`` over the link with an explicit ``timeout_ms``; a failure becomes a scrubbed
        :class:`HardwareError` (timeout: :class:`FeedbackTimeoutError`; the arm in fault:
        :class:`ArmFaultError`; the link or its process: :class:`ConnectionLostError`, after
        :meth:`_lose`), raised outside the handler so nothing that may echo a secret is chained."""
        try:
            return self._link.call(method, timeout_ms=int(timeout_ms), **args)
        except LinkError as error:
            kind, message = error.kind, self._secret_free(error.message)
        if kind == "timeout":
            raise FeedbackTimeoutError(f"{what}: no answer within {timeout_ms} ms ({message})")
        if kind == "fault":
            self._arm_in_fault, self._arm_faults = True, self._arm_faults | Fault.HARDWARE
            raise ArmFaultError(f"{what}: the arm refused it in fault ({message}); "
                                "clear_faults() first")
        if kind in ("connection", "dead"):
            self._lose(f"{what}: {message}", process_dead=kind == "dead")
            raise ConnectionLostError(f"{what}: {message}")
        if kind == "not_installed":
            raise KortexNotInstalledError(message)
        raise HardwareError(f"{what}: {message}")

    def _rpc(self, what: str, method: str, **args: Any) -> Any:
        return self._call(what, method, self._options.rpc_timeout_ms, **args)

    def _lose(self, why: str, *, process_dead: bool) -> None:
        """The link dropped: send ``Base.Stop`` (best effort, ``lost_link_stop_timeout_ms``), then
        close the session and the link, and record why (:attr:`lost_reason`, the log). With the
        kortex_api process gone no Stop can be sent: the arm's own connection inactivity timeout
        is then the only guard."""
        self._connected = False
        self._watchdog.close()
        self.lost_reason = why
        timeout = self._options.lost_link_stop_timeout_ms
        log.error("kortex: LINK LOST (%s)", why)
        if process_dead:
            log.error("kortex: the kortex_api process is gone: no Stop can be sent; the arm's own "
                      "connection_inactivity_timeout (%d ms) is the only guard",
                      self._options.connection_inactivity_timeout_ms)
        else:
            for method in ("stop", "close"):
                try:
                    self._link.call(method, timeout_ms=timeout)
                except LinkError as error:
                    log.error("kortex: %s after the lost link failed: %s", method,
                              self._secret_free(error.message))
                else:
                    log.info("kortex: %s after the lost link went through", method)
        self._link.shutdown()

    # ------------------------------------------------------------------ session
    def connect(self) -> None:
        """Open the session, read the arm's model, DoF, joint speed hard limits, kinematic soft
        limits and protection zones, refuse an arm that is not the trained one, whose soft limits
        are below the policy's (:func:`~ahrm_stack.hardware.kortex.arm_model.soft_limit_refusal`)
        or whose zones reach into the task workspace (per ``kortex.refuse_zones_in_workspace``),
        then single-level servoing and Stop."""
        if self._connected:
            raise HardwareError(f"KortexArm({self._address}) is already connected")
        options = self._options
        self._link = self._make_link()
        failure = None
        try:
            self._link.call("open", address=self._address, port=self._port,
                            username=self._credentials.username,
                            password=self._credentials.password,
                            session_inactivity_timeout_ms=options.session_inactivity_timeout_ms,
                            connection_inactivity_timeout_ms=options.connection_inactivity_timeout_ms,
                            timeout_ms=options.session_rpc_timeout_ms)
        except LinkError as error:  # the vendor's errors may echo the request: scrub them
            failure, kind = self._secret_free(error.message), error.kind
        if failure is not None:  # raised outside the handler: no chained vendor exception
            self._link.shutdown()
            if kind == "not_installed":
                raise KortexNotInstalledError(failure)
            log.error("kortex: connecting to %s:%d failed: %s", self._address, self._port, failure)
            raise HardwareError(f"connecting to the arm at {self._address}:{self._port} failed: "
                                f"{failure}")
        self._connected = True
        self.lost_reason = ""
        self._freshness = FrameFreshness()
        self._previous = None
        where = f"{self._address}"
        slow = options.session_rpc_timeout_ms
        try:  # a failure from here on closes the session it opened (scrubbed, like every call)
            first = self._rpc("RefreshFeedback", "feedback")
            product = self._call("GetProductConfiguration", "product", slow)
            limits = self._call("GetAllJointsSpeedHardLimitation", "speed_limits", slow)
            refusal = model_refusal(self._robot, product, limits, options.models,
                                    tolerance=options.speed_limit_tolerance,
                                    actuators=len(first["position"]), where=where)
            if refusal is not None:
                raise HardwareError(refusal)
            self.arm_description = describe_arm(product)
            self.soft_limits = self._call("GetAllKinematicSoftLimits", "soft_limits", slow)
            refusal = soft_limit_refusal(self._robot, self.soft_limits, options.soft_limit_modes,
                                         tolerance=options.soft_limit_tolerance, where=where,
                                         arm=self.arm_description,
                                         acceleration_limit=self._acceleration_limit)
            if refusal is not None:
                raise HardwareError(refusal)
            zones = self._call("ReadAllProtectionZones", "protection_zones", slow)
            self.protection_zones = [ProtectionZone.from_values(z) for z in zones]
            log.info("kortex: %s: %s", where, zone_report(self.protection_zones))
            self._check_zones(where)
            self.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
            self.stop()
        except HardwareError:
            self.disconnect()
            raise
        self._watchdog.disarm()  # its thread starts with the first moving command
        hello = getattr(self._link, "hello", {})
        if hello:
            log.info("kortex: kortex_api runs in process %s (%s, python %s, protobuf %s)",
                     hello.get("pid"), getattr(self._link, "python", "?"), hello.get("python"),
                     hello.get("protobuf") or "none")
        log.info("kortex: connected to %s:%d (%s) as %s", self._address, self._port,
                 self.arm_description, self._credentials.username)

    def _check_zones(self, where: str) -> None:
        if self._workspace is None:
            return
        inside = zones_in_workspace(self.protection_zones, self._workspace)
        if not inside:
            return
        names = ", ".join(repr(z.name) for z in inside)
        box = "; ".join(f"{lo:.2f}..{hi:.2f}" for lo, hi in self._workspace)
        text = (f"the arm at {where} has protection zone(s) {names} reaching into the task "
                f"workspace (base frame x; y; z: {box} m)")
        if self._options.refuse_zones_in_workspace:
            raise HardwareError(text + ": the arm would stop inside the task (configs/deploy.yaml "
                                "kortex.refuse_zones_in_workspace)")
        log.warning("kortex: %s", text)

    @property
    def zone_summary(self) -> str:
        """One line for the deploy summary: the arm and its protection zones."""
        return f"kortex arm: {self.arm_description or 'not connected'}; {zone_report(self.protection_zones)}"

    def disconnect(self) -> None:
        self._watchdog.close()
        if not self._connected:
            return
        self._connected = False
        timeout = self._options.session_rpc_timeout_ms
        try:
            self._link.call("stop", timeout_ms=self._options.rpc_timeout_ms)
        except LinkError as error:
            log.error("kortex: stop on disconnect failed: %s", self._secret_free(error.message))
        try:
            self._link.call("close", timeout_ms=timeout)
        except LinkError as error:
            log.error("kortex: closing the session failed: %s", self._secret_free(error.message))
        self._link.shutdown()

    # ------------------------------------------------------------------ protocol
    def refresh_feedback(self) -> Feedback:
        """The arm's latest frame, stamped when its request was sent (adapter clock); a frame
        equal to the previous one in every analogue reading keeps that one's id and stamp
        (:mod:`ahrm_stack.hardware.kortex.freshness`); its flags: the arm's and the adapter's own (the
        e-stop, a refused command, the command watchdog: ``Fault.WATCHDOG``)."""
        frame = self._arm_frame()
        own = self._faults | (Fault.WATCHDOG if self._watchdog.tripped else Fault.NONE)
        return dataclasses.replace(frame, faults=frame.faults | own)

    def _arm_frame(self) -> Feedback:
        """The arm's frame, its flags the arm's only."""
        self._require()
        sent = self._clock.now()
        raw = self._rpc("RefreshFeedback", "feedback")
        frame_id, stamp = self._freshness.update(fingerprint(raw), sent)
        frame = feedback_from_values(
            timestamp=stamp, frame_id=frame_id,
            positions_deg=raw["position"], velocities_deg_s=raw["velocity"],
            torques_nm=raw["torque"], arm_state_name=raw["state"],
            base_bank_a=raw["base_fault_a"], base_bank_b=raw["base_fault_b"],
            actuator_banks=raw["actuator_faults"],
            reference=self._previous, continuous=~self._robot.limited,
            range_centre=self._range_centre)
        self._arm_in_fault = frame.arm_state == ArmState.IN_FAULT or frame.faults != Fault.NONE
        self._arm_faults = frame.faults
        if np.isfinite(frame.position).all():
            self._previous = frame.position
        return frame

    def _fault_state(self) -> tuple[Fault, str]:
        faults, reason = self._faults, self._fault_reason
        if self._watchdog.tripped:
            faults |= Fault.WATCHDOG
            reason = reason or self._watchdog_reason or "command watchdog: the arm was stopped"
        if self._arm_in_fault:
            faults |= self._arm_faults or Fault.HARDWARE
            reason = reason or "reported by the arm's feedback"
        return faults, reason

    def _add_fault(self, flag: Fault, reason: str) -> None:
        self._faults |= flag
        self._fault_reason = reason

    def _send(self, command: np.ndarray) -> np.ndarray:
        """Send a command that passed the gate, through the command watchdog."""
        moving = bool(np.any(command != 0.0))
        if moving:
            self._watchdog.start()  # a no-op once running
        if not self._watchdog.commanded(moving):
            raise ArmFaultError("the command watchdog stopped the arm (no command came in "
                                f"{self._options.watchdog_timeout * 1e3:.0f} ms): clear_faults() first")
        self._rpc("SendJointSpeedsCommand", "joint_speeds", speeds=joint_speeds_message(command))
        if self._watchdog.tripped:  # it fired while this command was on its way: stop again
            self._rpc("Stop", "stop")
            raise ArmFaultError("the command watchdog stopped the arm while a command was sent: "
                                "clear_faults() first")
        return command

    def _watchdog_expired(self, age: float) -> None:
        """From the watchdog thread: no fresh command for ``age`` s; stop the arm (Base.Stop,
        else zero joint speeds)."""
        self._watchdog_reason = (f"command watchdog: no command for {age * 1e3:.1f} ms (timeout "
                                 f"{self._options.watchdog_timeout * 1e3:.0f} ms): the arm was stopped")
        log.error("kortex: WATCHDOG: no command for %.1f ms (limit %.1f ms): stopping the arm",
                  age * 1e3, self._options.watchdog_timeout * 1e3)
        if not self._connected:
            return
        try:
            self._rpc("Stop", "stop")
            return
        except HardwareError as error:
            log.error("kortex: watchdog Stop failed (%s); sending zero joint speeds", error)
        if self._connected:
            self._rpc("SendJointSpeedsCommand", "joint_speeds",
                      speeds=joint_speeds_message(np.zeros(self._robot.num_joints)))

    def link_timing(self, on: bool) -> dict:
        """The durations (s) of the feedback and joint speed RPCs measured in the ``kortex_api``
        process since timing was last turned on (the RPC alone, without the pipe), by link
        method; then timing on afresh, or off (``--check``)."""
        self._require()
        return dict(self._rpc("link timing", "timed", on=bool(on)))

    def stop(self) -> None:
        self._require()
        self._rpc("Stop", "stop")
        self._watchdog.disarm()  # only once the stop got through

    def apply_emergency_stop(self) -> None:
        self._require()
        self._add_fault(Fault.EMERGENCY_STOP, "emergency stop applied")
        self._rpc("ApplyEmergencyStop", "emergency_stop")
        self._watchdog.disarm()

    def clear_faults(self) -> None:
        """ros2_kortex's reset: single-level servoing, ``ApplyEmergencyStop``
        (``reset_estop_repeats`` times: once proved unreliable there), ``ClearFaults``; then poll
        feedback every ``reset_poll`` s until the arm has left fault (:class:`ArmFaultError` after
        ``reset_wait`` s), restore the servoing mode, stop. Clears the e-stop and watchdog
        latches."""
        self._require()
        options = self._options
        self._set_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
        for _ in range(options.reset_estop_repeats):
            self._rpc("ApplyEmergencyStop", "emergency_stop")
        self._rpc("ClearFaults", "clear_faults")
        deadline = self._clock.now() + options.reset_wait
        while True:
            frame = self._arm_frame()
            arm_faults = frame.faults
            if frame.arm_state != ArmState.IN_FAULT and arm_faults == Fault.NONE:
                break
            if self._clock.now() >= deadline:
                raise ArmFaultError(f"clear_faults: the arm is still in fault after "
                                    f"{options.reset_wait * 1e3:.0f} ms (state "
                                    f"{frame.arm_state.value}, flags {arm_faults!r})")
            self._clock.sleep(options.reset_poll)
        self._faults, self._fault_reason = Fault.NONE, ""
        self._arm_in_fault, self._arm_faults = False, Fault.NONE
        self._watchdog.reset()
        if self._wanted_mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            self._set_mode(self._wanted_mode)
        self.stop()

    def set_servoing_mode(self, mode: ServoingMode) -> None:
        self._require()
        self._set_mode(mode)
        self._wanted_mode = ServoingMode(mode)

    def _set_mode(self, mode: ServoingMode) -> None:
        self._rpc("SetServoingMode", "set_servoing_mode", mode=servoing_mode_name(mode))
        self._watchdog.disarm()  # the arm stops when the mode changes
        self._mode = ServoingMode(mode)


__all__ = ["INSTALL_HINT", "KortexArm", "KortexNotInstalledError"]
