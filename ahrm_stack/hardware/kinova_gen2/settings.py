"""The Gen2 backend's settings (``configs/deploy.yaml``, section ``kinova_gen2``:
:class:`Gen2Settings`, :class:`HomeSettings`, :class:`JointConvention`), the checks of the SDK's
files (:func:`check_library`, :func:`check_sdk_path`) and the unit and joint-convention
conversions between the model (rad, rad/s) and Kinova (deg, deg/s).

The model's joint angle is ``sign * kinova_angle + offset`` per joint (``kinova_gen2.joints.<arm>``).
``GetAngularVelocity`` reports half the real velocity with negative values as 360 - |v|;
:func:`model_velocities` undoes both.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Optional

import numpy as np
from pydantic import AfterValidator, PlainValidator

from ahrm_stack.schema import Bool, ConfigError, FilePath, Float, Int, Section, Str, count, fail, ge, gt, le
from ahrm_stack.hardware.kinova_gen2.bus import POINT_PERIOD
from ahrm_stack.hardware.kinova_gen2.loader import LoaderPathError, check_comm_layers

if TYPE_CHECKING:
    from ahrm_stack.robot import RobotDescription

DOCS = "docs/hardware.md (section 'Kinova Gen2')"
ARM_POINT_RATE_HZ = 1.0 / POINT_PERIOD  # trajectory points the arm executes per second (100)
SERIAL_LENGTH = 20  # the SDK's serial number: char[SERIAL_LENGTH] (KinovaDevice, KinovaTypes.h)


class Gen2ConfigError(ValueError):
    """A ``kinova_gen2`` setting is missing or invalid, or the SDK file is missing; one line that
    names the key (or the path)."""


def _sign(value: int) -> int:
    if value not in (1, -1):
        fail(f" must be 1 or -1, got {value!r}")
    return value


def _serial(value: Any) -> str | None:
    """The arm's serial number, stripped (it fits the SDK's char[SERIAL_LENGTH]), or None."""
    if value is not None and (not isinstance(value, str) or not value.strip()
                              or len(value.encode()) >= SERIAL_LENGTH):
        fail(f" must be the arm's serial number (a string of at most {SERIAL_LENGTH - 1} bytes) "
             f"or null, got {value!r}")
    return value.strip() if isinstance(value, str) else None


def _not_empty(value: dict) -> dict:
    if not value:
        fail(" must map each arm name to its sign and offset_deg, got {}")
    return value


@dataclasses.dataclass(frozen=True)
class HomeSettings(Section):
    """``kinova_gen2.home``: the homing step (``--home``, :mod:`ahrm_stack.hardware.kinova_gen2.home`)."""

    factory_home_first: Bool  # MoveHome (the firmware's move to its factory home, at its own speed)
    # before the slow move to the policy's start
    speed_deg_s: Annotated[Float, gt(0), le(20.0, " deg/s: the homing move is a slow, supervised "
                                             "first motion (kinova-ros's default joint speed limit "
                                             "is 10)")]  # deg/s per joint, the final move's limit
    tolerance_deg: Annotated[Float, gt(0), le(5.0)]  # deg: each joint this near its target is there
    still_deg_s: Annotated[Float, gt(0), le(5.0)]  # deg/s: every joint slower than this is still
    settle: Annotated[Float, gt(0), le(5.0)]  # s the arm must stay still to count as arrived
    timeout: Annotated[Float, gt(0), le(600.0)]  # s each stage may take before the arm is stopped
    poll_rate_hz: Annotated[Float, gt(0), le(50.0)]  # Hz: position reads while it moves
    clearance: Annotated[Float, ge(0), le(0.5)]  # m: the pusher tip above the table top all along
    # the final move's joint-space path


@dataclasses.dataclass(frozen=True)
class TouchOffSettings(Section):
    """``kinova_gen2.touch_off``: the tool's touch-off (``--touch-off``,
    :mod:`ahrm_stack.hardware.kinova_gen2.touch_off`). Lengths in m, world frame."""

    points: Annotated[tuple[tuple[Float, Float], ...], count(3)]  # (x, y) of table points the tip
    # touches, m, world frame (within the arm's reach pointing down)
    lift: Annotated[Float, gt(0), le(0.3)]  # m above the table top when moving between points
    approach: Annotated[Float, gt(0), le(0.1)]  # m above the table top where the jogging starts
    step: Annotated[Float, gt(0), le(0.005, " m: a jog step is a move the user watches")]  # m per jog
    below: Annotated[Float, ge(0), le(0.02)]  # m: the jog stops this far below the model's table top
    speed_deg_s: Annotated[Float, gt(0), le(20.0)]  # deg/s per joint, every touch-off move
    max_error: Annotated[Float, gt(0), le(0.02)]  # m: |the tip's height above the model's table| at
    # every point; beyond it the touch-off fails
    record: Str  # JSON file of the last touch-off (the arm's serial, the errors, passed)
    required: Bool  # deploy --backend kinova-gen2 refuses unless that record is of this arm and passed

    def check(self, key: str) -> None:
        if self.approach >= self.lift:
            raise ConfigError(f"{key}.approach ({self.approach}) must be below {key}.lift ({self.lift})")


#: ROBOT_TYPE (KinovaTypes.h; values as the vendored binary's DWARF gives them): ``QuickStatus.RobotType``.
ROBOT_TYPES: dict[int, str] = {
    0: "JACOV1_ASSISTIVE", 1: "MICO_6DOF_SERVICE", 2: "MICO_4DOF_SERVICE", 3: "JACOV2_6DOF_SERVICE",
    4: "JACOV2_4DOF_SERVICE", 5: "MICO_6DOF_ASSISTIVE", 6: "JACOV2_6DOF_ASSISTIVE",
    7: "SPHERICAL_6DOF_SERVICE", 8: "SPHERICAL_7DOF_SERVICE", 254: "GENERIC_ROBOT", 255: "ROBOT_ERROR"}
RobotType = Literal["JACOV1_ASSISTIVE", "MICO_6DOF_SERVICE", "MICO_4DOF_SERVICE", "JACOV2_6DOF_SERVICE",
                    "JACOV2_4DOF_SERVICE", "MICO_6DOF_ASSISTIVE", "JACOV2_6DOF_ASSISTIVE",
                    "SPHERICAL_6DOF_SERVICE", "SPHERICAL_7DOF_SERVICE", "GENERIC_ROBOT"]  # of ROBOT_TYPES


@dataclasses.dataclass(frozen=True)
class JointConvention(Section):
    """model angle (deg) = ``sign`` * Kinova angle (deg) + ``offset_deg``, per joint."""

    sign: Annotated[tuple[Annotated[Int, AfterValidator(_sign)], ...], count(1)]  # +1 or -1 per joint
    offset_deg: tuple[Float, ...]  # deg, one per joint
    robot_types: Annotated[tuple[RobotType, ...], count(1)]  # the QuickStatus.RobotType names of
    # the arms this model is (connect refuses any other)

    def check(self, key: str) -> None:
        if len(self.offset_deg) != len(self.sign):
            raise ConfigError(f"{key}.offset_deg must be {len(self.sign)} finite numbers (deg), "
                              f"got {list(self.offset_deg)}")


@dataclasses.dataclass(frozen=True)
class Gen2Settings(Section):
    """``configs/deploy.yaml``'s ``kinova_gen2`` section. Files are not looked at here
    (:func:`check_library` does, when the backend is used)."""

    library: FilePath  # the command layer .so (its communication layer: on the loader's path)
    serial: Annotated[Optional[str], PlainValidator(_serial)]  # the arm's serial; required to connect
    send_rate_hz: Annotated[Float, gt(0), le(ARM_POINT_RATE_HZ, " Hz: the arm executes one trajectory "
                                              "point per 10 ms; faster points pile up in its 2,000-point "
                                              "FIFO and keep it moving after commands stop")]  # Hz: at
    # most this many trajectory points per second (100: the arm's own rate)
    send_ahead: Annotated[Float, gt(0), le(0.05, " s: queued motion delays every command by as much and "
                                           "keeps the arm moving that long after a lost link")]  # s of
    # motion left in the arm's FIFO when the next point is sent
    status_rate_hz: Annotated[Float, gt(0), le(10.0, " Hz: each poll is three USB calls of several ms "
                                           "(kinova-ros polls at 10 Hz)")]  # Hz: supply voltage, error
    # log and torques are read this often (a logged fault is seen within 1 / this)
    torque_each_tick: Bool  # read the joint torques (GetAngularForce) with each tick's positions,
    # one USB call more per tick, instead of at the status poll: the deploy loop's contact stop
    # (deploy.contact) needs them fresh and is off on this backend without it
    command_timeout: Annotated[Float, gt(1, " (a healthy loop sends one command per period)"),
                               le(100.0)]  # control periods without a fresh command before the
    # USB thread stops the arm
    check_calls: Annotated[Int, ge(10), le(10000)]  # --check: calls of each SDK function timed, and
    # control ticks of its held-still loop
    speed_scale: Annotated[Float, gt(0), le(1.0)]  # every command is multiplied by this
    velocity_window: Annotated[Float, gt(0), le(1.0)]  # s: velocities are the position difference to
    # the latest read at least this much older (angle noise over a few ms would be tens of deg/s)
    velocity_feedback_scale: Annotated[Float, gt(0)]  # GetAngularVelocity reports 1/this of the real one
    min_supply_voltage: Annotated[Float, gt(0)]  # V; below it the actuators are unpowered (the e-stop)
    scene: FilePath  # the static scene layout (ahrm_stack/hardware/scene.py) deploy uses for perception
    switch_interval: Annotated[Float, gt(0), le(0.005)]  # s, Python's GIL switch interval while
    # connected (sys.setswitchinterval)
    joints: Annotated[dict[Str, JointConvention], AfterValidator(_not_empty)]  # per arm (task.robot)
    home: HomeSettings  # the homing step (--home)
    touch_off: TouchOffSettings  # the tool's touch-off (--touch-off)


def setting_key(name: str) -> str:
    return f"deploy.kinova_gen2.{name}"


def check_library(settings: Gen2Settings) -> Path:
    """The command layer's path if it is a file whose communication layer the dynamic loader finds
    by bare name (:func:`check_sdk_path`); else a one-line :class:`Gen2ConfigError` naming the key
    or the path and saying what to do (nothing is downloaded or guessed)."""
    if settings.library is None:
        raise Gen2ConfigError(f"{setting_key('library')} is not set: give the path of Kinova's "
                              f"USBCommandLayerUbuntu.so (ahrm_stack/hardware/vendor/kinova_gen2/x86_64-linux-gnu/ "
                              f"or kinova-ros kinova_driver/lib/); see {DOCS}")
    library = Path(settings.library).expanduser()
    if not library.is_file():
        raise Gen2ConfigError(f"{setting_key('library')}: no file at {settings.library}; install Kinova's "
                              f"Gen2 SDK as described in {DOCS}")
    check_sdk_path(library)
    return library


def check_sdk_path(library: Path) -> dict[str, str | None]:
    """The communication layers ``library``'s ``InitAPI`` loads by bare name, each loaded here as
    the dynamic loader finds it (name -> file); a one-line :class:`Gen2ConfigError` saying what to
    set when it does not (see :mod:`ahrm_stack.hardware.kinova_gen2.loader`)."""
    try:
        return check_comm_layers(library, setting_key("library"), DOCS)
    except LoaderPathError as error:
        raise Gen2ConfigError(str(error)) from None
    except OSError as error:
        raise Gen2ConfigError(f"{setting_key('library')}: cannot read {library} "
                              f"({error.strerror or error})") from None


def joint_convention(settings: Gen2Settings, robot: RobotDescription) -> JointConvention:
    """The arm's joint convention; a one-line error when ``joints.<arm>`` is missing or of the
    wrong size."""
    convention = settings.joints.get(robot.name)
    if convention is None:
        raise Gen2ConfigError(f"{setting_key('joints.' + robot.name)} is missing (the deployed arm is "
                              f"{robot.name!r}; configured: {sorted(settings.joints)})")
    if len(convention.sign) != robot.num_joints:
        raise Gen2ConfigError(f"{setting_key('joints.' + robot.name)} has {len(convention.sign)} joints; "
                              f"{robot.name} has {robot.num_joints}")
    return convention


def robot_type_refusal(code: int, convention: JointConvention, serial: str, model: str) -> str | None:
    """Why an arm whose ``QuickStatus.RobotType`` is ``code`` must not be driven as ``model``
    (one line), or None when it is one of ``joints.<model>.robot_types``."""
    found = ROBOT_TYPES.get(code, f"an unknown type ({code})")
    if found in convention.robot_types:
        return None
    return (f"the Kinova arm {serial} is a {found}; the policy and its collision model are {model} "
            f"({' or '.join(convention.robot_types)}): refusing to drive it "
            f"({setting_key('joints.' + model + '.robot_types')})")


# ---------------------------------------------------------------------------------------------
# Unit and convention conversions (pure)
# ---------------------------------------------------------------------------------------------


def model_positions(kinova_deg, convention: JointConvention) -> np.ndarray:
    """Kinova joint angles (deg) -> the model's (rad), before unwrapping."""
    sign = np.asarray(convention.sign, dtype=float)
    return np.radians(sign * np.asarray(kinova_deg, dtype=float) + np.asarray(convention.offset_deg))


def kinova_positions(model_rad, convention: JointConvention) -> np.ndarray:
    """The model's joint angles (rad) -> Kinova's (deg); the inverse of :func:`model_positions`."""
    sign = np.asarray(convention.sign, dtype=float)
    return sign * (np.degrees(np.asarray(model_rad, dtype=float)) - np.asarray(convention.offset_deg))


def kinova_velocities(model_rad_s, convention: JointConvention) -> np.ndarray:
    """Model joint velocities (rad/s) -> the ANGULAR_VELOCITY command (deg/s)."""
    return np.asarray(convention.sign, dtype=float) * np.degrees(np.asarray(model_rad_s, dtype=float))


def model_velocities(reported, convention: JointConvention, feedback_scale: float) -> np.ndarray:
    """``GetAngularVelocity``'s values -> model joint velocities (rad/s): times ``feedback_scale``
    (the firmware reports half), values above 180 deg/s minus 360 (negative velocities come as
    360 - |v|), then the joint sign."""
    v = np.asarray(reported, dtype=float) * feedback_scale
    v = np.where(v > 180.0, v - 360.0, v)
    return np.asarray(convention.sign, dtype=float) * np.radians(v)

