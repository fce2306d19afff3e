from kortex_api.autogen.messages._enum import EnumType

_STATES = {"ARMSTATE_UNSPECIFIED": 0, "ARMSTATE_BASE_INITIALIZATION": 1, "ARMSTATE_IDLE": 2,
           "ARMSTATE_INITIALIZATION": 3, "ARMSTATE_IN_FAULT": 4, "ARMSTATE_MAINTENANCE": 5,
           "ARMSTATE_SERVOING_LOW_LEVEL": 6, "ARMSTATE_SERVOING_READY": 7,
           "ARMSTATE_SERVOING_PLAYING_SEQUENCE": 8, "ARMSTATE_SERVOING_MANUALLY_CONTROLLED": 9,
           "ARMSTATE_BRAKE_RELEASING": 10, "ARMSTATE_RESERVED": 255}
ArmState = EnumType(_STATES)
globals().update(_STATES)


class NotificationOptions:
    def __init__(self) -> None:
        self.type = 0  # NotificationType (3: NOTIFICATION_TYPE_EVENT)
        self.rate_m_sec = 0
        self.threshold_value = 0.0


class NotificationHandle:
    def __init__(self) -> None:
        self.identifier = 0
