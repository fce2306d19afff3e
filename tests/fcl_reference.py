"""python-fcl's signed distance, a second library for the cylinder-box cross-checks of the tests.

Only for poses clear of touching: python-fcl 0.7 aborts the process (an uncaught C++
``std::logic_error``) on some exactly-touching poses, and its GJK over-estimates separated
distances (see :mod:`ahrm_stack.kinematics.cylinder_box`). Nothing in ``ahrm_stack`` imports it.
"""

from __future__ import annotations

import fcl
import numpy as np

from ahrm_stack.kinematics.shapes import Bounds, Cylinder

_FCL_REQUEST = fcl.DistanceRequest(enable_signed_distance=True)  # read-only input


def fcl_signed_distance(cyl: Cylinder, b: Bounds) -> float:
    """Raw python-fcl signed distance (m) between the cylinder and the AABB ``b`` (world frame)."""
    xlo, ylo, zlo, xhi, yhi, zhi = b
    cyl_obj = fcl.CollisionObject(
        fcl.Cylinder(cyl.radius, 2.0 * cyl.half_length),  # FCL sizes are full lengths
        fcl.Transform(cyl.rotation, cyl.center),
    )
    box_obj = fcl.CollisionObject(
        fcl.Box(xhi - xlo, yhi - ylo, zhi - zlo),
        fcl.Transform(np.array([(xlo + xhi) / 2, (ylo + yhi) / 2, (zlo + zhi) / 2])),
    )
    # A fresh result per query: python-fcl keeps a running minimum in it.
    return float(fcl.distance(cyl_obj, box_obj, _FCL_REQUEST, fcl.DistanceResult()))
