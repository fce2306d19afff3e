"""ppo.lane_frame (issue 18): the policy reads the world mirrored x -> -x when its episode's lane is
-x. The mirror is checked against the simulator's own symmetry (a layout and its mirror image,
the tip placed by IK at the mirrored point), the actor's equivariance and log-probabilities by
hand, and the lever end to end: config errors, the trainer's normaliser, checkpoints, deploy."""

from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import TanhNormal

from ahrm_stack.config import ConfigError, load_config
from ahrm_stack.deploy.policy import NumpyPolicy
from ahrm_stack.env.layout import Layout
from ahrm_stack.env.start_pose import solve_start_pose
from ahrm_stack.env.torchrl_env import PushOffEnv
from ahrm_stack.learning.lane_frame import lane_mirror_for, observation_layout
from ahrm_stack.learning.ppo import lean_actor, lean_collection_actor, make_modules
from ahrm_stack.learning.start_states import StartState

FRAME = ["profile=scratch", "ppo.lane_frame=mirror", "task.realism=ideal"]  # the exact reflection
TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=64", "ppo.mini_batch_size=32", "train.num_envs=1"]


def _mirror_quaternion(q: np.ndarray) -> np.ndarray:
    """The orientation of a body reflected in the plane x = 0 (R -> M R M, M = diag(-1, 1, 1))."""
    w, x, y, z = q
    return np.array([w, x, -y, -z])


def _mirrored_world(env: PushOffEnv, safety) -> tuple[PushOffEnv, np.ndarray]:
    """A second environment whose cube and obstacles are ``env``'s reflected in x = 0 (positions,
    orientations, velocities) and whose pusher tip is placed, by the task's IK, at the reflected
    tip pointing down. Returns it and its first observation."""
    task, physics = env.task, env.runner.physics
    addresses = task.addresses
    other = PushOffEnv(task.config, safety, seed=99)
    other.reset()
    o_task, o_physics = other.task, other.runner.physics
    qpos, qvel = physics.data.qpos.copy(), physics.data.qvel.copy()
    for rows in [addresses.cube_qpos, *addresses.obstacle_qpos]:
        qpos[rows[0]] *= -1.0
        qpos[rows[3:7]] = _mirror_quaternion(qpos[rows[3:7]])
    for rows in [addresses.cube_dof, *addresses.obstacle_dof]:
        qvel[rows[0]] *= -1.0  # linear velocity x
        qvel[rows[0] + 4:rows[0] + 6] *= -1.0  # angular velocity about y and z
    tip = task.step_info.tip.copy()
    target = np.array([-tip[0], tip[1], tip[2]])
    result = solve_start_pose(o_physics.model.ptr, o_physics.data.ptr, o_task.addresses.arm_qpos,
                              o_task.addresses.arm_dof, o_task._tip_site_id, target,
                              np.asarray(task.config.arm.home), o_task.robot.position_lower,
                              o_task.robot.position_upper, o_task._is_arm, task.config.arm.start_ik)
    assert result.ok
    qpos[addresses.arm_qpos] = result.q
    layout = Layout(task.layout.cube_xy * [-1, 1], task.layout.obstacle_xy * [-1, 1])
    o_task.start_states = lambda random_state: StartState(layout, qpos, qvel)
    td = other.reset()
    return other, td["observation"].numpy().astype(float)


