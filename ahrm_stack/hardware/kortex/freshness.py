"""Feedback freshness without an arm clock.

Kortex feedback carries no timestamp, and ``Feedback.frame_id`` is not the arm's counter: it
echoes the ``frame_id`` of the client's last ``BaseCyclic.Command`` (Kinova's
api_python/examples/108-Gen3_torque_control/01-torque_control_cyclic.py sets
``base_command.frame_id += 1`` itself, wrapping at 65535, and copies it into each actuator's
``command_id``; Kinovarobotics/ros2_kortex, kortex_driver/src/hardware_interface.cpp, does the same
with ``base_command_.set_frame_id(base_command_.frame_id() + 1)`` and judges no freshness at all:
it takes each synchronous ``RefreshFeedback`` answer as current). An adapter that sends joint
speeds through ``Base`` (single-level servoing) sends no cyclic command, so ``frame_id`` never
moves; an arm counter built on it calls every frame stale.

So each frame is stamped on the adapter's clock when its request was sent (the arm measured it
after that, within one 1 kHz cycle: the stamp is never younger than the measurement by more than
1 ms, and its age includes the whole round trip), and a frozen arm is detected from what the frame
does carry: its analogue readings. A powered arm's motor currents, voltages and torques are
sampled with noise at 1 kHz, so two fresh frames are never equal in every reading; a frame equal
to the previous one in all of them is that frame again (a frozen base or a replayed answer). It
keeps the first copy's id and stamp, so the deploy loop's stale check (a frame id that does not
increase, an old stamp) stops the arm.
"""

from __future__ import annotations

from typing import Hashable


#: The readings of the plain-valued frame (ahrm_stack.hardware.kortex.vendor_link) compared between frames.
FINGERPRINT_KEYS = ("position", "velocity", "torque", "current_motor", "voltage",
                    "temperature_core", "arm_voltage", "arm_current")


def fingerprint(frame: dict) -> Hashable:
    """The frame's analogue readings as one comparable value: their exact text (``repr`` of a
    float round-trips), so equal readings compare equal whatever the objects, NaN included."""
    return repr([frame.get(key) for key in FINGERPRINT_KEYS])


class FrameFreshness:
    """Frame ids and stamps on the adapter's clock.

    :meth:`update` takes a frame's :func:`fingerprint` and the time (s, adapter clock) its request
    was sent; it returns ``(frame_id, timestamp)``: a new frame gets the next id and that time; a
    repeat of the previous frame its id and stamp again (:attr:`repeats` counts them).
    """

    def __init__(self) -> None:
        self._last: Hashable = None
        self.frame_id = 0
        self.timestamp = float("-inf")
        self.repeats = 0

    def update(self, key: Hashable, sent: float) -> tuple[int, float]:
        if self.frame_id and key == self._last:
            self.repeats += 1
            return self.frame_id, self.timestamp
        self._last = key
        self.frame_id += 1
        self.timestamp = float(sent)
        return self.frame_id, self.timestamp
