"""The control step in one place: a policy action ↔ a safety-filter request, and the filter.

Everything that drives the arm — the TorchRL environment, the scripted demonstrations and the
deploy loop — goes through this module, so an action means the same thing in training, in the
demonstrations' labels and on the robot:

* **action** (what a policy outputs): a normalised vector in [-1, 1], shaped by
  ``task.action.mode``:

  - ``joint``: one entry per *commanded* joint (:attr:`RobotDescription.commanded_joints`), the
    fraction of that joint's velocity limit (:attr:`RobotDescription.velocity_limit`, rad/s);
  - ``cartesian``: the pusher tip's linear velocity in the world frame as a fraction of
    ``task.action.cartesian_max_speed`` (m/s), per axis.

* **request** (what the safety filter takes, :func:`filter_call` picks the method):

  - ``joint``: joint velocities of *all* arm joints, rad/s (joints that are not commanded get 0);
    the filter's ``__call__`` projects them onto the safe set;
  - ``cartesian``: the tip velocity, m/s, world frame; :meth:`SafetyFilter.cartesian` turns it
    into joint velocities by differential IK under the same constraints.

The forward map (:meth:`ControlStep.request`) turns non-finite entries into 0 and clips to
[-1, 1]; the deploy loop uses :meth:`ControlStep.request_keeping_faults` instead, where a
non-finite entry stays NaN so that the loop stops the arm on it. The inverse map
(:meth:`ControlStep.action`) turns a controller's request back into the action that reproduces
it (the scripted demonstrations' labels); ``request(action(r)) == r`` for every request whose
action lies in [-1, 1] (and whose uncommanded joints are 0).

:func:`make_task_filter` builds the filter for a task (its arm, kinematics, control period,
table and pusher sites): the one place the filter's constructor arguments are spelled out.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Protocol

import numpy as np

from ahrm_stack.config import ActionConfig, SafetyConfig, TaskConfig
from ahrm_stack.robot import RobotDescription
from ahrm_stack.safety import FilterResult, SafetyFilter, make_filter

if TYPE_CHECKING:
    from ahrm_stack.kinematics.model import ArmKinematics
    from ahrm_stack.kinematics.scene import CollisionScene

JOINT = "joint"
CARTESIAN = "cartesian"
TIP_DIM = 3  # the tip's linear velocity: x, y, z (m/s, world frame)


def check_action_shape(action: np.ndarray, expected: tuple[int, ...], mode: str) -> None:
    """Raise ``ValueError`` unless ``action`` has exactly shape ``expected``: a wrong-sized action
    is a bug upstream, and broadcasting it would drive every joint with one value."""
    if np.shape(action) != expected:
        raise ValueError(f"action.mode {mode}: the action must have shape {expected}, got "
                         f"{np.shape(action)}")


def action_to_command(action: np.ndarray, velocity_limit: np.ndarray,
                      commanded: tuple[int, ...]) -> np.ndarray:
    """Map a normalised action of the commanded joints to joint velocities (rad/s) for all joints.

    ``action`` must have shape ``(len(commanded),)``: one value per commanded joint, never
    broadcast (a ``ValueError`` says what came). Non-finite entries become 0 and the action is
    clipped to [-1, 1]; joints that are not commanded get 0. ``velocity_limit``: rad/s, all joints.
    """
    action = np.asarray(action, dtype=float)
    check_action_shape(action, (len(commanded),), JOINT)
    action = np.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)
    command = np.zeros(len(velocity_limit))
    command[list(commanded)] = np.clip(action, -1.0, 1.0) * velocity_limit[list(commanded)]
    return command


def command_to_action(command: np.ndarray, velocity_limit: np.ndarray,
                      commanded: tuple[int, ...]) -> np.ndarray:
    """The inverse of :func:`action_to_command` (not clipped): ``command[j] / velocity_limit[j]``
    for the commanded joints j. ``command``: joint velocities of all joints, rad/s."""
    commanded = list(commanded)
    return np.asarray(command)[commanded] / velocity_limit[commanded]


def filter_call(safety_filter: SafetyFilter,
                cartesian: bool) -> Callable[..., FilterResult]:
    """The filter method that takes a request: :meth:`SafetyFilter.cartesian` for a tip velocity
    (m/s, world frame), the filter itself for joint velocities (rad/s). Either is called as
    ``(q, dq, request, u_prev=None)`` and returns a :class:`FilterResult` whose ``command`` is
    joint velocities, rad/s."""
    return safety_filter.cartesian if cartesian else safety_filter


def request_size(robot: RobotDescription, cartesian: bool) -> int:
    """Entries of a filter request: 3 (tip velocity) or the arm's joint count."""
    return TIP_DIM if cartesian else robot.num_joints


