"""The Kinova Gen2 backend: a JACO2 (j2n6s300 curved wrist = dm_control's ``jaco``, or j2s6s200
spherical wrist) through Kinova's C SDK, loaded with :mod:`ctypes`.

The SDK is the vendor's shared library that kinova-ros ships in ``kinova_driver/lib/<arch>/``:
``USBCommandLayerUbuntu.so`` with its communication layer ``USBCommLayerUbuntu.so`` (installed by
Kinova's installer as ``Kinova.API.USBCommandLayerUbuntu.so`` and ``Kinova.API.CommLayerUbuntu.so``);
the x86_64 pair is in ``ahrm_stack/hardware/vendor/kinova_gen2/``. Only USB is implemented: the Ethernet
variant (``EthCommandLayerUbuntu.so``) needs ``InitEthernetAPI``, which is not called here. The path
is ``kinova_gen2.library`` in ``configs/deploy.yaml``; nothing is downloaded or guessed. ``InitAPI``
loads the communication layer by bare name, so its folder must be on the dynamic loader's path
when the process starts: :func:`check_library` checks that before anything runs
(:mod:`ahrm_stack.hardware.kinova_gen2.loader`). The function signatures and struct layouts are those of
kinova-ros's headers (``kinova_driver/include/kinova/KinovaTypes.h``,
``Kinova.API.USBCommandLayerUbuntu.h``, ``Kinova.API.USBCommLayerUbuntu.h``) and match the vendor
binary's debug information; C++ references (``int &``) are pointers in the C ABI.

**One thread owns the USB.** The SDK handles one call at a time, each a USB round trip of several
ms, and an ANGULAR_VELOCITY trajectory point moves the arm for 10 ms only, so joint velocities must
reach it at 100 Hz while the deploy loop runs at 20 Hz with a 25 ms command deadline. Once
connected, every SDK call goes through :class:`~ahrm_stack.hardware.kinova_gen2.bus.UsbBus`'s thread, which
orders them: stops first, then trajectory points before the arm's FIFO runs dry, then the callers'
calls, then the status poll (see :mod:`ahrm_stack.hardware.kinova_gen2.bus`). A control tick costs one
position read (:meth:`KinovaGen2Arm.refresh_feedback`, stamped when the read returned; velocities
are position differences between reads); :meth:`~KinovaGen2Arm.send_joint_speeds` only makes the
command the standing one, which the thread sends in its next point (at most 100 per second,
``send_ahead`` s of motion queued: ``kinova_gen2.send_rate_hz`` is capped at 100 Hz since faster
points pile up in the arm's 2,000-point FIFO and keep it moving after commands stop). Supply
voltage, the system error log and the torques are polled at ``kinova_gen2.status_rate_hz`` (2 Hz);
with ``kinova_gen2.torque_each_tick`` the torques are read with each tick's positions instead
(the deploy loop's contact stop needs them so).
Every stop sends zero velocity and erases the FIFO (``EraseAllTrajectories``). The **command
watchdog** (the protocol's rule, :class:`~ahrm_stack.hardware.protocol.ArmAdapter`): when no fresh command has
come for ``kinova_gen2.command_timeout`` control periods while the standing command moves the arm,
the thread sends zero velocity, then ``EraseAllTrajectories``, at that deadline, records why
(:attr:`KinovaGen2Arm.watchdog_stops`) and latches ``Fault.WATCHDOG``: commands are refused until
:meth:`~KinovaGen2Arm.clear_faults`. A zero command or a stop disarms it.

Units: the protocol speaks rad and rad/s; Gen2 degrees and deg/s. The model's joint angle is
``sign * kinova_angle + offset`` per joint (``kinova_gen2.joints.<arm>``; both arms: sign +1,
offset 0, as kinova-ros's current driver publishes the raw angles for kinova_description's URDFs,
which dm_control's JACO MJCF copies). ``GetAngularVelocity`` (read only by the ``--check``:
the loop derives velocities from positions) reports half the real velocity with
negative values as 360 - |v| (kinova-ros's ``kinova_comm.cpp`` multiplies by 2 and
``kinova_arm.cpp`` subtracts 360 above 180); :func:`model_velocities` undoes both.

Faults: any SDK call that fails with a communication error (USB unplugged, power lost) is
:class:`~ahrm_stack.hardware.protocol.ConnectionLostError` and the adapter disconnects; another failing call
is a :class:`~ahrm_stack.hardware.protocol.HardwareError` naming the function and the code. A new entry in
the arm's system error log (``GetSystemErrorCount`` / ``GetSystemError``) puts the adapter in
fault (``Fault.HARDWARE``); a supply voltage below ``kinova_gen2.min_supply_voltage``
(``GetSensorsInfo``) or a logged voltage error is the e-stop cutting the actuators' power
(``Fault.EMERGENCY_STOP``). The status poll that sees a fault stops the arm at once, on the USB
thread, whatever the control loop is doing (:attr:`KinovaGen2Arm.fault_stops`), and the next
feedback frame carries the flags. Gen2 has no software e-stop: :meth:`KinovaGen2Arm.apply_emergency_stop`
sends zero, erases the trajectory FIFO and calls ``StopControlAPI`` (the arm ignores commands
until :meth:`~KinovaGen2Arm.clear_faults` calls ``StartControlAPI`` again). In fault, motion
commands raise :class:`~ahrm_stack.hardware.protocol.ArmFaultError`.

:meth:`KinovaGen2Arm.connect` selects the arm by its serial number (``kinova_gen2.serial``) from
``GetDevices``; it never takes the first one found. It starts the control API, stops it and starts
it again (as kinova-ros does: on a cold boot the arm may not respond to the first start). Every exit
path of connect (a failure included) and :meth:`~KinovaGen2Arm.disconnect` leave the arm stopped,
calling only what is valid after what succeeded: once ``StartControlAPI`` has succeeded, zero
velocity, ``EraseAllTrajectories``, ``StopControlAPI``; then ``CloseAPI`` (valid in every state).
Before that (``InitAPI`` failed, no arm) only ``CloseAPI``: the real SDK crashes in
``SendAdvanceTrajectory`` when ``InitAPI`` could not load its communication layer. An ``atexit``
hook disconnects an adapter left connected. Only the serial number is ever logged.

Tested against the fake SDK in ``tests/fake_kinova_sdk/`` (same exports and layouts; per-call USB
latency, one call at a time, the trajectory FIFO, noisy velocity feedback, a cold boot) and,
without an arm, against Kinova's own binary (``tests/test_kinova_gen2_vendor.py``); never against a
real arm: see docs/hardware.md.

The package, one idea a module: :mod:`~ahrm_stack.hardware.kinova_gen2.sdk` (the SDK through ctypes),
:mod:`~ahrm_stack.hardware.kinova_gen2.settings` (the ``kinova_gen2`` section, the file checks, the unit
conversions), :mod:`~ahrm_stack.hardware.kinova_gen2.loader` (the loader-path check),
:mod:`~ahrm_stack.hardware.kinova_gen2.lock` (Kinova's machine-wide lock), :mod:`~ahrm_stack.hardware.kinova_gen2.bus`
(the USB thread: the points, the command watchdog), :mod:`~ahrm_stack.hardware.kinova_gen2.faults` (the fault
state, the status poll), :mod:`~ahrm_stack.hardware.kinova_gen2.arm` (the adapter),
:mod:`~ahrm_stack.hardware.kinova_gen2.check` (``--check``) and :mod:`~ahrm_stack.hardware.kinova_gen2.home`
(``--home``). The names below are re-exported here.
"""

