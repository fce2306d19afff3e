"""Protection zones: the arm's own keep-out volumes, read on connect, reported, and checked
against the task workspace.

``Base.ReadAllProtectionZones`` returns each zone's shape (Kinovarobotics/Kinova-kortex2_Gen3_G3L,
api_python/doc/markdown/messages/Base/ZoneShape.md): a ``shape_type`` (``Base.ShapeType``:
1 cylinder, 2 sphere, 3 rectangular prism), an ``origin`` (m) and ``orientation`` in the arm's
base frame, ``dimensions`` (m: prism x, y, z; cylinder radius, height; sphere radius) and an
``envelope_thickness`` (m) around it. The reference does not say whether a prism's or cylinder's
origin is its centre or a corner / its base, so each zone is bounded by a sphere about its origin
that holds it either way (the sphere's radius, the envelope added; prism: its full diagonal;
cylinder: sqrt(radius² + height²)): the check may refuse a zone that only comes near the
workspace, never pass one that reaches into it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping, Sequence

import numpy as np

SHAPES = {1: "cylinder", 2: "sphere", 3: "rectangular prism"}


@dataclasses.dataclass(frozen=True)
class ProtectionZone:
    """One zone, in the arm's base frame (m)."""

    name: str
    enabled: bool
    shape: str  # one of SHAPES' values, or 'unspecified'
    origin: tuple[float, float, float]
    dimensions: tuple[float, ...]
    envelope: float

    @classmethod
    def from_values(cls, values: Mapping) -> "ProtectionZone":
        """From the plain values of :meth:`ahrm_stack.hardware.kortex.vendor_link.VendorLink.call`
        ``("protection_zones")``."""
        return cls(name=str(values["name"]), enabled=bool(values["enabled"]),
                   shape=SHAPES.get(int(values["shape_type"]), "unspecified"),
                   origin=tuple(float(v) for v in values["origin"]),  # type: ignore[arg-type]
                   dimensions=tuple(float(v) for v in values["dimensions"]),
                   envelope=float(values["envelope"]))

    @property
    def bounding_radius(self) -> float:
        """m: a sphere about :attr:`origin` holding the zone and its envelope (inf when the shape
        or its dimensions are unknown)."""
        d = self.dimensions
        if self.shape == "sphere" and len(d) >= 1:
            reach = abs(d[0])
        elif self.shape == "cylinder" and len(d) >= 2:
            reach = math.hypot(d[0], d[1])
        elif self.shape == "rectangular prism" and len(d) >= 3:
            reach = math.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        else:
            return math.inf
        return reach + abs(self.envelope)

    def describe(self) -> str:
        dims = ", ".join(f"{v:.3f}" for v in self.dimensions)
        state = "enabled" if self.enabled else "disabled"
        return (f"{self.name!r} ({state} {self.shape}, origin ({self.origin[0]:.3f}, "
                f"{self.origin[1]:.3f}, {self.origin[2]:.3f}) m, dimensions [{dims}] m, envelope "
                f"{self.envelope:.3f} m)")


def box_distance(point: Sequence[float], box: np.ndarray) -> float:
    """m from ``point`` to the axis-aligned ``box`` (rows: x, y, z; columns: min, max); 0 inside."""
    p = np.asarray(point, dtype=float)
    nearest = np.clip(p, box[:, 0], box[:, 1])
    return float(np.linalg.norm(p - nearest))


def zones_in_workspace(zones: Sequence[ProtectionZone], box: np.ndarray) -> list[ProtectionZone]:
    """The enabled zones whose bounding sphere reaches into ``box`` (base frame, m)."""
    return [z for z in zones if z.enabled and box_distance(z.origin, box) <= z.bounding_radius]


def task_workspace(task, height: float) -> np.ndarray:
    """The task workspace in the arm's base frame (m; rows x, y, z; columns min, max): the table
    top (``task.table``: ``half_extent`` about the origin, ``height``) up to ``height`` m above
    it, seen from the arm base (``task.arm.base_position``, ``base_yaw_deg`` about z); the
    axis-aligned box around that box's corners."""
    hx, hy = task.table.half_extent
    top = task.table.height
    corners = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (top, top + height)])
    yaw = math.radians(task.arm.base_yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    world_to_base = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    local = (corners - np.asarray(task.arm.base_position, dtype=float)) @ world_to_base.T
    return np.stack([local.min(axis=0), local.max(axis=0)], axis=1)


def zone_report(zones: Sequence[ProtectionZone]) -> str:
    """One line: how many zones, each described."""
    if not zones:
        return "protection zones: none"
    return f"protection zones ({len(zones)}): " + "; ".join(z.describe() for z in zones)
