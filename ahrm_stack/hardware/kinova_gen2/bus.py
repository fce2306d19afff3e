"""The one thread that talks to Kinova's Gen2 SDK while an adapter is connected (:class:`UsbBus`).

Kinova's SDK handles one call at a time and each call is a USB round trip of several ms (Kinova's
support, kinova-ros issue 233: "several ms" per blocking call, the arm handles one message per
10 ms; the fake SDK takes 3 ms). The arm executes one trajectory point per 10 ms from its FIFO, so
joint velocities must reach it at 100 Hz. A control loop at 20 Hz has a 25 ms command deadline. So
every SDK call after ``connect`` goes through this thread, and it decides their order, highest
priority first:

1. **stops** (zero velocity, ``EraseAllTrajectories``; the e-stop's ``StopControlAPI``): a stop
   waits at most for the call in progress;
2. the **command watchdog**'s stop, at its deadline (no fresh command for ``command_timeout`` s
   while the standing command moves the arm; a zero command or a stop disarms it): it latches, as
   the protocol says (:class:`~ahrm_stack.hardware.protocol.ArmAdapter`): commands are refused
   (:class:`BusHeldError`) until :meth:`UsbBus.release`, and the adapter hears of it
   (``on_watchdog``), which sets ``Fault.WATCHDOG``;
3. a trajectory point that is **urgent**: the arm's FIFO would run dry if one more call went first
   (at most one such point goes ahead of a waiting caller's call);
4. the **callers' calls**, in order: the control tick's one position read, ``clear_faults``, ...;
5. a trajectory point that is **due**: the FIFO holds at most ``send_ahead`` s of motion;
6. one call of the **periodic status poll** (the adapter's steps: supply voltage, the error log,
   torques; every ``status_period`` s), when no point falls due before it would typically end, or
   regardless once the poll is :data:`STATUS_PATIENCE` s late (a loaded machine stretches every
   call: the poll must not starve; one step then holds a point back by one call, within
   ``send_ahead``).

So a caller's call waits for at most one call in progress and one urgent point, and a stop for at
most one call in progress, whatever the control thread's load: stop latency is bounded by design
(three calls, ~9 ms at 3 ms per call), not by the scheduler's luck.

**Trajectory points.** The standing command (deg/s, set by :meth:`UsbBus.command`) goes out as one
``ANGULAR_VELOCITY`` point whenever a point is due; a fresh command does not add a point of its
own, it rides the next one (the arm would execute an extra point only after the queued ones
anyway, so the delay to the joints is the same, and the FIFO never fills). The thread keeps a model
of the arm's FIFO: each point is 10 ms of motion starting when the previous one ends or when it
arrives (taken as the end of its call), whichever is later; ``EraseAllTrajectories`` empties it. A
point is due when less than ``send_ahead`` s of motion is left (so one point waits behind the one
running and a point held back by up to ``send_ahead`` s still arrives before the arm runs dry), and
never sooner than ``send_period`` after the last one when that is longer than 10 ms. Each point adds
exactly 10 ms to the FIFO and is sent only when less than ``send_ahead`` is left, so the arm
receives at most 100 points per second however late the thread runs: points never pile up.

Failures: a call that fails with a communication error (the link is gone) fails every waiting
caller and ends the thread; the adapter then closes what it can. Any other failure of the thread's
own calls (a point, the watchdog, a status step) drops the standing command, erases the FIFO (best
effort) and is kept for the adapter (:meth:`UsbBus.take_error`), which puts the arm in fault.
Callers' failures are raised to them. Every call's duration is recorded (:class:`CallTimes`).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from typing import Any, Callable, Deque, NamedTuple, Protocol, Sequence, TypeVar

import numpy as np

log = logging.getLogger("ahrm_stack.hardware.kinova_gen2")

POINT_PERIOD = 0.010  # s: the arm executes one trajectory point per 10 ms (100 Hz)
RECENT_CALLS = 16  # the estimate of one call's duration: the longest of this many recent calls
DEFAULT_CALL_ESTIMATE = 0.003  # s, before any call was timed (the fake's and Kinova's figure)
STATUS_PATIENCE = 0.05  # s a due status poll defers to the points before it goes anyway

T = TypeVar("T")


class SdkLike(Protocol):
    """What the bus needs of the SDK (:class:`ahrm_stack.hardware.kinova_gen2.sdk.Sdk`)."""

    times: "CallTimes"

    def call(self, name: str, *args: Any) -> int: ...

    def call_quietly(self, name: str, *args: Any) -> None: ...


class CallTimes:
    """Durations (s) of the SDK's calls, per function (the last ``keep`` of each), and of the last
    :data:`RECENT_CALLS` calls of any function (the bus's estimate of one call)."""

    def __init__(self, keep: int = 1 << 16) -> None:
        self.by_function: dict[str, Deque[float]] = collections.defaultdict(
            lambda: collections.deque(maxlen=keep))
        self.recent: Deque[float] = collections.deque(maxlen=RECENT_CALLS)
        self.count = 0  # calls made

    def record(self, name: str, seconds: float) -> None:
        self.by_function[name].append(seconds)
        self.recent.append(seconds)
        self.count += 1

    def estimate(self) -> float:
        """s: the longest of the recent calls (one call's duration, pessimistically)."""
        recent = list(self.recent)
        return max(recent) if recent else DEFAULT_CALL_ESTIMATE

    def typical(self) -> float:
        """s: the median of the recent calls (one call's duration, typically)."""
        recent = list(self.recent)
        return float(np.median(recent)) if recent else DEFAULT_CALL_ESTIMATE

    def of(self, name: str) -> np.ndarray:
        """The recorded durations of ``name`` (s)."""
        return np.asarray(list(self.by_function.get(name, ())), dtype=float)


def is_link_error(error: BaseException) -> bool:
    """The link to the arm is gone (an SDK error with a communication code)."""
    return bool(getattr(error, "communication", False))


@dataclasses.dataclass(frozen=True)
class WatchdogStop:
    """One stop by the command watchdog: ``deadline`` (perf_counter s) the fresh command was due
    by, ``sent_at`` when the zero command went out, ``reason``."""

    deadline: float
    sent_at: float
    reason: str


class _Job:
    """A call (or a short sequence) to run on the bus thread; the caller waits for it."""

    __slots__ = ("fn", "done", "result", "error", "queued_at", "calls_at")

    def __init__(self, fn: Callable[[Any], Any], queued_at: float, calls_at: int) -> None:
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None
        self.queued_at = queued_at  # perf_counter s
        self.calls_at = calls_at  # SDK calls made before it was queued


class JobWait(NamedTuple):
    """How long a caller's call waited on the bus: ``seconds`` from being queued to starting, and
    ``calls_ahead``, the SDK calls that ended in between (by design at most two: the one in progress
    and an urgent point; more only behind a stop or the watchdog's). A tuple of numbers, which
    Python's garbage collector stops tracking: tens of thousands of them cost the loop's collections
    nothing."""

    seconds: float
    calls_ahead: int


class BusClosedError(RuntimeError):
    """The bus thread is not running (closed, or ended by a lost link: ``__cause__``)."""


class BusHeldError(RuntimeError):
    """A command while the bus holds the arm stopped (a fault's halt, until :meth:`UsbBus.release`)."""


class UsbBus:
    """The USB-owning thread of one connected Gen2 adapter (see the module docstring).

    Args:
        sdk: the loaded SDK (its ``call`` raises an error with ``communication`` for a lost link).
        make_point: deg/s per joint -> the ``SendAdvanceTrajectory`` argument (a velocity point).
        joints: joints per point.
        send_period: s, 1 / ``kinova_gen2.send_rate_hz``: no two points closer than this when it is
            longer than the arm's 10 ms (the arm then moves proportionally slower).
        send_ahead: s of motion the FIFO holds when the next point is due (``kinova_gen2.send_ahead``).
        command_timeout: s without a fresh command before the watchdog stops the arm (while the
            standing command moves it).
        status_period: s between two status polls (1 / ``kinova_gen2.status_rate_hz``).
        status_steps: the poll's steps, each one SDK call, run on this thread in order (the
            adapter's: they may call :meth:`halt`, which then runs inline).
        name: the thread's name.
        watchdog_stops: where the watchdog's stops are recorded (the adapter's list).
        on_watchdog: called on this thread with each watchdog stop, once the arm is stopped.
    """

    def __init__(self, sdk: SdkLike, make_point: Callable[[np.ndarray], Any], joints: int,
                 send_period: float, send_ahead: float, command_timeout: float,
                 status_period: float, status_steps: Sequence[Callable[[Any], None]],
                 name: str, watchdog_stops: list[WatchdogStop] | None = None,
                 on_watchdog: Callable[[WatchdogStop], None] | None = None) -> None:
        self.sdk = sdk
        self._make_point = make_point
        self._zero = np.zeros(joints)
        self._send_period = float(send_period)
        self._ahead = float(send_ahead)
        self._timeout = float(command_timeout)
        self._status_period = float(status_period)
        self._steps = tuple(status_steps)
        self._name = name
        self._cond = threading.Condition(threading.Lock())
        self._urgent: Deque[_Job] = collections.deque()
        self._jobs: Deque[_Job] = collections.deque()
        self._thread: threading.Thread | None = None
        self._quit = False
        self._closed_by: BaseException | None = None  # the lost link that ended the thread
        self.closed_at: float | None = None  # perf_counter s when that call failed
        self._error: BaseException | None = None  # a failure of the thread's own calls
        # the standing command and the FIFO model
        self._values = np.zeros(joints)  # deg/s
        self._active = False
        self._moving = False  # the standing command is not all zeros: the watchdog is armed
        self._held = False  # a fault's halt or the watchdog's stop: commands refused until release()
        self._fresh_at = 0.0  # perf_counter s of the last fresh command
        self._fifo_end = 0.0  # perf_counter s at which the arm will have run every point sent
        self._last_point = -1e9  # perf_counter s the last point was sent
        self._next_status = 0.0
        self._step = len(self._steps)  # the next status step; == len: the poll is done
        self._jumped = False  # a point went ahead of the waiting callers' first call
        self._poll_due = 0.0  # perf_counter s the poll under way fell due
        # what happened (read by tests, benchmarks and the --check)
        self.points = 0  # SendAdvanceTrajectory calls carrying the standing command
        self.point_times: Deque[float] = collections.deque(maxlen=1 << 16)  # when each point went out
        self.watchdog_stops: list[WatchdogStop] = [] if watchdog_stops is None else watchdog_stops
        self._on_watchdog = on_watchdog
        self.status_polls = 0
        self.waits: Deque[JobWait] = collections.deque(maxlen=1 << 16)  # the callers' calls

    # ------------------------------------------------------------------ life
    def start(self, status_now: bool = False) -> None:
        """Start the thread; the first status poll after one ``status_period`` (now when
        ``status_now``)."""
        now = time.perf_counter()
        self._next_status = now if status_now else now + self._status_period
        self._fifo_end = now
        self._quit = False
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def on_thread(self) -> bool:
        """The caller is the bus thread (a status step)."""
        return threading.current_thread() is self._thread

    def close(self, timeout: float = 2.0) -> None:
        """End the thread after its current call (pending callers get :class:`BusClosedError`)."""
        with self._cond:
            self._quit = True
            self._active = False
            self._cond.notify_all()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=timeout)
        self._fail_pending(BusClosedError(f"{self._name} closed"))

    def take_error(self) -> BaseException | None:
        """The link loss that ended the thread (kept), or else a failure of the thread's own calls
        since the last take (cleared)."""
        with self._cond:
            if self._closed_by is not None:
                return self._closed_by
            error, self._error = self._error, None
            return error

    # ------------------------------------------------------------------ callers
    def call(self, fn: Callable[[Any], T], urgent: bool = False) -> T:
        """Run ``fn(sdk)`` on the bus thread (``urgent``: before everything else) and return its
        result, or raise its exception; inline when called from the bus thread itself."""
        if self.on_thread():
            return fn(self.sdk)
        with self._cond:
            job = _Job(fn, time.perf_counter(), self.sdk.times.count)
            self._check_open()
            (self._urgent if urgent else self._jobs).append(job)
            self._cond.notify_all()
        job.done.wait()
        if job.error is not None:
            raise job.error
        return job.result

    def command(self, kinova_deg_s: np.ndarray) -> None:
        """A fresh command: the standing command from now on (it rides the next point). From rest
        (no standing command) it returns once the first point carrying it has gone out."""
        with self._cond:
            self._check_open()
            if self._held:
                raise BusHeldError("the arm is held stopped (a fault); release() first")
            self._values = np.array(kinova_deg_s, dtype=float)
            self._moving = bool(np.any(self._values != 0.0))
            self._fresh_at = time.perf_counter()
            starting, self._active = not self._active, True
            mark = self.points
            self._cond.notify_all()
            if starting and not self.on_thread():
                while (self.points == mark and self._active and self._closed_by is None
                       and not self._quit):
                    self._cond.wait(0.1)

    def drop(self) -> None:
        """No standing command: no more points are sent (the FIFO runs out by itself)."""
        with self._cond:
            self._active = False
            self._cond.notify_all()

    def halt(self, then: Callable[[Any], None] | None = None, hold: bool = False) -> float:
        """Stop: no standing command, a zero-velocity point and ``EraseAllTrajectories`` (then
        ``then(sdk)``, e.g. ``StopControlAPI``), before any other call; returns when done
        (perf_counter s of the erase). ``hold``: refuse commands from now until :meth:`release`
        (a fault: no command slips in between the adapter's fault check and this stop). From the
        bus thread itself it runs inline."""
        with self._cond:
            self._active = False
            self._held = self._held or hold
        return self.call(lambda sdk: self._stop_calls(sdk, then), urgent=True)

    def release(self) -> None:
        """Commands are accepted again (the fault was cleared)."""
        with self._cond:
            self._held = False

    @property
    def standing(self) -> np.ndarray | None:
        """The standing command (deg/s), or None when stopped."""
        with self._cond:
            return self._values.copy() if self._active else None

    @property
    def fifo_end(self) -> float:
        """perf_counter s at which the arm will have run out of points (the model)."""
        return self._fifo_end

    # ------------------------------------------------------------------ the thread
    def _check_open(self) -> None:
        if self._closed_by is not None:
            raise self._closed_by
        if self._quit or self._thread is None:
            raise BusClosedError(f"{self._name} is not running")

    def _fail_pending(self, error: BaseException) -> None:
        with self._cond:
            pending = list(self._urgent) + list(self._jobs)
            self._urgent.clear()
            self._jobs.clear()
        for job in pending:
            job.error = error
            job.done.set()

    def _stop_calls(self, sdk: SdkLike, then: Callable[[Any], None] | None) -> float:
        with self._cond:
            self._active = False
        sdk.call("SendAdvanceTrajectory", self._make_point(self._zero))
        sdk.call("EraseAllTrajectories")
        erased = time.perf_counter()
        self._fifo_end = erased
        if then is not None:
            then(sdk)
        return erased

    def _point_due(self) -> float:
        due = self._fifo_end - self._ahead
        if self._send_period > POINT_PERIOD:
            due = max(due, self._last_point + self._send_period)
        return due

    def _choose(self, now: float) -> tuple[Callable[[], None] | None, float]:
        """The next action (under the lock), or None and how long to wait."""
        if self._urgent:
            job = self._urgent.popleft()
            return (lambda: self._run_job(job)), 0.0
        estimate = self.sdk.times.estimate()
        waits = [self._next_status] if self._steps and self._step >= len(self._steps) else []
        if self._active:
            deadline = self._fresh_at + self._timeout if self._moving else float("inf")
            if now >= deadline:
                self._active, self._held = False, True  # latched: no command slips in
                return (lambda: self._watchdog_stop(now, deadline)), 0.0
            due = self._point_due()
            values = self._values.copy()
            if now >= due and self._fifo_end - now < 2.0 * estimate and not (self._jobs and self._jumped):
                self._jumped = bool(self._jobs)  # at most one point goes ahead of a waiting caller
                return (lambda: self._send_point(values)), 0.0
            waits += [deadline, due]
        if self._jobs:
            job = self._jobs.popleft()
            self._jumped = False
            return (lambda: self._run_job(job)), 0.0
        if self._active and now >= due:
            return (lambda: self._send_point(values)), 0.0
        if self._steps:
            if self._step >= len(self._steps) and now >= self._next_status:
                self._step = 0
                self._poll_due = self._next_status
                self._next_status = max(self._next_status + self._status_period, now)
                self.status_polls += 1
            if self._step < len(self._steps) and (
                    not self._active or due - now > self.sdk.times.typical()
                    or now - self._poll_due > STATUS_PATIENCE):
                step, self._step = self._steps[self._step], self._step + 1
                return (lambda: self._own(step)), 0.0
        return None, (max(0.0, min(waits) - now) if waits else 1.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while True:
                    if self._quit and not self._urgent:
                        return
                    action, wait = self._choose(time.perf_counter())
                    if action is not None:
                        break
                    self._cond.wait(wait)
            try:
                action()
            except BaseException as error:  # noqa: BLE001 - a lost link ends the thread
                self.closed_at = time.perf_counter()
                self._closed_by = error
                log.error("kinova_gen2: the USB thread stopped: %s", error)
                self._fail_pending(error)
                with self._cond:
                    self._active = False
                    self._cond.notify_all()
                return

    def _run_job(self, job: _Job) -> None:
        self.waits.append(JobWait(time.perf_counter() - job.queued_at,
                                  self.sdk.times.count - job.calls_at))
        try:
            job.result = job.fn(self.sdk)
        except BaseException as error:  # noqa: BLE001 - the caller's to handle
            job.error = error
            if is_link_error(error):
                job.done.set()
                raise
        finally:
            job.done.set()

    def _own(self, action: Callable[[Any], None]) -> None:
        """One of the thread's own calls (a status step): a lost link ends the thread; another
        failure drops the command, erases the FIFO and is kept for the adapter."""
        try:
            action(self.sdk)
        except BaseException as error:  # noqa: BLE001 - kept for the adapter
            if is_link_error(error):
                raise
            self._own_failed(error)

    def _own_failed(self, error: BaseException) -> None:
        log.error("kinova_gen2: a call of the USB thread failed: %s", error)
        with self._cond:
            self._active = False
            self._error = error
            self._cond.notify_all()
        self.sdk.call_quietly("EraseAllTrajectories")
        self._fifo_end = time.perf_counter()

    def _send_point(self, values: np.ndarray) -> None:
        try:
            self.sdk.call("SendAdvanceTrajectory", self._make_point(values))
        except BaseException as error:  # noqa: BLE001 - a lost link ends the thread
            if is_link_error(error):
                raise
            self._own_failed(error)
            return
        sent = time.perf_counter()
        self._fifo_end = max(self._fifo_end, sent) + POINT_PERIOD
        self._last_point = sent
        with self._cond:
            self.points += 1
            self.point_times.append(sent)
            self._cond.notify_all()

    def _watchdog_stop(self, now: float, deadline: float) -> None:
        try:
            self.sdk.call("SendAdvanceTrajectory", self._make_point(self._zero))
            sent_at = time.perf_counter()
            self.sdk.call("EraseAllTrajectories")
        except BaseException as error:  # noqa: BLE001 - a lost link ends the thread
            if is_link_error(error):
                raise
            self._own_failed(error)
            return
        self._fifo_end = time.perf_counter()
        reason = (f"command watchdog: no fresh command for {(now - self._fresh_at) * 1e3:.1f} ms "
                  f"(timeout {self._timeout * 1e3:.0f} ms): zero velocity sent, trajectories erased")
        stop = WatchdogStop(deadline, sent_at, reason)
        self.watchdog_stops.append(stop)
        log.warning("kinova_gen2: %s", reason)
        if self._on_watchdog is not None:
            self._on_watchdog(stop)