@pytest.mark.parametrize("seed", [0, 5])
def test_the_mirror_is_the_simulators_reflection_in_x(seed):
    config = load_config(FRAME)
    env = PushOffEnv(config.task, config.safety, seed=seed)
    observation = env.reset()["observation"].numpy().astype(float)
    robot = env.task.robot
    layout = observation_layout(config.task, robot.num_joints, len(robot.commanded_joints))
    assert max(s.stop for s in layout.values()) == observation.size
    mirror = lane_mirror_for(config, observation.size, 3)
    other, mirrored = _mirrored_world(env, config.safety)
    # the lane and the lanes' clearances are the world's: the reflection swaps them
    lanes = layout["lane_clearance"]
    assert np.allclose(mirrored[lanes], observation[lanes][::-1], atol=1e-9)
    if abs(observation[lanes][0] - observation[lanes][1]) > 2e-3:  # not a tie decided by the tip
        choice = layout["lane_choice"]
        assert np.array_equal(mirrored[choice], observation[choice][::-1])
    # the reflected world, read in its lane frame, is the original read in its own
    framed = mirror(torch.as_tensor(observation, dtype=torch.float32)).numpy()
    framed_other = mirror(torch.as_tensor(mirrored, dtype=torch.float32)).numpy()
    exact = [layout[k] for k in ("cube", "obstacle_0", "obstacle_1", "obstacle_2", "obstacle_3",
                                 "lane_clearance", "lane_choice")]
    for part in exact:
        assert np.allclose(framed[part], framed_other[part], atol=1e-5), part
    tol = config.task.arm.start_ik.position_tolerance + 1e-5  # the tip is where IK put it
    for part in (layout["pusher_tip"], slice(layout["relative_to_cube"].start, layout["relative_to_cube"].start + 3)):
        assert np.allclose(framed[part], framed_other[part], atol=tol)
    assert np.array_equal(framed[layout["phase"]], framed_other[layout["phase"]])
    # one of the two was mirrored: its x coordinates changed sign
    tip = layout["pusher_tip"].start
    mirrored_one = framed if observation[layout["lane_choice"]][1] > 0.5 else framed_other
    source = observation if mirrored_one is framed else mirrored
    assert mirrored_one[tip] == pytest.approx(-source[tip], abs=1e-6)
    env.close()
    other.close()


def test_mirror_no_joints_zeroes_the_joint_entries_only():
    config = load_config([*FRAME[:1], "ppo.lane_frame=mirror_no_joints"])
    env = PushOffEnv(config.task, config.safety, seed=2)
    observation = torch.as_tensor(env.reset()["observation"], dtype=torch.float32)
    layout = observation_layout(config.task, 6, 5)
    framed = lane_mirror_for(config, observation.numel(), 3)(observation)
    for name, part in layout.items():
        if name in ("joints_pos", "joints_vel", "previous_action"):
            assert torch.all(framed[part] == 0), name
        else:
            assert torch.any(framed[part] != 0) or torch.all(observation[part] == 0), name
    env.close()


def _modules(config, dim=75):
    mirror = lane_mirror_for(config, dim, 3, 6, 5)
    modules = make_modules(config.ppo, dim, 3, mirror)
    observation = torch.randn(64, dim)
    observation[:, 73:75] = 0.0
    observation[:32, 73] = 1.0  # lane +x
    observation[32:, 74] = 1.0  # lane -x
    modules.normalizer.update(modules.framed(observation))
    return modules, observation


def test_actor_mirrors_its_x_action_with_the_lane():
    modules, observation = _modules(load_config(FRAME))
    mirror = modules.mirror
    plus = observation[:32]
    reflected = plus[:, mirror.permutation] * mirror.sign  # the same world reflected: lane -x
    assert torch.all(reflected[:, 74] == 1.0)
    act = lean_actor(modules.actor).act
    a, b = act(plus), act(reflected)
    assert torch.allclose(a[:, 0], -b[:, 0]) and torch.allclose(a[:, 1:], b[:, 1:])
    # by hand: the network's mean of the framed observation, x negated for lane -x, through tanh
    net, norm = lean_actor(modules.actor).net, modules.normalizer
    loc = net(norm(mirror(observation[32:])))[0].detach()
    expected = torch.tanh(loc * torch.tensor([-1.0, 1.0, 1.0]))
    assert torch.allclose(act(observation[32:]), expected, atol=1e-6)
    # deploy's NumPy forward carries the frame: the same actions on both lanes, and the inputs
    # are not changed by the in-place framing
    policy = NumpyPolicy.from_actor(modules.actor)
    assert policy is not None
    for row, want in zip(observation.numpy().astype(np.float64), act(observation).numpy()):
        kept = row.copy()
        np.testing.assert_allclose(policy(row), want, atol=1e-5, rtol=0)
        np.testing.assert_array_equal(row, kept)


