class BaseCyclicClient:
    def __init__(self, router) -> None:
        self.router = router

    def RefreshFeedback(self, deviceId=0, options=None):
        return self.router.arm.rpc("RefreshFeedback", options)
