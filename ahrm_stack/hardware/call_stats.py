"""Call durations as the link checks report them (the Gen2's and the Kortex's ``--check``)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class CallStats:
    """One call's durations, ms."""

    count: int
    p50: float
    p99: float
    max: float

    @classmethod
    def of(cls, seconds: np.ndarray) -> "CallStats":
        ms = np.asarray(seconds, dtype=float) * 1e3
        if not ms.size:
            return cls(0, float("nan"), float("nan"), float("nan"))
        p50, p99 = np.percentile(ms, [50, 99])
        return cls(int(ms.size), float(p50), float(p99), float(ms.max()))

    def __str__(self) -> str:
        return f"p50 {self.p50:.2f} / p99 {self.p99:.2f} / max {self.max:.2f} ms ({self.count} calls)"
