class EnumType:
    """Like protobuf's EnumTypeWrapper: ``Name(value)`` and ``Value(name)``."""

    def __init__(self, values: dict) -> None:
        self._values = dict(values)
        self._names = {v: k for k, v in values.items()}

    def Name(self, value: int) -> str:
        if value not in self._names:
            raise ValueError(f"Enum has no name defined for value {value!r}")
        return self._names[value]

    def Value(self, name: str) -> int:
        return self._values[name]
