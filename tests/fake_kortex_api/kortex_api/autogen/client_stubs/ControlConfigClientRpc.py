class ControlConfigClient:
    def __init__(self, router) -> None:
        self.router = router

    def GetAllKinematicSoftLimits(self, deviceId=0, options=None):
        return self.router.arm.rpc("GetAllKinematicSoftLimits", options)

    def GetKinematicSoftLimits(self, controlmodeinformation, deviceId=0, options=None):
        return self.router.arm.rpc("GetKinematicSoftLimits", options, controlmodeinformation)
