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
