from kortex_api._fake_arm import FakeArm


class TCPTransport:
    def __init__(self) -> None:
        self.arm = None

    def connect(self, ip: str, port: int) -> None:
        self.arm = FakeArm.at(ip, port)

    def disconnect(self) -> None:
        self.arm = None
