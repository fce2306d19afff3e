"""What a deploy run reports when it ends: :class:`DeploySummary` (the telemetry's last line and
``deploy``'s printout) and :class:`DeployFault`, raised with it when a software fault stopped the
run. Times in s of loop time, latencies in ms."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass
class DeploySummary:
    success: bool  # the cube perceived off the table, sustained, and still off after the stop
    duration: float  # s of loop time
    ticks: int
    interventions: int  # ticks whose command the safety filter modified
    fallbacks: int
    deadline_misses: int
    latency_p50_ms: float  # feedback received -> command sent
    latency_p99_ms: float
    stop_reason: str
    emergency_stops: int
    adapter_refusals: int
    fault: str = ""  # the software fault that stopped the run (exception, NaN request), or ''
    # touching estimated from perception (deploy.touch): an obstacle perceived displaced
    touched: bool = False
    touched_obstacles: list[int] = dataclasses.field(default_factory=list)  # in order of touch
    first_touch_time: float | None = None  # s of loop time, None when nothing was touched

    def __str__(self) -> str:
        touched = (f"touched {self.touched} (obstacles {self.touched_obstacles}, first at "
                   f"{self.first_touch_time:.2f} s)" if self.touched and self.first_touch_time is not None
                   else f"touched {self.touched}")
        return (f"deploy summary: success {self.success} | {touched} | duration {self.duration:.2f} s | "
                f"ticks {self.ticks} | interventions {self.interventions} | fallbacks "
                f"{self.fallbacks} | deadline misses {self.deadline_misses} | latency p50 "
                f"{self.latency_p50_ms:.3f} ms p99 {self.latency_p99_ms:.3f} ms | e-stops "
                f"{self.emergency_stops} | stop: {self.stop_reason}")


class DeployFault(RuntimeError):
    """A software fault stopped the run: an exception in start-up, perception, the world model,
    the controller, the safety filter or the loop itself, or a non-finite controller request. The
    arm was commanded to zero velocity and the stop and the summary were recorded before this is
    raised. ``summary`` is the run's :class:`DeploySummary`; ``__cause__`` the original exception
    (None for a NaN request)."""

    def __init__(self, message: str, summary: DeploySummary) -> None:
        super().__init__(message)
        self.summary = summary
