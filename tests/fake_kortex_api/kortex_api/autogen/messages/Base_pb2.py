from kortex_api.autogen.messages._enum import EnumType

_MODES = {"UNSPECIFIED_SERVOING_MODE": 0, "SINGLE_LEVEL_SERVOING": 2, "LOW_LEVEL_SERVOING": 3,
          "BYPASS_SERVOING": 4}
ServoingMode = EnumType(_MODES)
globals().update(_MODES)


class _Repeated(list):
    def __init__(self, kind) -> None:
        super().__init__()
        self._kind = kind

    def add(self):
        item = self._kind()
        self.append(item)
        return item


class JointSpeed:
    def __init__(self) -> None:
        self.joint_identifier = 0
        self.value = 0.0  # deg/s
        self.duration = 0  # not implemented by the arm: speeds never expire


class JointSpeeds:
    def __init__(self) -> None:
        self.joint_speeds = _Repeated(JointSpeed)
        self.duration = 0


class ServoingModeInformation:
    def __init__(self) -> None:
        self.servoing_mode = 0


VELOCITY_LIMITATION = 3  # Base.LimitationType
CYLINDER, SPHERE, RECTANGULAR_PRISM = 1, 2, 3  # Base.ShapeType


class JointLimitation:
    def __init__(self) -> None:
        self.joint_identifier = 0
        self.type = 0
        self.value = 0.0


class JointsLimitationsList:
    def __init__(self) -> None:
        self.joints_limitations = _Repeated(JointLimitation)


class Point:
    def __init__(self) -> None:
        self.x = self.y = self.z = 0.0


class RotationMatrixRow:
    def __init__(self) -> None:
        self.column1 = self.column2 = self.column3 = 0.0


class RotationMatrix:
    def __init__(self) -> None:
        self.row1, self.row2, self.row3 = RotationMatrixRow(), RotationMatrixRow(), RotationMatrixRow()


class ZoneShape:
    def __init__(self) -> None:
        self.shape_type = 0
        self.origin = Point()  # m, base frame
        self.orientation = RotationMatrix()
        self.dimensions: list = []  # m: prism x, y, z; cylinder radius, height; sphere radius
        self.envelope_thickness = 0.0  # m


class ProtectionZone:
    def __init__(self) -> None:
        self.name = ""
        self.application_data = ""
        self.is_enabled = False
        self.shape = ZoneShape()


class ProtectionZoneList:
    def __init__(self) -> None:
        self.protection_zones = _Repeated(ProtectionZone)


# --- actions (messages/Base/Action.md, ConstrainedJointAngles.md, JointTrajectoryConstraint.md,
# ActionNotification.md, RequestedActionType.md, ActionList.md; enums/Base/ActionEvent.md,
# JointTrajectoryConstraintType.md, ActionType.md)
_EVENTS = {"UNSPECIFIED_ACTION_EVENT": 0, "ACTION_END": 1, "ACTION_ABORT": 2, "ACTION_PAUSE": 3,
           "ACTION_START": 4, "ACTION_PREPROCESS_START": 5, "ACTION_PREPROCESS_ABORT": 6,
           "ACTION_PREPROCESS_END": 7, "ACTION_POSTPROCESS_START": 8,
           "ACTION_POSTPROCESS_ABORT": 9, "ACTION_POSTPROCESS_END": 10, "ACTION_FEEDBACK": 11}
ActionEvent = EnumType(_EVENTS)
globals().update(_EVENTS)
_CONSTRAINTS = {"UNSPECIFIED_JOINT_CONSTRAINT": 0, "JOINT_CONSTRAINT_DURATION": 1,
                "JOINT_CONSTRAINT_SPEED": 2}
JointTrajectoryConstraintType = EnumType(_CONSTRAINTS)
globals().update(_CONSTRAINTS)
_ACTION_TYPES = {"UNSPECIFIED_ACTION": 0, "SEND_JOINT_SPEEDS": 4, "REACH_POSE": 6,
                 "REACH_JOINT_ANGLES": 7, "STOP_ACTION": 35}
ActionType = EnumType(_ACTION_TYPES)
globals().update(_ACTION_TYPES)


class JointAngle:
    def __init__(self) -> None:
        self.joint_identifier = 0
        self.value = 0.0  # deg


class JointAngles:
    def __init__(self) -> None:
        self.joint_angles = _Repeated(JointAngle)


class JointTrajectoryConstraint:
    def __init__(self) -> None:
        self.type = 0
        self.value = 0.0  # s (DURATION) or deg/s (SPEED: "m/s" in the reference, deg/s for joints)


class ConstrainedJointAngles:
    def __init__(self) -> None:
        self.joint_angles = JointAngles()
        self.constraint = JointTrajectoryConstraint()


class ActionHandle:
    def __init__(self) -> None:
        self.identifier = 0
        self.action_type = 0
        self.permission = 0


class Action:
    """Only the ``reach_joint_angles`` member of the ``action_parameters`` oneof is modelled
    (``WhichOneof`` says whether it was set)."""

    def __init__(self) -> None:
        self.handle = ActionHandle()
        self.name = ""
        self.application_data = ""
        self.reach_joint_angles = ConstrainedJointAngles()

    def WhichOneof(self, group: str):
        return "reach_joint_angles" if self.reach_joint_angles.joint_angles.joint_angles else None


class ActionNotification:
    def __init__(self) -> None:
        self.action_event = 0
        self.handle = ActionHandle()
        self.abort_details = 0


class RequestedActionType:
    def __init__(self) -> None:
        self.action_type = 0


class ActionList:
    def __init__(self) -> None:
        self.action_list = _Repeated(Action)


from kortex_api.autogen.messages.Common_pb2 import NotificationHandle, NotificationOptions  # noqa: E402,F401