def test_lean_collection_actor_matches_the_torchrl_actor_in_the_lane_frame():
    modules, observation = _modules(load_config(FRAME))
    lean = lean_collection_actor(modules.actor)
    for exploration in (ExplorationType.RANDOM, ExplorationType.DETERMINISTIC):
        with set_exploration_type(exploration):
            torch.manual_seed(3)
            reference = modules.actor(TensorDict({"observation": observation}, [64]))
            torch.manual_seed(3)
            fast = lean(TensorDict({"observation": observation}, [64]))
        for key in ("observation_norm", "loc", "scale", "action", "action_log_prob", "action_sign"):
            assert torch.allclose(reference[key], fast[key], atol=1e-6), key
    # log-probability of a world action = the frame's log-probability of the mirrored action
    # (a sign change has a unit Jacobian: PPO's ratios are the frame's)
    sign, scale = reference["action_sign"], reference["scale"]
    world = TanhNormal(reference["loc"], scale, low=-1.0, high=1.0)
    framed = TanhNormal(reference["loc"] * sign, scale, low=-1.0, high=1.0)
    action = reference["action"].clamp(-0.99, 0.99)
    assert torch.allclose(world.log_prob(action), framed.log_prob(action * sign), atol=1e-5)
    assert torch.allclose(modules.actor.get_dist(reference).log_prob(action), world.log_prob(action), atol=1e-5)


@pytest.mark.parametrize("overrides, key", [
    (["ppo.lane_frame=mirror", "task.observation.lane_choice=false"], "task.observation.lane_choice"),
    (["ppo.lane_frame=mirror", "task.action.mode=joint"], "task.action.mode"),
    (["ppo.lane_frame=mirror", "task.layout.lane_directions=[+x]"], "task.layout.lane_directions"),
    (["ppo.lane_frame=sideways"], "ppo.lane_frame"),
])
def test_bad_lane_frame_names_the_key(overrides, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config(overrides)


def test_trainer_learns_in_the_lane_frame_and_checkpoints_keep_it(tmp_path):
    import yaml

    from ahrm_stack.learning.rollouts import load_policy
    from ahrm_stack.learning.trainer import Trainer

    config = load_config([*FRAME, *TINY, "task.episode.duration=1.0", "train.time_limit=0.5"])
    trainer = Trainer(config)
    assert trainer.modules.mirror is not None
    trainer.iteration()
    # the normaliser saw framed observations: every episode's lane reads +x there
    choice = slice(73, 75)
    assert torch.allclose(trainer.modules.normalizer.mean[choice], torch.tensor([1.0, 0.0]))
    observation = torch.zeros(2, 75)
    observation[0, 73] = observation[1, 74] = 1.0
    observation[:, 18:21] = torch.tensor([0.05, 0.0, 0.45])
    expected = lean_actor(trainer.modules.actor).act(observation)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(trainer.config.to_dict(), sort_keys=False))
    trainer.save_policy(tmp_path / "policy.pt")
    _, policy = load_policy(tmp_path)
    assert policy.mirror is not None and torch.allclose(policy.act(observation), expected)
    trainer.close()


SCRATCH_RUN = (Path(__file__).resolve().parents[1] / "docs" / "scratch-study" / "round5" / "runs"
               / "mirror-nj-ahrm-seed0")


def test_numpy_policy_gives_the_committed_scratch_policys_action_on_both_lanes():
    """Round 5's committed policy (lane frame, joints zeroed) through deploy's NumPy forward:
    the action of ``LeanActor.act`` on the task's own observations, episodes of either lane."""
    from ahrm_stack.learning.rollouts import load_policy

    config, lean = load_policy(SCRATCH_RUN, SCRATCH_RUN / "policies" / "episode-20472.pt")
    policy = NumpyPolicy.from_actor(lean)
    assert policy is not None
    env = PushOffEnv(config.task, config.safety, seed=3)
    lanes, worst = set(), 0.0
    for _ in range(6):
        td = env.reset()
        for _ in range(30):
            observation = td["observation"]
            lanes.add(int(observation[74] > 0.5))
            want = lean.act(observation).numpy()
            got = policy(observation.numpy().astype(np.float64))
            worst = max(worst, float(np.abs(got - want).max()))
            td = env.step(td.set("action", torch.as_tensor(want)))["next"]
    env.close()
    assert lanes == {0, 1}  # both lanes were seen
    assert worst <= 1e-5, worst


