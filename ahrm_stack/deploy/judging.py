"""How a deploy run went, judged only from what a real deployment sees (perception and the world
model's measure of the task), never from the simulator: success (:class:`SuccessJudge`), touching
(:class:`TouchEstimator`) and task progress (:class:`ProgressWatchdog`). Each is fed once per
control tick by :class:`~ahrm_stack.deploy.loop.DeployLoop`; the settings are ``configs/deploy.yaml``'s
``success``, ``touch`` and ``progress`` sections; a success is confirmed from perception after
the stop (:func:`confirm_success`). Positions in m, world frame; times in s of loop time."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from ahrm_stack.config import TableConfig
from ahrm_stack.deploy.settings import ProgressSettings, SuccessSettings, TouchSettings
from ahrm_stack.hardware.protocol import HardwareError


class SuccessJudge:
    """Success from the perceived cube position: the cube centre past a table edge by
    ``edge_margin`` (or below the table top by it) for ``sustain_ticks`` consecutive ticks. A
    single noisy reading near the edge (the task's own test, ``|x| > half extent``) never counts.
    The loop then stops the arm and re-reads perception for ``confirm_time`` s: the success stands
    unless a read has the cube back on the table (:meth:`off_table` false). A cube that vanishes
    from perception (a camera's tag turned away as the cube tips over the edge) after it was
    perceived off the table, during the streak or the confirmation, counts as gone off the
    table."""

    def __init__(self, settings: SuccessSettings, table: TableConfig) -> None:
        self.settings = settings
        self._half = np.asarray(table.half_extent, dtype=float)
        self._top = float(table.height)
        self.streak = 0  # consecutive ticks the cube was perceived off the table, up to now
        self.seen = np.full(3, np.nan)  # the last cube position perceived off the table

    def off_table(self, position) -> bool:
        """Whether a perceived cube centre (x, y, z) is past a table edge by the margin, or below the
        table top by it."""
        margin = self.settings.edge_margin
        x, y, z = (float(v) for v in position[:3])
        return bool(abs(x) - self._half[0] > margin or abs(y) - self._half[1] > margin
                    or z < self._top - margin)

    def observe(self, position) -> bool:
        """One tick's perceived cube centre; True once it was off the table ``sustain_ticks``
        ticks in a row."""
        off = self.off_table(position)
        self.streak = self.streak + 1 if off else 0
        if off:
            self.seen = np.asarray(position, dtype=float)[:3].copy()
        return self.streak >= self.settings.sustain_ticks

    def reset(self) -> None:
        self.streak = 0


@dataclasses.dataclass
class Touch:
    """An obstacle estimated touched: its index, the loop time of the tick that confirmed it, and
    its perceived horizontal displacement then (m)."""

    obstacle: int
    time: float
    displacement: float


class TouchEstimator:
    """Touching estimated from the perceived obstacle positions (a real deployment sees no
    contacts). An obstacle's start position is the median of its perceived positions over the
    first ``reference_ticks`` ticks; from then on it counts as touched once its perceived
    horizontal position is more than ``displacement`` from there for ``sustain_ticks`` ticks in a
    row (so a few mm of perception noise does not fire it). An obstacle nudged less than
    ``displacement`` is not seen."""

    def __init__(self, settings: TouchSettings) -> None:
        self.settings = settings
        self._samples: list[np.ndarray] = []
        self.reference: np.ndarray | None = None  # (k, 2) start positions, once known
        self._streak: np.ndarray | None = None
        self.touches: list[Touch] = []

    @property
    def touched(self) -> bool:
        return bool(self.touches)

    @property
    def obstacles(self) -> list[int]:
        """Indices of the obstacles touched, in the order of their first touch."""
        return [t.obstacle for t in self.touches]

    @property
    def first_time(self) -> float | None:
        """Loop time (s) of the first touch, or None."""
        return self.touches[0].time if self.touches else None

    def observe(self, elapsed: float, obstacle_positions) -> list[Touch]:
        """One tick's perceived obstacle positions ((k, 3), m); the obstacles newly touched."""
        xy = np.asarray(obstacle_positions, dtype=float)[:, :2]
        if self.reference is None:
            self._samples.append(xy.copy())
            if len(self._samples) >= self.settings.reference_ticks:
                self.reference = np.median(np.stack(self._samples), axis=0)
                self._streak = np.zeros(len(xy), dtype=int)
                self._samples = []
            return []
        assert self._streak is not None
        moved = np.hypot(*(xy - self.reference).T)
        self._streak = np.where(moved > self.settings.displacement, self._streak + 1, 0)
        known = set(self.obstacles)
        new = [Touch(int(i), elapsed, float(moved[i]))
               for i in np.flatnonzero(self._streak >= self.settings.sustain_ticks) if int(i) not in known]
        self.touches.extend(new)
        return new


class ProgressWatchdog:
    """Stops a run that makes no task progress. The measure is the task's own
    (:func:`~ahrm_stack.env.rewards.progress`: the cube's distance from the table centre minus the
    tip-cube distance, m, as the world model measures it from perception). Progress is made when
    it exceeds its value at the last progress by more than ``epsilon`` (slow steady progress
    counts; noise around a plateau does not). A phase change alone is not progress: an arm
    sagging under gravity at zero command crosses a phase boundary too. :meth:`observe` gives the
    stop reason once ``timeout`` s passed without progress (never with ``timeout`` 0)."""

    def __init__(self, settings: ProgressSettings) -> None:
        self.settings = settings
        self.anchor = -np.inf  # m, the measure at the last progress
        self.progress_time = 0.0  # loop time of the last progress
        self.best = -np.inf  # m, the best measure so far, and when it was seen
        self.best_time = 0.0
        self.phase = 0  # the highest phase reached (reported)

    def restart(self, elapsed: float) -> None:
        """Count the time without progress from ``elapsed`` (after a resumed halt)."""
        self.progress_time = elapsed

    def observe(self, elapsed: float, progress: float, phase: int) -> str | None:
        """One tick's progress measure (m) and phase (reported in the reason); the stop reason when
        the run has stalled."""
        if progress > self.anchor + self.settings.epsilon:
            self.anchor, self.progress_time = progress, elapsed
        if progress > self.best:
            self.best, self.best_time = progress, elapsed
        self.phase = max(self.phase, phase)
        timeout = self.settings.timeout
        if timeout > 0 and elapsed - self.progress_time >= timeout - 1e-9:
            return (f"watchdog: no task progress for {timeout:.1f} s (best progress {self.best:.3f} m "
                    f"at t={self.best_time:.2f} s, highest phase {self.phase})")
        return None


def first_line(error: BaseException) -> str:
    """``Type: first line of the message`` (at most 200 characters of it)."""
    text = (str(error).splitlines() or [""])[0][:200]
    return type(error).__name__ + (f": {text}" if text else "")


@dataclasses.dataclass(frozen=True)
class SuccessConfirmation:
    """What perception showed after a success's stop (:func:`confirm_success`)."""

    confirmed: bool  # no read had the cube back on the table
    message: str  # what was perceived, for the stop reason and the log
    reads: list[np.ndarray]  # the cube centres read after the stop, (3,) each, m, world frame
    gone: str  # why the cube counted as gone from view (a perception error), or ''


def confirm_success(judge: SuccessJudge, perceive: Callable[[], Any], clock: Any, stopped: float,
                    period: float, lost: str = "") -> SuccessConfirmation:
    """Confirm a success that ``judge`` saw (the arm stopped at clock time ``stopped``, s): re-read
    ``perceive()`` (object poses) every ``period`` s for ``success.confirm_time`` s (``clock``
    sleeps between reads; none when ``lost``, the perception error of a cube perceived off the
    table and then gone from view). It is a success unless a read perceives the cube back on the
    table; a read that fails (an exception other than the adapter's
    :class:`~ahrm_stack.hardware.protocol.HardwareError`, which propagates; a non-finite position: a camera's
    tag fallen out of view) ends the confirmation as the cube gone."""
    seen = judge.seen
    wait = judge.settings.confirm_time
    count = 0 if lost else max(1, math.ceil(wait / period - 1e-9))
    reads: list[np.ndarray] = []
    gone = lost
    for k in range(1, count + 1):
        clock.sleep_until(stopped + min(k * period, wait))
        try:
            poses = perceive()
        except HardwareError:  # the adapter's: handled as in a tick
            raise
        except Exception as error:  # noqa: BLE001 - e.g. the tag out of view once fallen
            gone = first_line(error)
            break
        if not np.isfinite(poses.cube_position).all():
            gone = "non-finite cube position"
            break
        reads.append(np.asarray(poses.cube_position, dtype=float)[:3].copy())
    back = next((i for i, p in enumerate(reads) if not judge.off_table(p)), None)
    confirmed = back is None
    where = ", ".join(f"{v:.3f}" for v in seen[:3])
    message = (f"the cube was perceived off the table at ({where}) m for {judge.streak} "
               f"tick{'s' * (judge.streak != 1)}")
    if not confirmed:
        assert back is not None
        at = ", ".join(f"{v:.3f}" for v in reads[back])
        message += (f", but back on the table at ({at}) m "
                    f"{min((back + 1) * period, wait):.2f} s after the stop")
    elif lost:
        message += f", then gone from view ({lost})"
    elif gone and not reads:
        message += f", then gone from view at the first read after the stop ({gone})"
    elif gone:
        message += (f", still off in {len(reads)} read{'s' * (len(reads) != 1)} after the stop, "
                    f"then gone from view ({gone})")
    else:
        message += f", still off {wait:g} s after the stop ({len(reads)} reads)"
    return SuccessConfirmation(confirmed, message, reads, gone)
