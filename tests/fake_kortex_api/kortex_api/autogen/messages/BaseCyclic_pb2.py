"""BaseCyclic's Feedback as documented (api_python/doc/markdown/messages/BaseCyclic/*.md): frame_id,
base, actuators, interconnect. There is no timestamp field; frame_id is the client's (it echoes the
last BaseCyclic.Command's frame_id)."""


class ActuatorFeedback:
    def __init__(self) -> None:
        self.command_id = 0
        self.status_flags = 0
        self.jitter_comm = 0
        self.position = 0.0  # deg
        self.velocity = 0.0  # deg/s
        self.torque = 0.0  # N·m
        self.current_motor = 0.0
        self.voltage = 0.0
        self.temperature_motor = 0.0
        self.temperature_core = 0.0
        self.fault_bank_a = 0
        self.fault_bank_b = 0
        self.warning_bank_a = 0
        self.warning_bank_b = 0


class BaseFeedback:
    def __init__(self) -> None:
        self.active_state_connection_identifier = 0
        self.active_state = 0
        self.arm_voltage = 0.0  # V
        self.arm_current = 0.0  # A
        self.fault_bank_a = 0
        self.fault_bank_b = 0
        self.warning_bank_a = 0
        self.warning_bank_b = 0


class Feedback:
    def __init__(self) -> None:
        self.frame_id = 0
        self.base = BaseFeedback()
        self.actuators = []
        self.interconnect = None
