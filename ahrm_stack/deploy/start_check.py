"""Does the arm start where the policy was trained to start? (:func:`start_refusal`)

A policy has only seen episodes that begin from ``task.arm.start``: ``home``, every joint within
``task.arm.joint_jitter`` (rad) of ``task.arm.home_deg``; ``random``, the pusher tip at a point of
``task.arm.start_region`` (m, world frame) with the pusher pointing straight down (IK from the
jittered home). A simulated arm starts there by construction; a real one starts wherever it was
left. Before the first command :meth:`~ahrm_stack.deploy.DeployLoop.start` compares the first
feedback with that start, widened by ``deploy.start_posture``'s tolerances, and refuses in one line
(:class:`StartPostureError`) naming the joint, or the tip's coordinate or tilt, that is off and
what to do. Nothing has moved then: the loop stopped the arm before reading it.
"""

from __future__ import annotations

import numpy as np


class StartPostureError(RuntimeError):
    """The arm is not near the posture the policy was trained from; one line, nothing moved."""


ADVICE = ("move the arm there first (a Gen2 arm: python -m ahrm_stack.deploy --backend kinova-gen2 "
          "--home; else the joystick), then run again; or deploy a policy trained from this start")


def _wrapped(delta: np.ndarray, continuous: np.ndarray) -> np.ndarray:
    """Joint differences (rad), continuous joints' taken the short way round."""
    return np.where(continuous, np.angle(np.exp(1j * delta)), delta)


def start_refusal(world, q: np.ndarray, joint_tolerance: float, region_margin: float,
                  tilt_tolerance: float) -> str | None:
    """Why the arm at ``q`` (rad) is not near the trained start of ``world``'s task (a
    :class:`~ahrm_stack.deploy.WorldModel`), or None when it is. ``joint_tolerance``: rad beyond
    ``task.arm.joint_jitter`` (start: home); ``region_margin``: m the start region is grown by and
    ``tilt_tolerance``: rad of the pusher axis from straight down (start: random)."""
    arm = world.task.config.arm
    robot = world.robot
    q = np.asarray(q, dtype=float)
    if arm.start == "home":
        home = np.asarray(arm.home, dtype=float)
        off = np.abs(_wrapped(q - home, ~robot.limited))
        allowed = arm.joint_jitter + joint_tolerance
        bad = np.flatnonzero(off > allowed)
        if not bad.size:
            return None
        i = int(bad[np.argmax(off[bad])])
        return (f"the arm does not start near the posture the policy was trained from (task.arm.start: "
                f"home): joint {i} ({robot.joint_names[i]}) at {np.degrees(q[i]):.1f} deg is "
                f"{np.degrees(off[i]):.1f} deg from task.arm.home_deg's {np.degrees(home[i]):.1f} "
                f"(allowed {np.degrees(allowed):.1f}: joint_jitter + deploy.start_posture."
                f"joint_tolerance_deg); {ADVICE}")
    tip, axis = world.tip_pose(q)
    region = np.asarray(arm.start_region, dtype=float)
    lo, hi = region[:, 0] - region_margin, region[:, 1] + region_margin
    where = ", ".join(f"{v:.3f}" for v in tip)
    for k, name in enumerate("xyz"):
        if not lo[k] <= tip[k] <= hi[k]:
            return (f"the arm does not start near the posture the policy was trained from "
                    f"(task.arm.start: random): the pusher tip at ({where}) m has {name} outside "
                    f"task.arm.start_region's [{region[k, 0]:g}, {region[k, 1]:g}] m grown by "
                    f"deploy.start_posture.region_margin {region_margin:g} m; {ADVICE}")
    tilt = float(np.arccos(np.clip(-axis[2] / max(np.linalg.norm(axis), 1e-12), -1.0, 1.0)))
    if tilt > tilt_tolerance:
        return (f"the arm does not start near the posture the policy was trained from "
                f"(task.arm.start: random): the pusher points {np.degrees(tilt):.1f} deg from straight "
                f"down (allowed {np.degrees(tilt_tolerance):g}: deploy.start_posture.tilt_tolerance_deg); "
                f"{ADVICE}")
    return None
