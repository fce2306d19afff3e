"""Arm adapters: the Kortex-style protocol (:mod:`hardware.protocol`) and its backends —
:mod:`hardware.sim` (the training physics) and :mod:`hardware.kortex` (Kinova's ``kortex_api``,
an optional extra). Backends are imported from their modules so that the protocol stays light."""

from hardware.protocol import (ArmAdapter, ArmFaultError, ArmState, CommandRefusedError,
                               ConnectionLostError, FastClock, Fault, Feedback,
                               FeedbackTimeoutError, HardwareError, NotConnectedError, ObjectPoses,
                               ServoingMode, WallClock, check_joint_speeds)

__all__ = ["ArmAdapter", "ArmFaultError", "ArmState", "CommandRefusedError", "ConnectionLostError",
           "FastClock", "Fault", "Feedback", "FeedbackTimeoutError", "HardwareError",
           "NotConnectedError", "ObjectPoses", "ServoingMode", "WallClock", "check_joint_speeds"]
