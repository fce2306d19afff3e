"""ProductConfiguration's CompleteProductConfiguration (the fields the backend reads)."""


class CompleteProductConfiguration:
    def __init__(self) -> None:
        self.kin = ""
        self.model = 0  # ProductConfiguration.ModelId: 1 MODEL_ID_L53 (Gen3)
        self.degree_of_freedom = 0
