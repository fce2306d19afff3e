"""Arm adapters: the Kortex-style protocol (:mod:`ahrm_stack.hardware.protocol`) and the real arms'
backends — :mod:`ahrm_stack.hardware.kortex` (Kinova's ``kortex_api``, an optional extra) and
:mod:`ahrm_stack.hardware.kinova_gen2` (a JACO2 over Kinova's Gen2 C SDK, found as
:mod:`ahrm_stack.hardware.kinova_gen2.loader` checks; Kinova's x86_64 binary in
``ahrm_stack/hardware/vendor/``) — a static scene source (:mod:`ahrm_stack.hardware.scene`) and the
wrappers (:mod:`ahrm_stack.hardware.wrapper`, a dry run). This package imports nothing of the
simulation or of training (a test checks): the simulated arm behind the same protocol is
:mod:`ahrm_stack.sim_arm`, above the task it runs, and the backends deploy can build are listed in
:mod:`ahrm_stack.deploy.backends`. Backends are imported from their modules so that the protocol
stays light."""

from ahrm_stack.hardware.protocol import (ArmAdapter, ArmFaultError, DescribedArm, ArmState, CommandRefusedError,
                               ConnectionLostError, FastClock, Fault, Feedback,
                               FeedbackTimeoutError, HardwareError, NotConnectedError, ObjectPoses,
                               ServoingMode, WallClock, check_joint_speeds)

__all__ = ["ArmAdapter", "ArmFaultError", "DescribedArm", "ArmState", "CommandRefusedError", "ConnectionLostError",
           "FastClock", "Fault", "Feedback", "FeedbackTimeoutError", "HardwareError",
           "NotConnectedError", "ObjectPoses", "ServoingMode", "WallClock", "check_joint_speeds"]
