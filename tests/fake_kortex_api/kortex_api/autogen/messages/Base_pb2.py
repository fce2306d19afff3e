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
