

class SessionManager:
    def __init__(self, router) -> None:
        self.router = router

    def CreateSession(self, create_session_info, deviceId=0, options=None):
        self.router.arm.rpc("CreateSession", options, create_session_info)

    def CloseSession(self, deviceId=0, options=None):
        self.router.arm.rpc("CloseSession", options)
