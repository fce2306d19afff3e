"""RouterClient and its send options, as in kortex_api 2.6.0: the default timeout is 10 s."""


class RouterClientSendOptions:
    def __init__(self) -> None:
        self.andForget = False
        self.delay_ms = 0
        self.timeout_ms = 10000  # the vendor default

    def getTimeoutInSecond(self) -> float:
        return self.timeout_ms / 1000


class RouterClient:
    def __init__(self, transport, errorCallback=None) -> None:
        self.transport = transport
        self.errorCallback = errorCallback

    @property
    def arm(self):
        return self.transport.arm
