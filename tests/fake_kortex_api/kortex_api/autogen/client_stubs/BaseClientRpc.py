class BaseClient:
    def __init__(self, router) -> None:
        self.router = router

    def SendJointSpeedsCommand(self, joint_speeds, deviceId=0, options=None):
        return self.router.arm.rpc("SendJointSpeedsCommand", options, joint_speeds)

    def Stop(self, deviceId=0, options=None):
        return self.router.arm.rpc("Stop", options)

    def ApplyEmergencyStop(self, deviceId=0, options=None):
        return self.router.arm.rpc("ApplyEmergencyStop", options)

    def ClearFaults(self, deviceId=0, options=None):
        return self.router.arm.rpc("ClearFaults", options)

    def SetServoingMode(self, servoingmodeinformation, deviceId=0, options=None):
        return self.router.arm.rpc("SetServoingMode", options, servoingmodeinformation)

    def GetServoingMode(self, deviceId=0, options=None):
        return self.router.arm.rpc("GetServoingMode", options)

    def GetProductConfiguration(self, deviceId=0, options=None):
        return self.router.arm.rpc("GetProductConfiguration", options)

    def GetAllJointsSpeedHardLimitation(self, deviceId=0, options=None):
        return self.router.arm.rpc("GetAllJointsSpeedHardLimitation", options)

    def ReadAllProtectionZones(self, deviceId=0, options=None):
        return self.router.arm.rpc("ReadAllProtectionZones", options)

    def ExecuteAction(self, action, deviceId=0, options=None):
        return self.router.arm.rpc("ExecuteAction", options, action)

    def OnNotificationActionTopic(self, callback, notificationoptions, deviceId=0, options=None):
        return self.router.arm.rpc("OnNotificationActionTopic", options, callback)

    def Unsubscribe(self, notificationhandle, deviceId=0, options=None):
        return self.router.arm.rpc("Unsubscribe", options, notificationhandle)
