"""Value types of the phase geometry: an axis-aligned box and a solid cylinder.

World frame (z up), metres. Construction checks every input and raises ValueError naming the
field and the bad value; the ``unchecked`` constructor is the per-control-step path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Box", "Cylinder", "Bounds", "ROTATION_TOL"]


ROTATION_TOL = 1e-6
"""Max |R^T R - I| entry (and |det R - 1|) accepted for a rotation matrix."""

Bounds = tuple[float, float, float, float, float, float]  # xlo, ylo, zlo, xhi, yhi, zhi


# --------------------------------------------------------------------------- validation


def _fmt_index(index: tuple[int, ...]) -> str:
    return "".join(f"[{i}]" for i in index)


def _as_array(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """Read-only float64 copy of ``value`` with the given shape (-1 = any length), all finite."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of numbers, got {value!r}") from exc
    if arr.shape != shape and not (shape[0] == -1 and arr.ndim == 2 and arr.shape[1] == shape[1]):
        want = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if not all(map(math.isfinite, arr.ravel().tolist())):
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name}{_fmt_index(index)} must be finite, got {arr[index]}")
    arr.setflags(write=False)
    return arr


def _require_positive(name: str, arr: np.ndarray) -> None:
    if arr.size and not min(arr.ravel().tolist()) > 0.0:
        index = tuple(int(i) for i in np.argwhere(~(arr > 0.0))[0])
        raise ValueError(f"{name}{_fmt_index(index)} must be > 0, got {arr[index]}")


def _as_scalar(name: str, value: object, *, positive: bool = False, nonnegative: bool = False) -> float:
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    if positive and not x > 0.0:
        raise ValueError(f"{name} must be > 0, got {x}")
    if nonnegative and not x >= 0.0:
        raise ValueError(f"{name} must be >= 0, got {x}")
    return x


def _check_rotation(name: str, rot: np.ndarray) -> None:
    (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
    # Columns must be orthonormal and right-handed: R^T R = I, det R = +1.
    err = max(
        abs(a * a + d * d + g * g - 1.0),
        abs(b * b + e * e + h * h - 1.0),
        abs(c * c + f * f + i * i - 1.0),
        abs(a * b + d * e + g * h),
        abs(a * c + d * f + g * i),
        abs(b * c + e * f + h * i),
    )
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise ValueError(
            f"{name} must be a rotation matrix (orthonormal, det +1), "
            f"got max|R^T R - I| = {err:.3g}, det = {det:.6g}"
        )


# --------------------------------------------------------------------------- value types


@dataclass(frozen=True, eq=False)
class Box:
    """Axis-aligned box in the world frame: ``center`` (3,) m, ``half_size`` (3,) m, all > 0."""

    center: np.ndarray
    half_size: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _as_array("center", self.center, (3,)))
        half = _as_array("half_size", self.half_size, (3,))
        _require_positive("half_size", half)
        object.__setattr__(self, "half_size", half)

    def bounds(self) -> Bounds:
        """(xlo, ylo, zlo, xhi, yhi, zhi) in metres, world frame."""
        cx, cy, cz = self.center.tolist()
        hx, hy, hz = self.half_size.tolist()
        return (cx - hx, cy - hy, cz - hz, cx + hx, cy + hy, cz + hz)


@dataclass(frozen=True, eq=False)
class Cylinder:
    """Solid cylinder (the pusher), world frame.

    ``center`` (3,) m; ``rotation`` (3,3) world-from-cylinder, the cylinder axis is
    its local z axis (third column); ``radius`` > 0 m; ``half_length`` > 0 m along the axis.
    """

    center: np.ndarray
    rotation: np.ndarray
    radius: float
    half_length: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _as_array("center", self.center, (3,)))
        rot = _as_array("rotation", self.rotation, (3, 3))
        _check_rotation("rotation", rot)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "radius", _as_scalar("radius", self.radius, positive=True))
        object.__setattr__(self, "half_length", _as_scalar("half_length", self.half_length, positive=True))

    @property
    def axis(self) -> np.ndarray:
        """Unit axis direction (3,) in the world frame."""
        return self.rotation[:, 2]

    @classmethod
    def unchecked(cls, center: np.ndarray, rotation: np.ndarray, radius: float, half_length: float) -> "Cylinder":
        """The per-control-step constructor, for a pose from forward kinematics (a rotation by
        construction) and sizes from a validated config: shapes and orthonormality are not checked
        (~1 us instead of ~7 us); a non-finite pose still raises ValueError."""
        center = np.array(center, dtype=np.float64)
        rotation = np.array(rotation, dtype=np.float64)
        if not math.isfinite(float(center.sum()) + float(rotation.sum())):
            raise ValueError(f"pusher pose must be finite, got centre {center.tolist()}")
        center.setflags(write=False)
        rotation.setflags(write=False)
        cyl = object.__new__(cls)
        object.__setattr__(cyl, "center", center)
        object.__setattr__(cyl, "rotation", rotation)
        object.__setattr__(cyl, "radius", float(radius))
        object.__setattr__(cyl, "half_length", float(half_length))
        return cyl
