"""The deploy loop: one control period of feedback, world model, controller, safety filter and
command per :meth:`DeployLoop.tick`, and every way a run ends (its records, :class:`DeployFault`
and :class:`DeploySummary`, are in :mod:`ahrm_stack.deploy.summary`; the success confirmation
after the stop in :mod:`ahrm_stack.deploy.judging`)."""

from __future__ import annotations

import dataclasses
import gc
import json
import logging
import math
import time

import numpy as np

from ahrm_stack.deploy.contact import loop_contact_stop
from ahrm_stack.deploy.judging import (ProgressWatchdog, SuccessJudge, TouchEstimator, confirm_success,
                                      first_line)
from ahrm_stack.deploy.record import tick_record
from ahrm_stack.deploy.safety_settings import require_filter
from ahrm_stack.deploy.settings import DeploySettings, control_periods
from ahrm_stack.deploy.start_check import StartPostureError, start_refusal
from ahrm_stack.deploy.summary import DeployFault, DeploySummary
from ahrm_stack.deploy.world import WorldModel
from ahrm_stack.hardware.protocol import (ArmFaultError, CommandRefusedError, ConnectionLostError,
                               FeedbackTimeoutError, HardwareError, ServoingMode)

log = logging.getLogger("ahrm_stack.deploy")


class _Halt(Exception):
    """Internal: end the run; the arm was already stopped or e-stopped."""


