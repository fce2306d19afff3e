from kortex_api.Exceptions.KException import KException


class KServerException(KException):
    """The arm refused a request: an error code and sub-code (Errors_pb2)."""

    def __init__(self, error_code: int, sub_code: int, description: str) -> None:
        super().__init__(f"Server error name={error_code}, sub name={sub_code} => {description}")
        self._code, self._sub = error_code, sub_code

    def get_error_code(self) -> int:
        return self._code

    def get_error_sub_code(self) -> int:
        return self._sub