from ahrm_stack.hardware.kinova_gen2.bus import POINT_PERIOD, CallTimes, UsbBus, WatchdogStop
from ahrm_stack.hardware.kinova_gen2.settings import (ARM_POINT_RATE_HZ, DOCS, SERIAL_LENGTH, Gen2ConfigError,
                                           Gen2Settings, HomeSettings, JointConvention,
                                           check_library, check_sdk_path, joint_convention,
                                           kinova_positions, kinova_velocities, model_positions,
                                           model_velocities)
from ahrm_stack.hardware.kinova_gen2.sdk import (ANGULAR_POSITION, ANGULAR_VELOCITY, COMMUNICATION_ERRORS,
                                      ERROR_CODES, ERROR_DATA_COUNT_MAX, ERROR_LAYER_COUNT,
                                      ERROR_LOAD_COMM_DLL, ERROR_NO_DEVICE_FOUND, MAX_KINOVA_DEVICE,
                                      NO_ERROR_KINOVA, SIGNATURES, SYSTEM_ERROR_TYPES, VOLTAGE_ERROR,
                                      AngularInfo, AngularPosition, CartesianInfo, FingersPosition,
                                      KinovaDevice, Limitation, Sdk, SdkCallError, SensorsInfo,
                                      SystemError, TrajectoryPoint, UserPosition, position_point,
                                      velocity_point)
from ahrm_stack.hardware.kinova_gen2.faults import FaultStop
from ahrm_stack.hardware.kinova_gen2.arm import KinovaGen2Arm

__all__ = [
    "POINT_PERIOD", "CallTimes", "UsbBus", "WatchdogStop",
    "ARM_POINT_RATE_HZ", "DOCS", "SERIAL_LENGTH", "Gen2ConfigError", "Gen2Settings", "HomeSettings",
    "JointConvention", "check_library", "check_sdk_path", "joint_convention", "kinova_positions",
    "kinova_velocities", "model_positions", "model_velocities",
    "ANGULAR_POSITION", "ANGULAR_VELOCITY", "COMMUNICATION_ERRORS", "ERROR_CODES",
    "ERROR_DATA_COUNT_MAX", "ERROR_LAYER_COUNT", "ERROR_LOAD_COMM_DLL", "ERROR_NO_DEVICE_FOUND",
    "MAX_KINOVA_DEVICE", "NO_ERROR_KINOVA", "SIGNATURES", "SYSTEM_ERROR_TYPES", "VOLTAGE_ERROR",
    "AngularInfo", "AngularPosition", "CartesianInfo", "FingersPosition", "KinovaDevice",
    "Limitation", "Sdk", "SdkCallError", "SensorsInfo", "SystemError", "TrajectoryPoint",
    "UserPosition", "position_point", "velocity_point",
    "FaultStop", "KinovaGen2Arm",
]
