class SessionManager:
    """As kortex_api's: ``CreateSession(createSessionInfo, options=...)``, ``CloseSession(options=...)``.
    (The vendor's also runs a thread that sends KeepAlive every 150 ms; the fake has none.)"""

    def __init__(self, router) -> None:
        self.router = router

    def CreateSession(self, createSessionInfo, options=None):
        self.router.arm.rpc("CreateSession", options, createSessionInfo)

    def CloseSession(self, options=None):
        self.router.arm.rpc("CloseSession", options)