def test_the_cube_side_frame_is_keyed_on_the_cubes_x_not_the_plan():
    """ppo.lane_frame: cube_side_no_joints (issue 42): mirrored where the observed cube x < 0, with
    no lane_choice in the observation; the actor equivariant, deploy's NumPy forward the same, and
    the key rebuilt from the config (not in the state dict, so older checkpoints load)."""
    config = load_config(["profile=scratch-own-lane", "ppo.lane_frame=cube_side_no_joints"])
    layout = observation_layout(config.task, 6, 5)
    assert "lane_choice" not in layout
    dim, cube_x = max(part.stop for part in layout.values()), layout["cube"].start
    modules = make_modules(config.ppo, dim, 3, lane_mirror_for(config, dim, 3, 6, 5))
    mirror = modules.mirror
    observation = torch.randn(64, dim)
    observation[:32, cube_x] = 0.1
    observation[32:, cube_x] = -0.1
    modules.normalizer.update(modules.framed(observation))
    assert mirror.mirrored(observation).squeeze(-1).tolist() == [False] * 32 + [True] * 32
    framed, action_sign = mirror.canonical(observation)
    assert torch.all(framed[:, cube_x] == 0.1)  # every episode seen with its cube at x >= 0
    assert action_sign[:32].tolist() == [[1.0, 1.0, 1.0]] * 32 and action_sign[32:].tolist() == [[-1.0, 1.0, 1.0]] * 32
    act = lean_actor(modules.actor).act
    plus = observation[:32]
    reflected = plus[:, mirror.permutation] * mirror.sign  # the same world reflected: cube at x < 0
    a, b = act(plus), act(reflected)
    assert torch.allclose(a[:, 0], -b[:, 0]) and torch.allclose(a[:, 1:], b[:, 1:])
    policy = NumpyPolicy.from_actor(modules.actor)
    assert policy is not None
    for row, want in zip(observation.numpy().astype(np.float64), act(observation).numpy()):
        np.testing.assert_allclose(policy(row), want, atol=1e-5, rtol=0)
    assert not any("key_" in name for name in mirror.state_dict())
    with pytest.raises(ConfigError, match=r"task\.action\.mode"):
        load_config(["profile=scratch-own-lane", "ppo.lane_frame=cube_side_no_joints", "task.action.mode=joint"])


def test_the_tip_side_frame_is_keyed_on_the_tips_side_of_the_cube():
    """ppo.lane_frame: tip_side_no_joints (issue 56): mirrored where the observed tip is at larger
    x than the cube (relative_to_cube's x > 0), so a push away from the tip is +x in the frame; the
    actor equivariant and deploy's NumPy forward the same; it needs the relative observation."""
    config = load_config(["profile=scratch-own-lane", "ppo.lane_frame=tip_side_no_joints"])
    layout = observation_layout(config.task, 6, 5)
    assert "lane_choice" not in layout
    dim, key = max(part.stop for part in layout.values()), layout["relative_to_cube"].start
    modules = make_modules(config.ppo, dim, 3, lane_mirror_for(config, dim, 3, 6, 5))
    mirror = modules.mirror
    observation = torch.randn(64, dim)
    observation[:32, key] = -0.08  # tip 8 cm on the cube's -x side
    observation[32:, key] = 0.08
    modules.normalizer.update(modules.framed(observation))
    assert mirror.mirrored(observation).squeeze(-1).tolist() == [False] * 32 + [True] * 32
    framed, action_sign = mirror.canonical(observation)
    assert torch.all(framed[:, key] == -0.08)  # the tip always on the cube's -x side in the frame
    assert action_sign[32:].tolist() == [[-1.0, 1.0, 1.0]] * 32
    act = lean_actor(modules.actor).act
    minus = observation[:32]
    reflected = minus[:, mirror.permutation] * mirror.sign  # the same world reflected: tip on +x
    a, b = act(minus), act(reflected)
    assert torch.allclose(a[:, 0], -b[:, 0]) and torch.allclose(a[:, 1:], b[:, 1:])
    policy = NumpyPolicy.from_actor(modules.actor)
    assert policy is not None
    for row, want in zip(observation.numpy().astype(np.float64), act(observation).numpy()):
        np.testing.assert_allclose(policy(row), want, atol=1e-5, rtol=0)
    with pytest.raises(ConfigError, match=r"task\.observation\.relative"):
        load_config(["profile=scratch-own-lane", "ppo.lane_frame=tip_side_no_joints",
                     "task.observation.relative=false"])
