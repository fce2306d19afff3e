"""ControlConfig's kinematic limits (api_python/doc/markdown/messages/ControlConfig/KinematicLimits.md,
KinematicLimitsList.md, ControlModeInformation.md; enums/ControlConfig/ControlMode.md)."""

from kortex_api.autogen.messages._enum import EnumType
from kortex_api.autogen.messages.Base_pb2 import _Repeated

_MODES = {"UNSPECIFIED_CONTROL_MODE": 0, "ANGULAR_JOYSTICK": 1, "CARTESIAN_JOYSTICK": 2,
          "ANGULAR_TRAJECTORY": 4, "CARTESIAN_TRAJECTORY": 5, "CARTESIAN_ADMITTANCE": 6,
          "JOINT_ADMITTANCE": 7, "NULL_SPACE_ADMITTANCE": 8, "FORCE_CONTROL": 10,
          "FORCE_CONTROL_MOTION_RESTRICTED": 11, "CARTESIAN_WAYPOINT_TRAJECTORY": 12, "IDLE": 13}
ControlMode = EnumType(_MODES)
globals().update(_MODES)


class ControlModeInformation:
    def __init__(self) -> None:
        self.control_mode = 0


class KinematicLimits:
    def __init__(self) -> None:
        self.control_mode = 0
        self.twist_linear = 0.0  # m/s
        self.twist_angular = 0.0  # deg/s
        self.joint_speed_limits: list = []  # deg/s per joint (repeated float)
        self.joint_acceleration_limits: list = []  # deg/s^2 per joint (repeated float)


class KinematicLimitsList:
    def __init__(self) -> None:
        self.kinematic_limits_list = _Repeated(KinematicLimits)
