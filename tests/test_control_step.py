"""The control step (ahrm_stack.env.control_step): action <-> filter request in both directions,
checked against the closed forms (a joint action entry of 1 is that joint's velocity limit; a
Cartesian entry of 1 is cartesian_max_speed along that world axis), the filter method per mode,
the runner's step on an action against the same step on the closed-form request, and the task's
joint addresses against MuJoCo's own placement of the bodies."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.config import load_config
from ahrm_stack.env.control_step import (ControlStep, action_to_command, command_to_action,
                                         filter_call, make_task_filter)
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask

CONFIG = load_config()
LIMIT = np.array([0.8, 0.9, 1.0, 1.1, 1.2, 1.3])  # rad/s, distinct per joint
COMMANDED = (0, 1, 2, 3, 4)


@dataclasses.dataclass(frozen=True)
class Arm:  # the two fields of a RobotDescription the maps read, plus the joint count
    velocity_limit: np.ndarray
    commanded_joints: tuple[int, ...]

    @property
    def num_joints(self) -> int:
        return len(self.velocity_limit)


def _step(mode: str, speed: float = 0.5) -> ControlStep:
    action = dataclasses.replace(CONFIG.task.action, mode=mode, cartesian_max_speed=speed)
    return ControlStep(Arm(LIMIT, COMMANDED), action)


finite = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(st.lists(finite, min_size=5, max_size=5))
def test_joint_action_is_the_fraction_of_each_velocity_limit(values):
    action = np.array(values)
    request = _step("joint").request(action)
    expected = np.zeros(6)
    for j in COMMANDED:  # closed form, entry by entry
        expected[j] = max(-1.0, min(1.0, values[j])) * LIMIT[j]
    np.testing.assert_array_equal(request, expected)
    assert request[5] == 0.0  # the uncommanded joint holds still


@settings(max_examples=100, deadline=None)
@given(st.lists(finite, min_size=3, max_size=3), st.floats(0.05, 2.0))
def test_cartesian_action_is_the_tip_velocity_over_the_speed_cap(values, speed):
    request = _step("cartesian", speed).request(np.array(values))
    expected = [max(-1.0, min(1.0, v)) * speed for v in values]  # m/s, world x, y, z
    np.testing.assert_array_equal(request, expected)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5),
       st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_the_inverse_map_recovers_the_action(joint, cartesian):
    for mode, values in (("joint", joint), ("cartesian", cartesian)):
        step = _step(mode)
        action = np.array(values)
        np.testing.assert_allclose(step.action(step.request(action)), action, rtol=0, atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5),
       st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3))
def test_the_forward_map_recovers_a_request_within_the_scale(fractions, tip):
    joint = _step("joint")
    request = np.zeros(6)
    request[list(COMMANDED)] = np.array(fractions) * LIMIT[list(COMMANDED)]
    np.testing.assert_allclose(joint.request(joint.action(request)), request, rtol=1e-15, atol=0)
    cartesian = _step("cartesian", 0.5)
    np.testing.assert_allclose(cartesian.request(cartesian.action(np.array(tip))), tip, rtol=1e-15,
                               atol=0)


def test_the_inverse_map_is_not_clipped_and_matches_the_closed_form():
    step = _step("joint")
    request = np.array([1.6, -0.45, 0.0, 2.2, 0.6, 9.0])  # joint 6 is not commanded: ignored
    np.testing.assert_allclose(step.action(request), [2.0, -0.5, 0.0, 2.0, 0.5])
    np.testing.assert_allclose(_step("cartesian", 0.4).action(np.array([0.8, -0.2, 0.1])),
                               [2.0, -0.5, 0.25])
    np.testing.assert_array_equal(command_to_action(request, LIMIT, COMMANDED),
                                  step.action(request))


def test_non_finite_actions_become_zero_or_stay_faults():
    joint, cartesian = _step("joint"), _step("cartesian", 0.5)
    action = np.array([np.nan, 0.5, np.inf, -np.inf, -2.0])
    np.testing.assert_array_equal(joint.request(action), [0.0, 0.45, 0.0, 0.0, -1.2, 0.0])
    faults = joint.request_keeping_faults(action)
    np.testing.assert_array_equal(faults, [np.nan, 0.45, np.nan, np.nan, -1.2, 0.0])
    tip = np.array([0.5, np.nan, -np.inf])
    np.testing.assert_array_equal(cartesian.request(tip), [0.25, 0.0, 0.0])
    np.testing.assert_array_equal(cartesian.request_keeping_faults(tip), [0.25, np.nan, np.nan])
    assert cartesian.request_keeping_faults(tip).dtype == np.float64


@pytest.mark.parametrize("mode, bad", [("joint", np.zeros(4)), ("joint", np.zeros(6)),
                                       ("joint", np.float64(0.3)), ("cartesian", np.zeros(5)),
                                       ("cartesian", np.zeros((1, 3)))])
def test_a_wrong_sized_action_is_refused_never_broadcast(mode, bad):
    step = _step(mode)
    with pytest.raises(ValueError, match=rf"action.mode {mode}: the action must have shape"):
        step.request(bad)
    with pytest.raises(ValueError, match=rf"action.mode {mode}"):
        step.request_keeping_faults(np.zeros(step.action_size + 1))


def test_sizes_and_the_old_joint_map_agree():
    assert (_step("joint").action_size, _step("joint").request_size) == (5, 6)
    assert (_step("cartesian").action_size, _step("cartesian").request_size) == (3, 3)
    action = np.array([0.1, -0.2, 0.3, 1.5, np.nan])
    np.testing.assert_array_equal(action_to_command(action, LIMIT, COMMANDED),
                                  _step("joint").request(action))


def test_the_filter_method_follows_the_request():
    class Filter:
        def __call__(self, *args):
            return "joint"

        def cartesian(self, *args):
            return "cartesian"

    f = Filter()
    assert filter_call(f, cartesian=True)() == "cartesian" and filter_call(f, False)() == "joint"
    assert _step("cartesian").filter_call(f)() == "cartesian"
    assert _step("joint").filter_call(f)() == "joint"


@pytest.fixture(scope="module")
def task_runner():
    task = PushOffTask(CONFIG.task)
    return task, TaskRunner(task, seed=3, safety=CONFIG.safety)


@pytest.mark.parametrize("mode", ["cartesian", "joint"])
def test_a_step_on_an_action_is_the_step_on_its_closed_form_request(mode, task_runner):
    """The same episode twice: stepped on actions, then on the requests computed here by hand;
    the filtered commands and the states are bit-identical."""
    if mode == CONFIG.task.action.mode:
        runner = task_runner[1]
    else:
        config = load_config([f"task.action.mode={mode}"])
        runner = TaskRunner(PushOffTask(config.task), safety=config.safety)
    robot, speed = runner.task.robot, runner.task.config.action.cartesian_max_speed
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, (8, runner.control.action_size))
    record = []
    for by_hand in (False, True):
        runner.seed(11)
        runner.reset()
        for action in actions:
            if not by_hand:
                runner.step_action(action)
            elif mode == "cartesian":
                runner.step_cartesian(np.clip(action, -1, 1) * speed)
            else:
                request = np.zeros(robot.num_joints)
                for k, j in enumerate(robot.commanded_joints):
                    request[j] = np.clip(action[k], -1, 1) * robot.velocity_limit[j]
                runner.step_only(request)
            record.append((runner.last_filter_result.command.copy(), runner.physics.data.qpos.copy()))
    assert len(record) == 2 * len(actions)
    for (u, q), (u_hand, q_hand) in zip(record[:len(actions)], record[len(actions):]):
        np.testing.assert_array_equal(u, u_hand)
        np.testing.assert_array_equal(q, q_hand)


def test_the_task_filter_has_the_task_s_period_or_the_one_given(task_runner):
    task, runner = task_runner
    runner.reset()
    assert runner.filter.dt == CONFIG.task.episode.control_period
    assert make_task_filter(task, CONFIG.safety, scene=runner._scene, control_period=0.01).dt == 0.01


def test_the_joint_addresses_place_every_body_where_mujoco_puts_it(task_runner):
    """Write a distinct pose into each free joint's address and compare MuJoCo's body frames;
    write joint angles and read the arm's joint positions back through MuJoCo's named joints."""
    task, runner = task_runner
    runner.reset()
    physics, at = runner.physics, task.addresses
    model, data = physics.model.ptr, physics.data.ptr
    props = [task.cube, *task.obstacles]
    qpos = np.vstack([at.cube_qpos, at.obstacle_qpos])
    dofs = np.vstack([at.cube_dof, at.obstacle_dof])
    assert qpos.shape == (len(props), 7) and dofs.shape == (len(props), 3)
    rng = np.random.default_rng(1)
    for k, prop in enumerate(props):
        position = rng.uniform(-1, 1, 3)
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        data.qpos[qpos[k]] = np.concatenate([position, quaternion])
        velocity = rng.uniform(-1, 1, 3)
        data.qvel[dofs[k]] = velocity
        mujoco.mj_forward(model, data)
        body = int(physics.bind(prop.geom).bodyid)
        np.testing.assert_allclose(data.xpos[body], position, atol=1e-12)
        np.testing.assert_allclose(data.xquat[body], quaternion * np.sign(
            quaternion[0] * data.xquat[body][0]), atol=1e-12)
        twist = np.zeros(6)  # mj_objectVelocity: (angular, linear) in the world frame
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, body, twist, 0)
        np.testing.assert_allclose(twist[3:], velocity, atol=1e-12)
    q = rng.uniform(-1, 1, task.robot.num_joints)
    data.qpos[at.arm_qpos] = q
    for k, joint in enumerate(task.arm.joints):
        assert physics.named.data.qpos[joint.full_identifier] == q[k]
    runner.reset()
