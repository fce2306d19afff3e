"""Is the arm on the link the arm the policy was trained on?

The arm reports its model and degrees of freedom (``Base.GetProductConfiguration``:
``CompleteProductConfiguration.model``, a ``ProductConfiguration.ModelId``, and
``degree_of_freedom``) and its joint speed hard limits (``Base.GetAllJointsSpeedHardLimitation``,
deg/s); Kinovarobotics/Kinova-kortex2_Gen3_G3L, api_python/doc/markdown/summary_pages/Base.md,
enums/ProductConfiguration/ModelId.md. A robot description (``ahrm_stack/robot.py``,
``task.robot``) is a Kortex arm only where ``configs/deploy.yaml`` ``kortex.models`` says which
(model, DoF) it is: no JACO Gen2 description is one, whatever its joint count.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ahrm_stack.robot import RobotDescription
from ahrm_stack.hardware.kortex.settings import KortexModel

#: ``ProductConfiguration.ModelId`` values (enums/ProductConfiguration/ModelId.md).
MODEL_IDS = {0: "MODEL_ID_UNSPECIFIED", 1: "MODEL_ID_L53", 2: "MODEL_ID_L31", 3: "MODEL_ID_HDK"}
MODEL_TITLES = {"MODEL_ID_L53": "Gen3", "MODEL_ID_L31": "PICO", "MODEL_ID_HDK": "HDK",
                "MODEL_ID_UNSPECIFIED": "unspecified model"}


def model_name(model_id: int) -> str:
    """A ``ModelId`` value -> its name (``MODEL_ID_?`` for an unknown value)."""
    return MODEL_IDS.get(int(model_id), f"MODEL_ID_{int(model_id)}?")


def describe_arm(product: Mapping) -> str:
    """``MODEL_ID_L53 (Gen3), 7 DoF`` from the plain ``product`` answer."""
    name = model_name(product["model"])
    return f"{name} ({MODEL_TITLES.get(name, 'unknown model')}), {int(product['dof'])} DoF"


def model_refusal(robot: RobotDescription, product: Mapping, speed_limits: Sequence[Mapping],
                  models: Mapping[str, KortexModel], *, tolerance: float, actuators: int,
                  where: str) -> str | None:
    """Why the arm at ``where`` is not the arm ``robot`` describes, as one line naming both; None
    when it is.

    Args:
        robot: the description the policy was trained on.
        product: ``{"model": ModelId value, "dof": int}`` (the arm's product configuration).
        speed_limits: entries ``{"joint", "type", "value"}`` (deg/s) of the hard limits.
        models: ``kortex.models``: description name -> the Kortex arm it is.
        tolerance: fraction the description's velocity limit may exceed the arm's hard limit.
        actuators: actuators in the arm's feedback.
        where: the arm's address, for the message.
    """
    arm = describe_arm(product)
    ours = f"the policy's robot {robot.name!r} ({robot.num_joints} joints)"
    expected = models.get(robot.name)
    if expected is None:
        return (f"the arm at {where} is a {arm}; {ours} is not a Kortex arm (configs/deploy.yaml "
                f"kortex.models has no entry for {robot.name!r}): the trained arm model must match "
                "the arm")
    if model_name(product["model"]) != expected.model or int(product["dof"]) != expected.dof:
        return (f"the arm at {where} is a {arm}; {ours} is a {expected.model} with {expected.dof} "
                "DoF (kortex.models): the trained arm model must match the arm")
    if actuators != robot.num_joints or int(product["dof"]) != robot.num_joints:
        return (f"the arm at {where} has {actuators} actuators ({arm}); {ours}: the trained arm "
                "model must match the arm")
    # Every entry of GetAllJointsSpeedHardLimitation is a speed limit (``type`` is
    # Base.LimitationType VELOCITY_LIMITATION, 3, there; not filtered on, so that an unset type cannot hide a limit).
    velocity = {int(e["joint"]): float(e["value"]) for e in speed_limits}
    ours_deg = np.degrees(robot.velocity_limit)
    for i, (name, limit) in enumerate(zip(robot.joint_names, ours_deg)):
        # Joint identifiers are 0-based as in Base.JointSpeed (api_python/examples/102-*/04-*).
        hard = velocity.get(i)
        if hard is None:
            return (f"the arm at {where} ({arm}) reports no speed hard limit for joint {i}; {ours} "
                    f"needs {limit:.1f} deg/s on {name}")
        if limit > hard * (1.0 + tolerance):
            return (f"the arm at {where} ({arm}) allows joint {i} at most {hard:.1f} deg/s; {ours} "
                    f"was trained with {limit:.1f} deg/s on {name} (kortex.speed_limit_tolerance "
                    f"{tolerance:g}): the trained arm model must match the arm")
    return None


def _lowest(soft_limits: Sequence[Mapping], modes: Sequence[str], field: str, joint: int,
            ) -> tuple[float, str] | None:
    """The lowest ``field`` soft limit of ``joint`` over ``modes`` and its mode (None: a mode lacks
    it)."""
    by_mode = {str(entry["control_mode"]): entry for entry in soft_limits}
    found = []
    for mode in modes:
        values = by_mode[mode][field]
        if joint >= len(values):
            return None
        found.append((float(values[joint]), mode))
    return min(found)


def soft_limit_refusal(robot: RobotDescription, soft_limits: Sequence[Mapping], modes: Sequence[str],
                       *, tolerance: float, where: str, arm: str,
                       acceleration_limit: np.ndarray | None = None) -> str | None:
    """Why the arm's soft limits (``ControlConfig.GetAllKinematicSoftLimits``) do not allow the
    policy's, as one line naming the joint, the arm's limit and the policy's; None when they do.

    The rule is :func:`model_refusal`'s for the hard limits: each joint's velocity limit of the
    description (``robot.velocity_limit``, deg/s) against the arm's lowest joint speed soft limit
    over ``modes`` (``kortex.soft_limit_modes``) times 1 + ``tolerance``; with
    ``acceleration_limit`` (rad/s^2 per joint: the safety filter's) the same for the joint
    acceleration soft limits, where the arm reports them.

    Args:
        soft_limits: entries ``{"control_mode", "joint_speed", "joint_acceleration"}`` (deg/s,
            deg/s^2 per joint), as :class:`~ahrm_stack.hardware.kortex.vendor_link.VendorLink`
            returns them.
        where, arm: the arm's address and description, for the message.
    """
    ours = f"the policy's robot {robot.name!r} ({robot.num_joints} joints)"
    reported = {str(entry["control_mode"]) for entry in soft_limits}
    for mode in modes:
        if mode not in reported:
            return (f"the arm at {where} ({arm}) reports no soft limits for control mode {mode} "
                    f"(ControlConfig.GetAllKinematicSoftLimits gave {sorted(reported)}; "
                    "kortex.soft_limit_modes): its joint speed limits cannot be checked against the policy's")
    checks = [("joint_speed", "speed", "deg/s", np.degrees(robot.velocity_limit))]
    if acceleration_limit is not None:
        checks.append(("joint_acceleration", "acceleration", "deg/s^2",
                       np.degrees(np.asarray(acceleration_limit, dtype=float))))
    for field, what, unit, policy in checks:
        if field == "joint_acceleration" and not all(
                entry.get(field) for entry in soft_limits if str(entry["control_mode"]) in modes):
            continue  # not reported by the arm: nothing to compare
        for i, (name, limit) in enumerate(zip(robot.joint_names, policy)):
            lowest = _lowest(soft_limits, modes, field, i)
            if lowest is None:
                return (f"the arm at {where} ({arm}) reports no joint {what} soft limit for joint {i}; "
                        f"{ours} needs {limit:.1f} {unit} on {name}")
            soft, mode = lowest
            if limit > soft * (1.0 + tolerance):
                return (f"the arm at {where} ({arm}) has a joint {what} soft limit of {soft:.1f} {unit} "
                        f"on joint {i} ({mode}); {ours} was trained with {limit:.1f} {unit} on {name} "
                        f"(kortex.soft_limit_tolerance {tolerance:g}): raise the arm's soft limit or "
                        "deploy a policy within it")
    return None


def soft_limit_report(soft_limits: Sequence[Mapping]) -> list[str]:
    """One line per control mode: its joint speed (deg/s) and acceleration (deg/s^2) soft limits."""
    def values(seq, unit: str) -> str:
        return "(" + ", ".join(f"{float(v):.1f}" for v in seq) + f") {unit}" if seq else "not reported"

    return [f"{entry['control_mode']}: speed {values(entry['joint_speed'], 'deg/s')}, acceleration "
            f"{values(entry.get('joint_acceleration', ()), 'deg/s^2')}" for entry in soft_limits]