class DeployLoop:
    """One deployment run on ``arm`` (a connected :class:`~ahrm_stack.hardware.protocol.ArmAdapter` with a
    ``perception()`` method), paced by the adapter's clock.

    Every way a run ends commands the arm to stop (zero velocity, or an e-stop), writes a stop
    event with its cause to the log and the telemetry, and (through :meth:`run`) the summary: the
    watchdog, hardware and contact checks (:mod:`~ahrm_stack.deploy.contact`), the progress
    watchdog, the safety filter's report, an adapter error, success (confirmed or not), the
    duration, Ctrl-C, and any exception in start-up or in a tick's stages (a *fault*: the stop
    reason names the stage, ``perception fault: ValueError: ...``; :meth:`run` then raises
    :class:`DeployFault`). A controller request that is not finite (NaN from a policy) is a fault
    too, never a silent zero.

    How the run went is judged from perception alone (:mod:`~ahrm_stack.deploy.judging`): success
    is the cube perceived past a table edge by ``settings.success.edge_margin`` for
    ``sustain_ticks`` ticks, then, after the stop, not perceived back on the table for
    ``confirm_time`` s (else the stop reason says ``success not confirmed``); a cube that vanishes
    from perception once perceived off the table (a perception error that is not the adapter's)
    counts as gone off it. An obstacle perceived displaced counts as touched (the summary's
    ``touched`` fields, each tick's ``touched`` flag, a ``touch`` event). A run without task
    progress for ``settings.progress.timeout`` s is stopped by the progress watchdog.

    Args:
        arm: the adapter; its ``clock`` paces the loop and stamps the feedback.
        world: the :class:`WorldModel` of the deployed task.
        controller: a :class:`ScriptedController` or :class:`PolicyController`.
        safety: the ``safety`` config; the loop turns the obstacle rows on.
        settings: the deploy settings (rate, watchdog).
        telemetry: an open text file for the JSONL log, or None.
        scene: where perception comes from: a scene source (``poses()`` -> ObjectPoses, e.g.
            :mod:`ahrm_stack.perception`'s camera scene), or None for the adapter's
            ``perception()``. An exception from it is a perception fault (the arm stops).
    """

    def _perceive(self):
        """This tick's object poses: the scene source's, or the adapter's ``perception()`` (looked
        up at each call)."""
        if self._scene_source is not None:
            return self._scene_source.poses()
        return self.arm.perception()

    def __init__(self, arm, world: WorldModel, controller, safety, settings: DeploySettings,
                 telemetry=None, scene=None) -> None:
        from ahrm_stack.env.control_step import filter_call, make_task_filter, request_size
        from ahrm_stack.safety import InterventionStats

        require_filter(safety)
        self.arm, self.world, self.controller = arm, world, controller
        self._scene_source = scene
        self.settings = settings
        self.period = settings.period
        self.clock = arm.clock
        self.telemetry = telemetry
        task = world.task
        robot = task.robot
        self._lower, self._upper = robot.position_lower, robot.position_upper
        self._speed_alarm = robot.velocity_limit * (1.0 + settings.watchdog.velocity_tolerance)
        self._over_speed = np.zeros(robot.num_joints, dtype=int)  # consecutive readings over it
        self.scene = world.make_collision_scene()
        self.filter = make_task_filter(task, dataclasses.replace(safety, obstacle_rows=True),
                                       scene=self.scene, control_period=self.period)
        # a Cartesian request (tip velocity, m/s) goes through the same QP as differential IK
        cartesian = getattr(controller, "cartesian", False)
        self._solve = filter_call(self.filter, cartesian)
        self._request_size = request_size(robot, cartesian)
        self.stats = InterventionStats()
        self.latencies: list[float] = []  # s, feedback received -> command sent
        self.deadline_misses = 0
        self.emergency_stops = 0
        self.adapter_refusals = 0
        self.success = False
        self.stop_reason = ""
        self.fault = ""  # the stop reason when a software fault stopped the run
        self.error: BaseException | None = None  # the exception behind the fault, if any
        self.stopped_at: float | None = None  # clock time the arm was stopped / e-stopped
        self.tick_time: float | None = None  # clock time the current (or last) tick began
        self.halted = False
        self.interrupted = False
        self._sent = np.zeros(robot.num_joints)
        self._last_frame = -1
        self._ticks = 0
        self._t0 = 0.0
        self._started = False
        self._stage = "start-up"
        self.success_judge = SuccessJudge(settings.success, task.config.table)
        self.touch = TouchEstimator(settings.touch)
        self.progress = ProgressWatchdog(settings.progress)
        self.contact = loop_contact_stop(arm, world, settings.contact, robot.name, self.period)

    # ------------------------------------------------------------------ helpers
    def _write(self, record: dict) -> None:
        """A telemetry line; a failing log never stops the stop logic (the error is logged)."""
        if self.telemetry is None:
            return
        try:
            self.telemetry.write(json.dumps(record) + "\n")
        except (OSError, ValueError) as error:  # disk full, a closed file
            log.error("deploy: telemetry write failed (%s: %s)", type(error).__name__, error)

    def _event(self, level: int, kind: str, message: str, **fields) -> None:
        log.log(level, "deploy: %s: %s", kind.upper(), message)
        self._write({"t": round(self.clock.now() - self._t0, 6), "event": kind, "reason": message,
                     **fields})

    def _halt(self, reason: str, emergency: bool, level: int = logging.WARNING) -> None:
        """Stop (or e-stop) the arm, log why (``level``; e-stops at ERROR), end the run."""
        self.stop_reason = reason
        self._command_stop(emergency)
        self._event(logging.ERROR if emergency else level,
                    "emergency stop" if emergency else "stop", reason)
        raise _Halt(reason)

    def _command_stop(self, emergency: bool) -> None:
        """Stop (or e-stop) the arm now; the run is halted (:attr:`stopped_at` stamped)."""
        self.halted = True
        self._sent = np.zeros_like(self._sent)
        try:
            if emergency:
                self.arm.apply_emergency_stop()
                self.emergency_stops += 1
            else:
                self.arm.stop()
        except Exception as error:  # e.g. the link is gone: the arm's own watchdog stops it
            log.error("deploy: could not %s the arm (%s)", "e-stop" if emergency else "stop",
                      type(error).__name__)
            if emergency:  # a plain stop is the next best command
                try:
                    self.arm.stop()
                except Exception:  # noqa: BLE001 - nothing more to try from here
                    pass
        self.stopped_at = self.clock.now()

    def _judge_success(self, lost: str = "") -> None:
        """The cube was perceived off the table for ``success.sustain_ticks`` ticks, or (``lost``:
        the perception error) perceived off and then gone from view: stop the arm, confirm it from
        perception after the stop (:func:`~ahrm_stack.deploy.judging.confirm_success`), record the
        judgement and end the run."""
        judge = self.success_judge
        if not self.halted:
            self.stop_reason = "success judgement: confirming after the stop"
        self._command_stop(emergency=False)
        stopped = self.stopped_at if self.stopped_at is not None else self.clock.now()
        check = confirm_success(judge, self._perceive, self.clock, stopped, self.period, lost)
        confirmed, message = check.confirmed, check.message
        self._event(logging.INFO if confirmed else logging.WARNING, "success judgement", message,
                    cube=[round(float(v), 6) for v in judge.seen[:3]], sustained_ticks=judge.streak,
                    stopped_t=round(stopped - self._t0, 6), confirm_time=judge.settings.confirm_time,
                    confirmation_reads=[[round(float(v), 6) for v in p] for p in check.reads],
                    gone_from_view=check.gone, confirmed=confirmed)
        self.success = confirmed
        self.stop_reason = f"success: {message}" if confirmed else f"success not confirmed: {message}"
        self._event(logging.INFO if confirmed else logging.WARNING, "stop", self.stop_reason)
        raise _Halt(self.stop_reason)

    def _stop_on_fault(self, error: BaseException | None, reason: str) -> None:
        """Record a software fault (``reason``; ``error`` the exception, if any), stop the arm."""
        self.fault = reason
        self.error = error
        try:
            self._halt(reason, emergency=False, level=logging.ERROR)
        except _Halt:
            pass

    def _fault_reason(self, error: BaseException) -> str:
        text = (str(error).splitlines() or [""])[0][:300]
        return f"{self._stage} fault: {type(error).__name__}" + (f": {text}" if text else "")

    def _check_feedback(self, feedback) -> None:
        age = self.clock.now() - feedback.timestamp
        max_age = self.settings.watchdog.max_feedback_age * self.period
        if feedback.frame_id <= self._last_frame or age > max_age:
            self._halt(f"watchdog: stale feedback (frame {feedback.frame_id}, age "
                       f"{age * 1e3:.1f} ms > {max_age * 1e3:.1f} ms)", emergency=False)
        self._last_frame = feedback.frame_id
        for name, values in (("position", feedback.position), ("velocity", feedback.velocity),
                             ("torque", feedback.torque)):
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                self._halt(f"non-finite feedback: {name}[{bad[0]}] = {values[bad[0]]}",
                           emergency=True)
        if not feedback.healthy:
            self._halt(f"arm fault: state {feedback.arm_state.value}, flags {feedback.faults!r}",
                       emergency=True)
        if contact := self.contact.observe(feedback.position, feedback.velocity, feedback.torque):
            self._halt(contact, emergency=True)
        past = np.flatnonzero((feedback.position < self._lower) | (feedback.position > self._upper))
        if past.size:
            i = past[0]
            self._halt(f"limit violation: joint {i} at {feedback.position[i]:.4f} rad, outside "
                       f"[{self._lower[i]:.4f}, {self._upper[i]:.4f}]", emergency=True)
        # a joint over the alarm speed on velocity_alarm_ticks consecutive readings: a runaway
        # persists, a noisy reading (a real JACO2's velocity feedback) does not
        over = np.abs(feedback.velocity) > self._speed_alarm
        self._over_speed = np.where(over, self._over_speed + 1, 0)
        fast = np.flatnonzero(self._over_speed >= self.settings.watchdog.velocity_alarm_ticks)
        if fast.size:
            i = fast[0]
            self._halt(f"limit violation: joint {i} moving at {feedback.velocity[i]:.3f} rad/s, "
                       f"alarm at {self._speed_alarm[i]:.3f} rad/s on {self._over_speed[i]} "
                       "consecutive readings", emergency=True)

    def _check_request(self, u_nom) -> np.ndarray:
        """The controller's request as a float vector; a wrong size or a non-finite entry (NaN
        from a policy) is a controller fault: the arm stops and the run ends."""
        try:
            request = np.asarray(u_nom, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            request = None
        if request is None or request.size != self._request_size:
            reason = (f"controller fault: request {u_nom!r:.80} is not {self._request_size} "
                      "numbers")
            self._stop_on_fault(None, reason)
            raise _Halt(reason)
        bad = np.flatnonzero(~np.isfinite(request))
        if bad.size:
            reason = (f"controller fault: non-finite request u_nom[{bad[0]}] = {request[bad[0]]} "
                      f"({bad.size} of {request.size} entries)")
            self._stop_on_fault(None, reason)
            raise _Halt(reason)
        return request

    def _deadline(self, tick_time: float, where: str) -> None:
        late = self.clock.now() - (tick_time + self.settings.watchdog.command_deadline * self.period)
        if late > 0:
            self.deadline_misses += 1
            message = f"missed deadline {where} by {late * 1e3:.2f} ms"
            if self.deadline_misses > self.settings.watchdog.max_deadline_misses:
                self._halt(f"watchdog: {message}", emergency=False)
            self._event(logging.WARNING, "deadline", message)

    @property
    def next_tick_time(self) -> float:
        """Clock time (s) at which the next :meth:`tick` begins."""
        return self._t0 + self._ticks * self.period

    # ------------------------------------------------------------------ the loop
    def start(self) -> None:
        """Synchronise with the arm: first feedback, a check that the arm starts near the posture
        the policy was trained from (:class:`StartPostureError` otherwise, nothing moved), plan,
        warm the controller and filter (so their first-call costs do not hit a deadline), then
        schedule tick 0 at the clock's now."""
        self._stage = "start-up"
        self._t0 = self.clock.now()
        if self.arm.servoing_mode != ServoingMode.SINGLE_LEVEL_SERVOING:
            self.arm.set_servoing_mode(ServoingMode.SINGLE_LEVEL_SERVOING)
        self.arm.stop()
        feedback = self.arm.refresh_feedback()
        start = self.settings.start_posture
        refusal = start_refusal(self.world, feedback.position, math.radians(start.joint_tolerance_deg),
                                start.region_margin, math.radians(start.tilt_tolerance_deg))
        if refusal is not None:
            raise StartPostureError(refusal)
        self._last_frame = feedback.frame_id - 1
        self._t0 = self.clock.now()
        self.contact.reset()
        self.world.begin_run()
        self.world.update(feedback, self._perceive(), 0.0)
        self.controller.reset()
        self.world.place_objects(self.scene)
        request = np.asarray(self.controller(), dtype=float).reshape(-1)
        if request.size != self._request_size:
            raise ValueError(f"the controller's request has {request.size} entries, not "
                             f"{self._request_size}")
        if not np.isfinite(request).all():  # never sent: each tick checks its own request
            log.warning("deploy: the controller's warm-up request is not finite: %s", request)
            request = np.zeros_like(request)
        self._solve(feedback.position, feedback.velocity, request, u_prev=self._sent)
        self.filter.reset()
        self.controller.reset()
        self._sent = np.zeros_like(self._sent)
        self._t0 = self.clock.now()
        getattr(self.telemetry, "start_run", lambda t0: None)(self._t0)  # a RunLog: frames are timed from t0
        self._started = True

    def resume(self) -> None:
        """Continue after a halt (the caller cleared the arm's faults / reconnected it)."""
        self.halted = False
        self.stop_reason = ""
        self.fault = ""
        self.error = None
        self._over_speed[:] = 0
        self.contact.reset()
        self._sent = np.zeros_like(self._sent)
        self.filter.reset()
        feedback = self.arm.refresh_feedback()
        self._last_frame = feedback.frame_id - 1
        self._ticks = int(math.ceil((self.clock.now() - self._t0) / self.period))
        self.success_judge.reset()
        self.progress.restart(self._ticks * self.period)

    def tick(self) -> bool:
        """One control period; False when the run ended (success, a halt or a fault: the arm is
        then stopped and the stop recorded). Never raises but for Ctrl-C (KeyboardInterrupt)."""
        tick_time = self._t0 + self._ticks * self.period
        self.clock.sleep_until(tick_time)
        self.tick_time = tick_time
        self._ticks += 1
        try:
            self._stage = "feedback"
            try:
                feedback = self.arm.refresh_feedback()
            except FeedbackTimeoutError:
                self._halt("watchdog: feedback dropped (no frame in time)", emergency=False)
            except ConnectionLostError:
                self._halt("connection lost: the arm's own watchdog stops it", emergency=False)
            received = time.perf_counter()
            self._check_feedback(feedback)
            self._stage = "perception"
            try:
                poses = self._perceive()
            except Exception as error:  # noqa: BLE001 - re-raised: a perception or adapter fault
                if not self.success_judge.streak or isinstance(error, HardwareError):
                    raise
                self._judge_success(lost=first_line(error))  # perceived off, then gone from view
            if not poses.finite:
                self._halt("non-finite perception (object poses)", emergency=False)
            elapsed = tick_time - self._t0
            info = self.world.update(feedback, poses, elapsed)
            self._stage = "judging"
            for touch in self.touch.observe(elapsed, poses.obstacle_positions):
                self._event(logging.WARNING, "touch",
                            f"obstacle {touch.obstacle} perceived {touch.displacement * 1e3:.1f} mm "
                            "from its start position: touched", obstacle=touch.obstacle,
                            displacement=round(touch.displacement, 6), first=touch is self.touch.touches[0])
            if self.success_judge.observe(poses.cube_position):
                self._judge_success()
            stalled = self.progress.observe(elapsed, info.progress, info.phase)
            if stalled:
                self._halt(stalled, emergency=False)
            self._stage = "controller"
            u_nom = self._check_request(self.controller())
            self._stage = "safety filter"
            self.world.place_objects(self.scene)
            result = self._solve(feedback.position, feedback.velocity, u_nom, u_prev=self._sent)
            self.stats.add(result)
            if result.violated:
                self._halt(f"safety filter reports violated constraints {list(result.violated)}",
                           emergency=True)
            self._deadline(tick_time, "before the command")
            self._stage = "command"
            try:
                sent = self.arm.send_joint_speeds(result.command)
            except CommandRefusedError as error:
                self.adapter_refusals += 1
                self.emergency_stops += 1
                self._halt(f"adapter refused the command and e-stopped: {error}", emergency=False)
            except ArmFaultError as error:
                self._halt(f"arm in fault: {error}", emergency=True)
            except ConnectionLostError:
                self._halt("connection lost: the arm's own watchdog stops it", emergency=False)
            latency, sent_at = time.perf_counter() - received, self.clock.now()
            self.latencies.append(latency)
            self._sent = sent
            self._deadline(tick_time, "sending the command")
            self._stage = "telemetry"
            self.world.record_command(sent)
            self._write(tick_record(elapsed, self._t0, info, self.controller.stage, feedback, poses, u_nom,
                                    sent, sent_at, result, self.touch.touched, latency,
                                    getattr(self._scene_source, "frame", None)))
            return True
        except _Halt:
            return False
        except HardwareError as error:  # anything else from the adapter: stop, never continue
            try:
                self._halt(f"adapter error {type(error).__name__}: {error}", emergency=True)
            except _Halt:
                return False
        except Exception as error:  # noqa: BLE001 - a crash in a stage: stop, record, end the run
            self._stop_on_fault(error, self._fault_reason(error))
            return False

    def run(self, duration: float) -> DeploySummary:
        """Tick until success, a halt or ``duration`` s, then stop the arm; the summary is the
        telemetry's last line. Ctrl-C (SIGINT) stops the arm too, sets :attr:`interrupted` and
        returns the summary. A software fault (start-up, a stage's exception, a NaN request)
        raises :class:`DeployFault` once the arm is stopped and the summary written; any other
        exception escaping the loop (e.g. SystemExit) stops the arm, is recorded, and propagates.

        Python's garbage collector, a realtime loop's usual outlier, runs between ticks: the set-up's
        objects frozen (``gc.freeze``), automatic collection off, and after each tick's command the
        generation the interpreter would have collected is (:meth:`_collect_garbage`); both are
        restored when the run ends (not when automatic collection was already off)."""
        ticks = control_periods(duration, self.period)
        collecting = gc.isenabled()
        thaw = collecting and gc.get_freeze_count() == 0  # else another freeze is not ours to undo
        try:
            return self._run(ticks, duration, collecting)
        finally:
            if collecting:
                if thaw:
                    gc.unfreeze()
                gc.enable()

    @staticmethod
    def _collect_garbage() -> None:
        """The collection Python's automatic collector would make at its next allocation (the
        oldest generation whose count passed its threshold), made between ticks instead."""
        counts, thresholds = gc.get_count(), gc.get_threshold()
        for generation in (2, 1, 0):
            if thresholds[generation] and counts[generation] > thresholds[generation]:
                gc.collect(generation)
                return

    def _run(self, ticks: int, duration: float, collecting: bool) -> DeploySummary:
        try:
            if collecting:  # inside the try: Ctrl-C here stops the arm too
                # No collection first: a full one takes ~0.5-2 s with torch and MuJoCo loaded;
                # what is garbage now is collectable again after the run (unfreeze).
                gc.freeze()
                gc.disable()
            if not self._started:
                try:
                    self.start()
                except HardwareError as error:
                    self._stage = "start-up"
                    self._stop_on_fault(error, f"start-up fault: adapter error "
                                               f"{type(error).__name__}: {error}")
                except Exception as error:  # noqa: BLE001 - perception, controller, filter
                    self._stop_on_fault(error, self._fault_reason(error))
            while not self.halted and self._ticks < ticks and self.tick():
                if collecting:
                    self._collect_garbage()
            if not self.halted:
                try:
                    self._halt(f"duration of {duration:g} s reached", emergency=False,
                               level=logging.INFO)
                except _Halt:
                    pass
        except KeyboardInterrupt:
            self.interrupted = True
            try:
                self._halt("interrupted (Ctrl-C / SIGINT / SIGTERM)", emergency=False)
            except _Halt:
                pass
        except BaseException as error:  # SystemExit, MemoryError, a bug in the loop itself
            if not self.halted:
                self._stop_on_fault(error, self._fault_reason(error))
            self._finish()
            raise
        summary = self._finish()
        if self.fault:
            raise DeployFault(self.fault, summary) from self.error
        return summary

    def _finish(self) -> DeploySummary:
        summary = self.summary()
        self._write({"summary": dataclasses.asdict(summary)})
        if self.telemetry is not None:
            try:
                self.telemetry.flush()
            except (OSError, ValueError):
                pass
        return summary

    def summary(self) -> DeploySummary:
        latencies = np.asarray(self.latencies) * 1e3
        p50, p99 = (np.percentile(latencies, [50, 99]) if latencies.size else (math.nan, math.nan))
        return DeploySummary(
            success=self.success, duration=self._ticks * self.period, ticks=self._ticks,
            interventions=self.stats.interventions, fallbacks=self.stats.fallbacks,
            deadline_misses=self.deadline_misses, latency_p50_ms=float(p50),
            latency_p99_ms=float(p99), stop_reason=self.stop_reason,
            emergency_stops=self.emergency_stops, adapter_refusals=self.adapter_refusals,
            fault=self.fault, touched=self.touch.touched, touched_obstacles=self.touch.obstacles,
            first_touch_time=self.touch.first_time)
