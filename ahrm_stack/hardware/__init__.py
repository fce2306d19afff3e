"""Arm adapters: the Kortex-style protocol (:mod:`ahrm_stack.hardware.protocol`) and its backends —
:mod:`ahrm_stack.hardware.sim` (the training physics), :mod:`ahrm_stack.hardware.kortex` (Kinova's
``kortex_api``, an optional extra) and :mod:`ahrm_stack.hardware.kinova_gen2` (a JACO2 over Kinova's
Gen2 C SDK, found as :mod:`ahrm_stack.hardware.kinova_gen2.loader` checks; Kinova's x86_64 binary in
``ahrm_stack/hardware/vendor/``); the ones
deploy can build are in :mod:`ahrm_stack.hardware.backends`, a static scene source in :mod:`ahrm_stack.hardware.scene`.
Backends are imported from their modules so that the protocol stays light."""

from ahrm_stack.hardware.protocol import (ArmAdapter, ArmFaultError, DescribedArm, ArmState, CommandRefusedError,
                               ConnectionLostError, FastClock, Fault, Feedback,
                               FeedbackTimeoutError, HardwareError, NotConnectedError, ObjectPoses,
                               ServoingMode, WallClock, check_joint_speeds)

__all__ = ["ArmAdapter", "ArmFaultError", "DescribedArm", "ArmState", "CommandRefusedError", "ConnectionLostError",
           "FastClock", "Fault", "Feedback", "FeedbackTimeoutError", "HardwareError",
           "NotConnectedError", "ObjectPoses", "ServoingMode", "WallClock", "check_joint_speeds"]