class ControlStep:
    """The action ↔ request maps of one arm in one action mode (``task.action``).

    Args:
        robot: the arm (velocity limits in rad/s, the commanded joints).
        action: ``task.action``: ``mode`` (``joint`` or ``cartesian``) and
            ``cartesian_max_speed`` (m/s: the tip speed per axis of an action entry of 1).
    """

    def __init__(self, robot: RobotDescription, action: ActionConfig) -> None:
        if action.mode not in (JOINT, CARTESIAN):
            raise ValueError(f"task.action.mode: {action.mode!r} is not allowed; choose one of "
                             f"{[JOINT, CARTESIAN]}")
        self.mode = action.mode
        self.cartesian = action.mode == CARTESIAN
        self.max_tip_speed = float(action.cartesian_max_speed)  # m/s
        self.velocity_limit = robot.velocity_limit  # rad/s, all joints
        self.commanded = tuple(robot.commanded_joints)
        self.action_size = TIP_DIM if self.cartesian else len(self.commanded)
        self._commanded_index = np.asarray(self.commanded, dtype=int)
        self._commanded_limit = self.velocity_limit[self._commanded_index]
        self.request_size = request_size(robot, self.cartesian)
        self.smoothing = float(action.smoothing)  # in [0, 1); 0: requests pass unchanged
        self._previous: np.ndarray | None = None  # the last smoothed request of this episode

    def reset(self) -> None:
        """Start an episode: the next request is not blended with any earlier one."""
        self._previous = None

    def smooth(self, request: np.ndarray) -> np.ndarray:
        """Exponential smoothing of a policy's requests (``task.action.smoothing`` = s): the first
        request of an episode passes unchanged, each later one becomes
        ``s * previous + (1 - s) * request`` (the previous *smoothed* request; same units as the
        request). A non-finite request passes unchanged and is not remembered (the deploy loop
        stops on it). With s = 0 this returns ``request`` itself. It acts before the safety
        filter, which still sees every request that reaches the arm."""
        if self.smoothing == 0.0:
            return request
        if not np.isfinite(request).all():
            return request
        if self._previous is None:
            self._previous = np.array(request, dtype=float)
            return request
        blended = self.smoothing * self._previous + (1.0 - self.smoothing) * np.asarray(request, dtype=float)
        self._previous = blended
        return blended.copy()

    def request(self, action: np.ndarray) -> np.ndarray:
        """The filter request for a normalised ``action`` of shape ``(action_size,)`` (a wrong
        shape is a ``ValueError``, never broadcast): non-finite entries become 0, the rest are
        clipped to [-1, 1] and scaled — to the tip velocity (m/s, world frame; the action's float
        type is kept) or to joint velocities of all joints (rad/s, float64)."""
        if not self.cartesian:
            return action_to_command(action, self.velocity_limit, self.commanded)
        action = np.asarray(action)
        check_action_shape(action, (TIP_DIM,), CARTESIAN)
        finite = np.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)
        return np.clip(finite, -1.0, 1.0) * self.max_tip_speed

    def request_keeping_faults(self, action: np.ndarray) -> np.ndarray:
        """As :meth:`request` (float64, a new array), but an entry whose action is NaN or infinite
        is NaN in the request: for the deploy loop, which stops the arm on it (a broken policy is a
        fault, never a silent zero). A finite action of the right size takes the same arithmetic
        without :meth:`request`'s checks (the deploy loop calls this every tick)."""
        action = np.array(action, dtype=float).reshape(-1)  # a copy: written in place below
        if action.shape == (self.action_size,) and np.isfinite(action).all():
            np.clip(action, -1.0, 1.0, out=action)
            if self.cartesian:
                action *= self.max_tip_speed
                return action
            command = np.zeros(len(self.velocity_limit))
            command[self._commanded_index] = action * self._commanded_limit
            return command
        request = self.request(action)
        bad = ~np.isfinite(action)
        if self.cartesian:
            request[bad] = np.nan
        else:
            request[np.asarray(self.commanded, dtype=int)[bad]] = np.nan
        return request

    def action(self, request: np.ndarray) -> np.ndarray:
        """The normalised action that reproduces ``request`` (not clipped: a request beyond the
        scale gives entries beyond ±1): the tip velocity (m/s, world frame) over
        ``cartesian_max_speed``, or the commanded joints' velocities (rad/s) over their limits."""
        if self.cartesian:
            return np.asarray(request) / self.max_tip_speed
        return command_to_action(request, self.velocity_limit, self.commanded)

    def filter_call(self, safety_filter: SafetyFilter) -> Callable[..., FilterResult]:
        """The filter method for this mode's requests (:func:`filter_call`)."""
        return filter_call(safety_filter, self.cartesian)


class FilterTask(Protocol):
    """What :func:`make_task_filter` reads of a task: :class:`~ahrm_stack.env.task.PushOffTask`
    has it. (Named here, not imported: the task imports this module, for the observation's
    previous action.)"""

    @property
    def config(self) -> TaskConfig: ...

    @property
    def robot(self) -> RobotDescription: ...

    @property
    def kinematics(self) -> ArmKinematics: ...

    @property
    def pusher(self) -> Any:
        """The pusher entity: its ``tip_site`` (an MJCF site) is the filter's tip point."""

    @property
    def arm(self) -> Any:
        """The arm entity: its ``wrist_site`` (an MJCF site) is the filter's wrist point."""


def make_task_filter(task: FilterTask, safety: SafetyConfig, *,
                     scene: CollisionScene | None = None,
                     control_period: float | None = None) -> SafetyFilter:
    """The safety filter for ``task``'s arm: its robot description and Pinocchio model, the
    pusher tip and wrist sites, the table height (m) and the control period (s; default
    ``task.episode.control_period``, the deploy loop passes its own). ``scene``: the task's
    collision scene (:meth:`PushOffTask.make_collision_scene`), needed for the obstacle and
    self-collision rows."""
    config = task.config
    period = config.episode.control_period if control_period is None else control_period
    return make_filter(task.robot, task.kinematics, safety, control_period=period,
                       table_height=config.table.height, tip_site=task.pusher.tip_site,
                       wrist_site=task.arm.wrist_site, scene=scene)


__all__ = ["CARTESIAN", "JOINT", "ControlStep", "FilterTask", "action_to_command", "check_action_shape",
           "command_to_action", "filter_call", "make_task_filter", "request_size"]
