"""The command path of a real arm: a command reaches the velocity actuators ``command_latency`` s
after it is sent and they follow it through a first-order lag of time constant ``actuator_lag``
(:class:`ActuatorModel`). Training's runner and the sim backend's arm step the same object, one
physics step at a time."""

from __future__ import annotations

import collections
import math
from typing import Iterator

import numpy as np

from ahrm_stack.realism.config import RealismConfig


class ActuatorModel:
    """Commands reaching the velocity actuators late (``command_latency``) and through a first-order
    lag (``actuator_lag``), advanced one physics step at a time. ``latency`` is rounded to whole
    physics steps (``timestep`` s). Ideal (no latency, no lag) it passes each command on at the next
    step."""

    def __init__(self, realism: RealismConfig, timestep: float, num_joints: int) -> None:
        self.delay_steps = int(round(realism.command_latency / timestep))
        tau = realism.actuator_lag
        self.alpha = 1.0 if tau <= 0 else 1.0 - math.exp(-timestep / tau)
        self._pending: collections.deque[tuple[int, np.ndarray]] = collections.deque()
        self._target = np.zeros(num_joints)  # the command the actuators are converging to, rad/s
        self.output = np.zeros(num_joints)  # what the actuators apply now, rad/s
        self._step = 0

    @property
    def in_flight(self) -> bool:
        """Whether a command sent has not yet taken effect."""
        return bool(self._pending)

    @property
    def target(self) -> np.ndarray:
        """The latest command to have reached the actuators (rad/s): what they converge to."""
        return self._target.copy()

    def upcoming(self, after: int = 0) -> np.ndarray:
        """The command the actuators converge to from the next physics step (``after`` steps from
        now): the target, or the latest command in flight due by then (rad/s)."""
        due = [command for step, command in self._pending if step <= self._step + int(after)]
        return (due[-1] if due else self._target).copy()

    def reset(self, command: np.ndarray | None = None) -> None:
        """At rest (or holding ``command`` already), nothing in flight."""
        self._pending.clear()
        value = np.zeros_like(self.output) if command is None else np.asarray(command, float)
        self._target = value.copy()
        self.output = value.copy()

    def command(self, command: np.ndarray, after: int = 0) -> None:
        """A command sent now, or ``after`` physics steps from now (a caller whose clock runs ahead
        of the physics it has stepped): it takes effect ``delay_steps`` physics steps later."""
        self._pending.append((self._step + int(after) + self.delay_steps, np.asarray(command, float).copy()))

    def hold(self, command: np.ndarray) -> None:
        """The arm's own stop (or any command it takes at once): everything in flight dropped, the
        actuators converging to ``command`` (rad/s) from the next step, through the lag."""
        self._pending.clear()
        self._target = np.asarray(command, float).copy()

    def stop_now(self) -> None:
        """Everything in flight dropped and the actuators at zero at once."""
        self.reset()

    def step(self) -> np.ndarray:
        """The actuators' command for the next physics step (rad/s); call once per step."""
        while self._pending and self._pending[0][0] <= self._step:
            self._target = self._pending.popleft()[1]
        if self.alpha == 1.0:  # no lag: the command itself (not output + (target - output))
            self.output = self._target.copy()
        else:
            self.output = self.output + self.alpha * (self._target - self.output)
        self._step += 1
        return self.output

    def run(self, steps: int) -> Iterator[tuple[int, np.ndarray]]:
        """The next ``steps`` physics steps as runs of one output: ``(count, rad/s)`` pairs, each
        to be applied for ``count`` steps (one step per run under a lag; without one, a run lasts
        until the next command in flight takes effect). The same outputs as :meth:`step` per step."""
        while steps > 0:
            output = self.step()
            count = 1
            if self.alpha == 1.0:
                until = self._pending[0][0] if self._pending else self._step + steps
                count = max(1, min(steps, until - self._step + 1))
                self._step += count - 1
            yield count, output
            steps -= count
