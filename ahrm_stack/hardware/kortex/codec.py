"""Kortex values <-> this protocol's, as pure functions: degrees and radians, the joint-speed
message as plain values, arm states, fault banks, a :class:`~ahrm_stack.hardware.protocol.Feedback` from the
plain values of a BaseCyclic frame.

Kortex speaks degrees (deg, deg/s); the protocol radians (rad, rad/s). Field names and units are
those of Kinova's message reference (Kinovarobotics/Kinova-kortex2_Gen3_G3L,
api_python/doc/markdown/messages/BaseCyclic/ActuatorFeedback.md and BaseFeedback.md).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ahrm_stack.hardware.protocol import ArmState, Fault, Feedback, ServoingMode, unwrap_positions

__all__ = ["arm_state_from_kortex", "degrees_to_radians", "faults_from_banks", "feedback_from_values",
           "joint_speeds_message", "radians_to_degrees", "servoing_mode_name", "unwrap_positions"]


def radians_to_degrees(values) -> np.ndarray:
    """rad (or rad/s) -> deg (or deg/s)."""
    return np.degrees(np.asarray(values, dtype=float))


def degrees_to_radians(values) -> np.ndarray:
    """deg (or deg/s) -> rad (or rad/s)."""
    return np.radians(np.asarray(values, dtype=float))


def joint_speeds_message(speeds_rad_s: Sequence[float] | np.ndarray) -> list[dict]:
    """The ``Base_pb2.JointSpeeds`` content, as plain values: one entry per joint with
    ``joint_identifier`` (0-based), ``value`` (deg/s) and ``duration`` 0 (hold until the next)."""
    degrees = radians_to_degrees(speeds_rad_s)
    return [{"joint_identifier": i, "value": float(v), "duration": 0} for i, v in enumerate(degrees)]


_ARM_STATES = {
    "ARMSTATE_BASE_INITIALIZATION": ArmState.BASE_INITIALIZATION,
    "ARMSTATE_IDLE": ArmState.IDLE,
    "ARMSTATE_INITIALIZATION": ArmState.INITIALIZATION,
    "ARMSTATE_IN_FAULT": ArmState.IN_FAULT,
    "ARMSTATE_MAINTENANCE": ArmState.MAINTENANCE,
    "ARMSTATE_SERVOING_LOW_LEVEL": ArmState.SERVOING_LOW_LEVEL,
    "ARMSTATE_SERVOING_READY": ArmState.SERVOING_READY,
    "ARMSTATE_SERVOING_PLAYING_SEQUENCE": ArmState.SERVOING_PLAYING_SEQUENCE,
    "ARMSTATE_SERVOING_MANUALLY_CONTROLLED": ArmState.SERVOING_MANUALLY_CONTROLLED,
}

_SERVOING_MODES = {
    ServoingMode.SINGLE_LEVEL_SERVOING: "SINGLE_LEVEL_SERVOING",
    ServoingMode.LOW_LEVEL_SERVOING: "LOW_LEVEL_SERVOING",
}


def arm_state_from_kortex(name: str) -> ArmState:
    """A Kortex ``ArmState`` enum name (``Common_pb2.ArmState.Name(value)``) -> :class:`ArmState`.
    Unknown names (e.g. ``ARMSTATE_RESERVED``) read as in fault: never as ready."""
    return _ARM_STATES.get(name, ArmState.IN_FAULT)


def servoing_mode_name(mode: ServoingMode) -> str:
    """:class:`ServoingMode` -> the Kortex ``Base_pb2.ServoingMode`` enum name."""
    return _SERVOING_MODES[ServoingMode(mode)]


def faults_from_banks(base_bank_a: int, base_bank_b: int, actuator_banks: Sequence[int],
                      arm_state: ArmState) -> Fault:
    """Summarise Kortex fault banks: any non-zero bank is a hardware fault; in fault with empty
    banks (as after ApplyEmergencyStop) is an emergency stop."""
    faults = Fault.NONE
    if base_bank_a or base_bank_b or any(actuator_banks):
        faults |= Fault.HARDWARE
    if arm_state == ArmState.IN_FAULT and faults == Fault.NONE:
        faults |= Fault.EMERGENCY_STOP
    return faults


def feedback_from_values(*, timestamp: float, frame_id: int, positions_deg, velocities_deg_s,
                         torques_nm, arm_state_name: str, base_bank_a: int = 0,
                         base_bank_b: int = 0, actuator_banks: Sequence[int] = (),
                         reference: np.ndarray | None = None,
                         continuous: np.ndarray | None = None,
                         range_centre: np.ndarray | None = None) -> Feedback:
    """A :class:`Feedback` (SI, radians) from the plain values of a BaseCyclic feedback frame;
    ``continuous`` and ``range_centre`` as in :func:`unwrap_positions`."""
    positions = degrees_to_radians(positions_deg)
    if continuous is None:
        continuous = np.zeros(positions.size, dtype=bool)
    state = arm_state_from_kortex(arm_state_name)
    return Feedback(timestamp=float(timestamp), frame_id=int(frame_id),
                    position=unwrap_positions(positions, reference, continuous, range_centre),
                    velocity=degrees_to_radians(velocities_deg_s),
                    torque=np.asarray(torques_nm, dtype=float),
                    arm_state=state,
                    faults=faults_from_banks(base_bank_a, base_bank_b, actuator_banks, state))

