"""The command watchdog: Kortex joint-speed commands never expire on the arm
(``JointSpeed.duration`` is not implemented; Kinovarobotics/ros_kortex issues 159 and 347), so a
client that stops sending leaves the arm moving; this thread of the adapter stops it. It latches, as
the protocol's command watchdog does (:class:`~ahrm_stack.hardware.protocol.ArmAdapter`): the adapter reports
a tripped watchdog as ``Fault.WATCHDOG`` and its command gate refuses until ``clear_faults()``."""

from __future__ import annotations

import logging
import threading
import time
import types
import weakref

log = logging.getLogger("ahrm_stack.hardware.kortex")


class CommandWatchdog:
    """Stops the arm when commands stop coming (Kortex joint speeds never expire on the arm).

    :meth:`commanded` records each command (and whether it moves the arm). A daemon thread calls
    :meth:`check` every ``poll`` s: when the last moving command is older than ``timeout`` s it
    calls ``on_expire(age)`` once (age in s) and latches :attr:`tripped` until :meth:`reset`; a
    tripped watchdog refuses further commands (:meth:`commanded` returns False).

    Args:
        timeout: s without a fresh command before the arm is stopped.
        poll: s between two checks.
        on_expire: called from the watchdog thread with the command's age (s); sends the stop.
            A bound method is held weakly: the thread ends when its object is gone (an adapter
            dropped without :meth:`close` leaves no thread behind).
        clock: seconds, monotonic (``time.perf_counter``; tests pass their own).
    """

    def __init__(self, timeout: float, poll: float, on_expire, clock=time.perf_counter) -> None:
        if not (timeout > 0 and 0 < poll <= timeout):
            raise ValueError(f"CommandWatchdog needs 0 < poll <= timeout, got {poll!r}, {timeout!r}")
        self.timeout, self.poll = float(timeout), float(poll)
        self._on_expire = (weakref.WeakMethod(on_expire) if isinstance(on_expire, types.MethodType)
                           else (lambda: on_expire))
        self._clock = clock
        self._lock = threading.Lock()
        self._last: float | None = None
        self._armed = False
        self.tripped = False
        self.trips = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the checking thread (a no-op when it runs)."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="kortex-command-watchdog",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the checking thread (it is a no-op when called from that thread)."""
        self._stop.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=max(1.0, 10 * self.poll))
        self._thread = None

    def commanded(self, moving: bool) -> bool:
        """A command is about to be sent (``moving``: any non-zero speed). False when tripped:
        the command must not be sent."""
        with self._lock:
            if self.tripped:
                return False
            self._last = self._clock()
            self._armed = bool(moving)
            return True

    def disarm(self) -> None:
        """The arm was stopped: nothing to watch until the next moving command."""
        with self._lock:
            self._armed = False

    def reset(self) -> None:
        """Leave the tripped state (after the arm's faults were cleared)."""
        with self._lock:
            self.tripped = False
            self._armed = False

    def check(self) -> bool:
        """One check; True when it tripped now (``on_expire`` was called)."""
        with self._lock:
            if not self._armed or self._last is None:
                return False
            age = self._clock() - self._last
            if age <= self.timeout:
                return False
            self._armed = False
            self.tripped = True
            self.trips += 1
        on_expire = self._on_expire()
        if on_expire is not None:
            on_expire(age)
        return True

    def _run(self) -> None:
        while not self._stop.wait(self.poll):
            if self._on_expire() is None:  # the adapter is gone
                return
            try:
                self.check()
            except Exception:  # noqa: BLE001 - the thread must survive a failing stop
                log.exception("kortex: the command watchdog's stop failed")

