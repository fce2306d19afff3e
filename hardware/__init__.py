"""Arm adapters: the Kortex-style protocol (:mod:`hardware.protocol`) and its backends —
:mod:`hardware.sim` (the training physics), :mod:`hardware.kortex` (Kinova's ``kortex_api``,
an optional extra) and :mod:`hardware.kinova_gen2` (a JACO2 over Kinova's Gen2 C SDK, found as
:mod:`hardware.kinova_gen2.loader` checks; Kinova's x86_64 binary in ``hardware/vendor/``); the ones
deploy can build are in :mod:`hardware.backends`, a static scene source in :mod:`hardware.scene`.
Backends are imported from their modules so that the protocol stays light."""

from hardware.protocol import (ArmAdapter, ArmFaultError, DescribedArm, ArmState, CommandRefusedError,
                               ConnectionLostError, FastClock, Fault, Feedback,
                               FeedbackTimeoutError, HardwareError, NotConnectedError, ObjectPoses,
                               ServoingMode, WallClock, check_joint_speeds)

__all__ = ["ArmAdapter", "ArmFaultError", "DescribedArm", "ArmState", "CommandRefusedError", "ConnectionLostError",
           "FastClock", "Fault", "Feedback", "FeedbackTimeoutError", "HardwareError",
           "NotConnectedError", "ObjectPoses", "ServoingMode", "WallClock", "check_joint_speeds"]
