from kortex_api.autogen.messages._enum import EnumType

_CODES = {"ERROR_NONE": 0, "ERROR_PROTOCOL_SERVER": 1, "ERROR_PROTOCOL_CLIENT": 2,
          "ERROR_DEVICE": 3, "ERROR_INTERNAL": 4}
_SUB = {"SUB_ERROR_NONE": 0, "INVALID_SESSION": 12, "ROBOT_IN_FAULT": 22,
        "ROBOT_IN_EMERGENCY_STOP": 25, "WRONG_SERVOING_MODE": 75, "METHOD_TIMEOUT": 131}
ErrorCodes = EnumType(_CODES)
SubErrorCodes = EnumType(_SUB)
globals().update(_CODES)
globals().update(_SUB)
