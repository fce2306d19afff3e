"""The levers of learning without demonstrations (issue 18), each a config value that takes effect:
the frame budget, the training time limit, near-cube starts and the start curriculum, touch_end."""

import csv
import dataclasses

import numpy as np
import pytest
import torch
from ahrm_stack.config import ConfigError, config_from_dict, load_config, load_raw, profile_overrides
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask
from ahrm_stack.env.torchrl_env import PushOffEnv, touch_penalty
from ahrm_stack.learning.trainer import Trainer

TINY = ["ppo.hidden_sizes=[16,16]", "ppo.frames_per_batch=64", "ppo.mini_batch_size=32",
        "train.warm_start=none", "ppo.bc_coeff=0", "ppo.bc_coeff_final=0"]


def test_time_limit_truncates_training_episodes_only():
    config = load_config(["task.episode.duration=2.0"])
    env = PushOffEnv(config.task, config.safety, seed=0, time_limit=0.5)  # 10 control steps
    full = PushOffEnv(config.task, config.safety, seed=0)
    for limited, steps in ((env, 10), (full, 40)):
        td = limited.reset()
        count = 0
        while count < 100:
            td = limited.step(td.set("action", limited.action_spec.zero()))["next"]
            count += 1
            if bool(td["done"]):
                break
        assert count == steps and bool(td["truncated"]) and not bool(td["terminated"])


def test_trainer_passes_the_time_limit_and_the_evaluation_keeps_the_task_duration():
    trainer = Trainer(load_config([*TINY, "train.time_limit=0.25", "task.episode.duration=3.0"]))
    assert trainer.envs[0].runner.max_steps == 5
    result = trainer.iteration()  # 64 frames: at most 5 steps per episode, so >= 12 episodes end
    assert len(result.episodes) >= 12 and all(row["steps"] <= 5 for row in result.episodes)
    assert PushOffEnv(trainer.config.task, trainer.config.safety, seed=1).runner.max_steps == 60
    trainer.close()


def test_frame_budget_ends_training_by_frames_not_episodes():
    trainer = Trainer(load_config([*TINY, "train.frames=128", "train.episodes=1",
                                   "task.episode.duration=1.0"]))
    trainer.iteration()
    assert trainer.episodes >= 1 and not trainer.finished()  # 64 < 128 frames: the episodes don't count
    trainer.iteration()
    assert trainer.finished()
    trainer.close()
    by_episodes = Trainer(load_config([*TINY, "train.episodes=1000", "task.episode.duration=1.0"]))
    by_episodes.iteration()
    assert not by_episodes.finished()
    by_episodes.close()


def _near_cube_start(task, runner, seed):
    """Reset with ``seed`` (a near-cube start, not the home fallback): the tip by Pinocchio's
    forward kinematics and the cube centre, world frame, m."""
    runner.seed(seed)
    runner.reset()
    assert task.start_target is not None, "fell back to the home posture"
    q, _ = task.arm_state(runner.physics)
    task.kinematics.update(q)
    tip, _ = task.kinematics.frame_pose(task._tip_frame)
    return tip, runner.physics.bind(task._cube.geom).xpos


def test_near_cube_starts_put_the_tip_around_the_cube_pointing_down():
    """The tip measured with Pinocchio's forward kinematics (the IK ran on MuJoCo's model)."""
    config = load_config([])
    task = PushOffTask(config.task)
    task.near_cube_share = 1.0
    runner = TaskRunner(task, seed=3, safety=config.safety)
    near = config.task.arm.near_cube
    bearings = []
    for seed in range(10):
        tip, cube = _near_cube_start(task, runner, seed)
        offset = tip[:2] - cube[:2]
        assert near.distance[0] - 3e-3 <= np.hypot(*offset) <= near.distance[1] + 3e-3
        height = tip[2] - config.task.table.height
        assert near.height[0] - 3e-3 <= height <= near.height[1] + 3e-3
        bearings.append(np.arctan2(offset[1], offset[0]))
    assert np.ptp(bearings) > np.pi  # every side of the cube, not one
    assert task.start_fallbacks == 0


def test_zero_near_cube_share_leaves_the_random_stream_unchanged():
    config = load_config([])
    tasks = [PushOffTask(config.task), PushOffTask(config.task)]
    tasks[1].near_cube_share = 0.0  # explicit: the default
    observations = []
    for task in tasks:
        runner = TaskRunner(task, seed=7, safety=config.safety)
        observations.append(runner.reset().observation)
    for key in observations[0]:
        np.testing.assert_array_equal(observations[0][key], observations[1][key])


def test_start_curriculum_widens_when_the_success_rate_reaches_the_threshold():
    trainer = Trainer(load_config([*TINY, "train.start_curriculum=near_cube",
                                   "train.curriculum_window=4", "train.curriculum_threshold=0.5",
                                   "train.curriculum_step=0.25"]))
    assert trainer.curriculum_level == 0.0 and trainer.envs[0].task.near_cube_share == 1.0
    trainer._update_curriculum([{"success": s} for s in (True, False, False, False)])  # 25 %
    assert trainer.curriculum_level == 0.0
    trainer._update_curriculum([{"success": s} for s in (True, True, False, False, True)])  # 50 %
    assert trainer.curriculum_level == 0.25 and trainer.envs[0].task.near_cube_share == 0.75
    # after a rise the rest of the batch (started at the old level) is not counted
    trainer._update_curriculum([{"success": s} for s in (True, True, True, True, True, True)])
    assert trainer.curriculum_level == 0.5
    trainer._update_curriculum([{"success": s} for s in (True, False)])
    state = trainer.state_dict()
    assert state["curriculum"] == {"level": 0.5, "window": [True, False]}
    resumed = Trainer(load_config([*TINY, "train.start_curriculum=near_cube",
                                   "train.curriculum_window=4"]))
    resumed.load_state_dict(state)
    assert resumed.curriculum_level == 0.5 and resumed.envs[0].task.near_cube_share == 0.5
    for _ in range(2):
        resumed._update_curriculum([{"success": True}] * 4)
    assert resumed.curriculum_level == 1.0 and resumed.envs[0].task.near_cube_share == 0.0
    off = Trainer(load_config(TINY))
    assert off.curriculum_level == 1.0 and off.envs[0].task.near_cube_share == 0.0
    for built in (trainer, resumed, off):
        built.close()


@pytest.mark.parametrize("override, key", [
    ("train.time_limit=-1", "train.time_limit"),
    ("train.frames=-5", "train.frames"),
    ("train.curriculum_threshold=1.5", "train.curriculum_threshold"),
    ("train.curriculum_step=0", "train.curriculum_step"),
    ("train.start_curriculum=maybe", "train.start_curriculum"),
    ("task.arm.near_cube.distance=[0.2,0.1]", "task.arm.near_cube.distance"),
    ("task.arm.near_cube.bearing=front", "task.arm.near_cube.bearing"),
    ("task.arm.near_cube.behind_spread_deg=-5", "task.arm.near_cube.behind_spread_deg"),
    ("task.rewards.time_reference=best", "task.rewards.time_reference"),
    ("mechanism.priority_rule=loudest", "mechanism.priority_rule"),
    ("ppo.actor_init_scale=0", "ppo.actor_init_scale"),
    ("ppo.actor_init_scale=2", "ppo.actor_init_scale"),
])
def test_bad_scratch_values_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_config([override])


def test_the_scratch_profile_has_no_demonstrations():
    config = load_config(profile_overrides("scratch"))
    assert config.train.warm_start == "none" and config.ppo.bc_coeff == 0 == config.ppo.bc_coeff_final
    assert config.train.time_limit < config.task.episode.duration
    assert config.train.start_curriculum == "near_cube"
    assert config.mechanism.priority_rule == "violation"  # round 3 (docs/scratch-study.md)


def test_old_run_configs_get_the_neutral_values():
    raw = load_raw()  # the sections as read, the arms' values composed in
    for key in ("frames", "time_limit", "start_curriculum", "curriculum_states", "curriculum_window",
                "curriculum_threshold", "curriculum_step"):
        raw["train"].pop(key)
    raw["task"]["arm"].pop("near_cube")
    raw["task"]["rewards"].pop("time_reference")
    raw["mechanism"]["priority_rule"] = "violation"
    assert config_from_dict(raw).mechanism.priority_rule == "violation"
    raw["mechanism"].pop("priority_rule")
    raw["ppo"].pop("actor_init_scale")
    config = config_from_dict(raw)
    assert config.train.frames == 0 and config.train.time_limit == 0
    assert config.train.start_curriculum == "none"
    assert config.task.rewards.time_reference == "previous"  # the spec's, as before the key
    assert config.task.arm.near_cube.bearing == "any"
    assert config.mechanism.priority_rule == "magnitude"  # the spec's ranking, as before the key
    assert config.ppo.actor_init_scale == 1.0  # torch's init, as before the key


def test_a_resumed_log_keeps_its_columns(tmp_path):
    from ahrm_stack.learning.run_folder import RunLog
    path = tmp_path / "batches.csv"
    path.write_text("batch,frames\n1,64\n")
    log = RunLog(tmp_path)
    log.batch({"batch": 2, "frames": 128, "episodes": 3, "curriculum_level": 0.5})
    log.close()
    rows = list(csv.reader(open(path)))
    assert rows == [["batch", "frames"], ["1", "64"], ["2", "128"]]


def test_scripted_states_start_from_recorded_states_further_back_as_the_level_rises():
    """The recorded states are the scripted controller's own (replayed here independently from the
    same seeds); a level-0 start is the last state before the cube fell, level 1 the task's start."""
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.learning.start_states import ScriptedStartStates, record_trajectories
    from ahrm_stack.seeds import seed_table
    config = load_config(["task.episode.duration=10"])
    trajectories = record_trajectories(config, 2)
    assert len(trajectories) == 2  # the controller wins these layouts
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.seed(seed_table()["start_states"].start)
    runner.reset()
    controller = ScriptedPusher(task, config.scripted)
    controller.reset(runner.physics)
    np.testing.assert_array_equal(runner.physics.data.qpos, trajectories[0].qpos[0])
    for _ in range(3):
        runner.step_only(controller(runner.physics))
    np.testing.assert_array_equal(runner.physics.data.qpos, trajectories[0].qpos[3])

    states = ScriptedStartStates(trajectories)
    task.start_states = states
    runner.seed(11)
    last = runner.reset()  # level 0: one step from the cube leaving the table
    assert last.info.phase == 3
    chosen = next(t for t in trajectories if np.array_equal(t.layout.cube_xy, task.layout.cube_xy))
    cube = runner.physics.bind(task._cube.geom).xpos
    np.testing.assert_allclose(cube, chosen.qpos[-1][runner.physics.model.jnt_qposadr[
        runner.physics.model.body_jntadr[task._cube_body]]:][:3], atol=1e-9)
    np.testing.assert_array_equal(task.arm_state(runner.physics)[1], 0.0)  # the arm at rest
    states.level = 1.0
    assert states(np.random.RandomState(0)) is None  # the task draws the start itself


def test_trainer_builds_the_scripted_states_curriculum():
    trainer = Trainer(load_config([*TINY, "train.start_curriculum=scripted_states",
                                   "train.curriculum_states=2", "task.episode.duration=10"]))
    assert trainer.start_states is not None and trainer.start_states.level == 0.0
    assert all(env.task.start_states is trainer.start_states for env in trainer.envs)
    trainer._update_curriculum([{"success": True}] * trainer.config.train.curriculum_window)
    assert trainer.start_states.level == trainer.config.train.curriculum_step
    trainer.close()


def test_interim_evaluations_every_so_many_frames(tmp_path):
    from ahrm_stack.train import main
    run = tmp_path / "run"
    assert main([*TINY, "task.episode.duration=1.0", "train.frames=256", "train.eval_every_frames=128",
                 "train.eval_episodes=1", "--run-dir", str(run), "--no-progress"]) == 0
    rows = list(csv.DictReader(open(run / "evaluations.csv")))
    # before training (frames 0), at 128 and at 256 frames (64 frames per batch)
    assert [int(row["frames"]) for row in rows] == [0, 128, 256]


def test_reward_scale_scales_the_rewards_the_advantage_sees():
    """Same seeds, same networks: the GAE inputs differ exactly by the scale."""
    seen = []
    for scale in (1.0, 0.05):
        trainer = Trainer(load_config([*TINY, f"ppo.reward_scale={scale}", "train.seed=3",
                                       "mechanism.method=ls"]))  # LS: every objective from the start
        original = trainer.advantage
        trainer.advantage = lambda data, original=original: (
            seen.append(data.get(("next", "reward")).clone()), original(data))[1]
        trainer.iteration()
        trainer.close()
    torch.testing.assert_close(seen[1], seen[0] * 0.05)
    assert seen[0].abs().sum() > 0


def test_behind_starts_put_the_tip_opposite_the_episodes_lane():
    """bearing: behind — the tip (Pinocchio forward kinematics) lies within behind_spread_deg of
    the side of the cube opposite the lane the observation announces (lane_choice)."""
    config = load_config(["task.arm.near_cube.bearing=behind", "task.arm.near_cube.behind_spread_deg=20"])
    task = PushOffTask(config.task)
    task.near_cube_share = 1.0
    runner = TaskRunner(task, seed=3, safety=config.safety)
    directions = config.task.layout.lane_directions
    lanes = set()
    for seed in range(12):
        tip, cube = _near_cube_start(task, runner, seed)
        lane = directions[int(np.argmax(task.lane_choice(runner.physics)))]
        lanes.add(lane)
        push = np.array([1.0, 0.0]) if lane == "+x" else np.array([-1.0, 0.0])
        offset = tip[:2] - cube[:2]
        # the tip behind the cube: the angle between (cube - tip) and the push direction
        angle = np.degrees(np.arccos(np.clip(-offset @ push / np.linalg.norm(offset), -1, 1)))
        assert angle <= 20 + 3, (seed, lane, angle)  # + IK tolerance (3 mm at >= 6 cm) and settling
    assert lanes == {"+x", "-x"}  # both lanes occur over these seeds, so the side follows the lane


@pytest.mark.parametrize("reference, set_after_failure", [("previous", True), ("success", False)])
def test_time_reference_decides_which_episodes_set_the_phase_budgets(reference, set_after_failure):
    config = load_config([f"task.rewards.time_reference={reference}", "task.episode.duration=0.5"])
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    done = False
    while not done:  # still: no success in 0.5 s, the episode ends at its time limit
        _, terminated, truncated = runner.step_only(np.zeros(task.robot.num_joints))
        done = terminated or truncated
    assert not task.step_info.success
    assert (not np.isnan(task.time_objective.budget).all()) == set_after_failure
    spent = task.time_objective.spent.copy()
    task.step_info = dataclasses.replace(task.step_info, success=True)  # as if it had succeeded
    runner.end_episode()
    expected = spent if reference == "success" else np.where(spent > 0, spent, task.time_objective.budget)
    np.testing.assert_allclose(task.time_objective.budget, expected)


NO_DEMOS = ["train.warm_start=none", "ppo.bc_coeff=0"]


def test_action_smoothing_by_hand():
    """request_t = s * request_{t-1} + (1 - s) * new_t, the first of an episode unchanged."""
    from ahrm_stack.env.control_step import ControlStep
    config = load_config(["task.action.smoothing=0.75", "task.action.cartesian_max_speed=0.5", *NO_DEMOS])
    task = PushOffTask(config.task)
    control = ControlStep(task.robot, config.task.action)
    control.reset()
    first = control.smooth(control.request(np.array([1.0, 0.0, -1.0])))
    np.testing.assert_allclose(first, [0.5, 0.0, -0.5])            # m/s, unchanged
    second = control.smooth(control.request(np.array([-1.0, 1.0, 0.0])))
    np.testing.assert_allclose(second, [0.25, 0.125, -0.375])      # 0.75 * first + 0.25 * (-0.5, 0.5, 0)
    third = control.smooth(control.request(np.array([0.0, 0.0, 0.0])))
    np.testing.assert_allclose(third, 0.75 * second)
    fault = control.smooth(np.array([np.nan, 0.0, 0.0]))            # passes, not remembered
    assert np.isnan(fault[0])
    np.testing.assert_allclose(control.smooth(np.zeros(3)), 0.75 * third)
    control.reset()                                                 # a new episode starts fresh
    np.testing.assert_allclose(control.smooth(control.request(np.array([0.2, 0.2, 0.2]))), [0.1] * 3)


def test_action_smoothing_takes_effect_in_the_environment():
    """The same actions with and without smoothing: the filter sees the smoothed request."""
    requests = {}
    for smoothing in (0.0, 0.8):
        config = load_config([f"task.action.smoothing={smoothing}", *NO_DEMOS])
        task = PushOffTask(config.task)
        runner = TaskRunner(task, seed=0, safety=config.safety)
        runner.reset()
        seen = []
        call = runner.filter.cartesian
        def spy(q, dq, request, *args, seen=seen, call=call, **kwargs):
            seen.append(np.array(request))
            return call(q, dq, request, *args, **kwargs)
        runner.filter.cartesian = spy
        for action in ([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]):
            runner.step_action(np.array(action))
        requests[smoothing] = np.array(seen)
    speed = load_config([]).task.action.cartesian_max_speed
    np.testing.assert_allclose(requests[0.0][:, 0], [speed, 0.0, 0.0])
    np.testing.assert_allclose(requests[0.8][:, 0], [speed, 0.8 * speed, 0.64 * speed])


@pytest.mark.parametrize("overrides", [["task.action.smoothing=1.0", *NO_DEMOS],
                                       ["task.action.smoothing=-0.1", *NO_DEMOS],
                                       ["task.action.smoothing=0.5", "train.warm_start=bc"]])
def test_bad_smoothing_names_the_key(overrides):
    with pytest.raises(ConfigError, match=r"task\.action\.smoothing"):
        load_config(overrides)


def _touch_the_cube_with_an_obstacle(env: PushOffEnv) -> None:
    """Place obstacle 0 flush against the cube's +x face, 1 mm into it (a contact)."""
    physics, task = env.runner.physics, env.task
    body = int(physics.bind(task.obstacles[0].geom).bodyid)
    adr = physics.model.jnt_qposadr[physics.model.body_jntadr[body]]
    cube_xy = physics.data.xpos[int(physics.bind(task.cube.geom).bodyid)][:2]
    gap = task.config.cube.size / 2 + task.config.obstacles.size[0] / 2 - 0.001
    physics.data.qpos[adr:adr + 2] = [cube_xy[0] + gap, cube_xy[1]]
    physics.forward()


@pytest.mark.parametrize("penalty", [0.0, 300.0])
def test_touch_end_makes_a_touch_terminal_with_the_penalty(penalty):
    config = load_config()
    env = PushOffEnv(config.task, config.safety, seed=0, touch_penalty=penalty)  # no mechanism: LS
    td = env.reset()
    _touch_the_cube_with_an_obstacle(env)
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    assert bool(td["touched"])
    g_sum = float(td["g"].sum())  # the linear sum of the penalty-form components (f1 = -1 on a touch)
    assert float(td["g"][0]) == -1.0
    assert float(td["reward"]) == pytest.approx(g_sum - penalty)
    assert bool(td["terminated"]) == (penalty > 0) and not bool(td["truncated"])
    if penalty > 0:
        assert len(env.completed) == 1 and not env.completed[0].success and env.completed[0].touched


def test_touch_penalty_is_every_objective_violated_forever():
    assert touch_penalty(True, 0.99) == pytest.approx(3 / 0.01)  # 300: the discounted sum of -3 per step
    assert touch_penalty(True, 0.9, objectives=2) == pytest.approx(20.0)
    assert touch_penalty(False, 0.99) == 0.0


def test_trainer_switches_touch_end_on_after_so_many_frames():
    """train.touch_end_after = 64 frames (one batch): the first batch is collected without the
    penalty, the second with it; without touch_end nothing changes."""
    on = Trainer(load_config([*TINY, "train.touch_end=true", "ppo.gamma=0.98", "train.touch_end_after=64"]))
    seen = []
    for _ in range(2):
        on.iteration()
        seen.append([env.touch_penalty for env in on.envs])
    assert seen == [[0.0] * len(on.envs), [pytest.approx(3 / 0.02)] * len(on.envs)]
    on.close()
    off = Trainer(load_config(TINY))
    off.iteration()
    assert all(env.touch_penalty == 0.0 for env in off.envs)
    off.close()


def test_worker_processes_get_the_curriculum_level_and_the_delayed_touch_switch():
    """``train.env_workers=2``: the near-cube level reaches both workers' environments when it
    rises (and after a resume), and a delayed ``touch_end`` is off for the first batch and on for
    the second, as in process."""
    trainer = Trainer(load_config([*TINY, "train.num_envs=2", "train.env_workers=2", "train.touch_end=true",
                                   "ppo.gamma=0.98", "train.touch_end_after=64", "train.start_curriculum=near_cube",
                                   "train.curriculum_window=4", "train.curriculum_step=0.25"]))
    try:
        assert trainer.env.worker_settings() == [(1.0, 0.0, 0.0)] * 2  # level 0: every start near the cube
        seen = []
        for _ in range(2):
            trainer.iteration()
            seen.append([penalty for _, penalty, _ in trainer.env.worker_settings()])
        assert seen == [[0.0, 0.0], [pytest.approx(3 / 0.02)] * 2]
        level = trainer.curriculum_level
        trainer._update_curriculum([{"success": True}] * 4)
        assert trainer.curriculum_level == level + 0.25
        assert [share for share, _, _ in trainer.env.worker_settings()] == [1.0 - trainer.curriculum_level] * 2
        state = trainer.state_dict()
    finally:
        trainer.close()
    resumed = Trainer(load_config([*TINY, "train.num_envs=2", "train.env_workers=2",
                                   "train.start_curriculum=near_cube"]))
    try:
        resumed.load_state_dict(state)
        assert [share for share, _, _ in resumed.env.worker_settings()] == [1.0 - state["curriculum"]["level"]] * 2
    finally:
        resumed.close()


def test_scripted_states_with_worker_processes_names_the_key():
    with pytest.raises(ConfigError, match="train.start_curriculum .scripted_states. needs train.env_workers: 1"):
        load_config(["train.start_curriculum=scripted_states", "train.num_envs=2", "train.env_workers=2"])


def test_pool_workers_get_the_touch_penalty():
    """``train.env_workers`` > 1 (the EnvPool): each worker's environments get the same penalty,
    gamma's 3 / (1 - 0.99), and their consecutive share of the seeds."""
    from ahrm_stack.learning import pool
    from ahrm_stack.learning.workers import WorkerEnv
    config = load_config([*TINY, "train.touch_end=true", "ppo.gamma=0.99", "train.num_envs=4",
                          "train.env_workers=2"])
    arguments = pool.worker_arguments(config, [10, 11, 12, 13])
    assert [(a[3], a[4]) for a in arguments] == [((10, 11), (0, 1)), ((12, 13), (2, 3))]
    env = WorkerEnv(*arguments[1][:3], arguments[1][3][0], arguments[1][4][0], *arguments[1][5:])
    assert env.touch_penalty == pytest.approx(300.0) and env.index == 2


def test_worker_processes_get_the_touch_penalty(monkeypatch):
    """``train.env_workers`` > 1 through TorchRL's ParallelEnv (the reference path): each worker's
    environments are built with the same penalty."""
    import torchrl_reference
    built = []
    monkeypatch.setattr(torchrl_reference, "ParallelEnv", lambda n, groups, **kwargs: built.extend(groups) or
                        type("Started", (), {"start": lambda self: None})())
    config = load_config([*TINY, "train.touch_end=true", "ppo.gamma=0.99", "train.num_envs=2",
                          "train.env_workers=2"])
    torchrl_reference.make_worker_envs(config, [0, 1])
    envs = [group() for group in built]
    assert len(envs) == 2 and all(env.touch_penalty == pytest.approx(300.0) for env in envs)


def test_actor_init_scale_shrinks_the_output_layer_only():
    """ppo.actor_init_scale multiplies the actor's output layer's initial weights and bias, after
    the library's init: the same seed gives the same hidden layers and critic, and initial mean
    actions (pre-tanh) that are the scaled ones, 0.01 x when every hidden layer is the same."""
    from ahrm_stack.learning.ppo import make_modules

    def build(scale: float):
        config = load_config([*TINY, f"ppo.actor_init_scale={scale}"])
        torch.manual_seed(7)
        return make_modules(config.ppo, 20, 3)

    plain, small = build(1.0), build(0.01)
    linear = lambda m: [x for x in m.modules() if isinstance(x, torch.nn.Linear)]  # noqa: E731
    actor_plain, actor_small = linear(plain.actor), linear(small.actor)
    for a, b in zip(actor_plain[:-1], actor_small[:-1]):
        assert torch.equal(a.weight, b.weight) and torch.equal(a.bias, b.bias)
    assert torch.allclose(actor_small[-1].weight, 0.01 * actor_plain[-1].weight)
    assert torch.allclose(actor_small[-1].bias, 0.01 * actor_plain[-1].bias)
    for a, b in zip(linear(plain.critic), linear(small.critic)):
        assert torch.equal(a.weight, b.weight)
    # the output layer is linear: its output (the Gaussian's loc) scales exactly
    hidden = torch.nn.Sequential(*list(plain.actor.module[0].module[1].module[0])[:-1])
    x = torch.randn(5, 20)
    loc_plain = actor_plain[-1](hidden(x))
    loc_small = actor_small[-1](hidden(x))
    assert torch.allclose(loc_small, 0.01 * loc_plain, atol=1e-7)


def test_touch_cost_is_charged_once_per_episode_and_the_episode_goes_on():
    """task.rewards.touch_cost: the first touching step of an episode pays it, the next touching
    step does not, the episode is not ended by it, and a new episode pays it again."""
    config = load_config(["task.rewards.touch_cost=40"])
    env = PushOffEnv(config.task, config.safety, seed=0)  # no mechanism: LS, the sum of g
    for _ in range(2):  # two episodes: the charge is per episode
        td = env.reset()
        _touch_the_cube_with_an_obstacle(env)
        paid = []
        for _ in range(2):
            td = env.step(td.set("action", env.action_spec.zero()))["next"]
            assert bool(td["touched"]) and not bool(td["done"])
            paid.append(float(td["g"].sum()) - float(td["reward"]))
        assert paid == [pytest.approx(40.0), pytest.approx(0.0)]


def test_trainer_charges_the_touch_cost_after_so_many_frames():
    """train.touch_cost_after = 64 frames (one batch): the first batch is collected with no touch
    cost, the second with task.rewards.touch_cost, in process and in worker processes alike."""
    on = Trainer(load_config([*TINY, "task.rewards.touch_cost=40", "train.touch_cost_after=64"]))
    seen = []
    for _ in range(2):
        on.iteration()
        seen.append([env.touch_cost for env in on.envs])
    assert seen == [[0.0] * len(on.envs), [40.0] * len(on.envs)]
    on.close()
    pooled = Trainer(load_config([*TINY, "task.rewards.touch_cost=40", "train.touch_cost_after=64",
                                  "train.num_envs=2", "train.env_workers=2"]))
    try:
        seen = []
        for _ in range(2):
            pooled.iteration()
            seen.append([cost for _, _, cost in pooled.env.worker_settings()])
        assert seen == [[0.0, 0.0], [40.0, 40.0]]
    finally:
        pooled.close()
    always = Trainer(load_config([*TINY, "task.rewards.touch_cost=40"]))
    always.iteration()
    assert all(env.touch_cost == 40.0 for env in always.envs)
    always.close()


def test_bad_touch_cost_names_the_key():
    with pytest.raises(ConfigError, match=r"task\.rewards\.touch_cost"):
        load_config(["task.rewards.touch_cost=-1"])


def _push_the_cube_off(env: PushOffEnv) -> None:
    """Place the cube 5 cm beyond the table's +x edge (the next step is a success)."""
    physics, task = env.runner.physics, env.task
    body = int(physics.bind(task.cube.geom).bodyid)
    adr = physics.model.jnt_qposadr[physics.model.body_jntadr[body]]
    physics.data.qpos[adr] = task.config.table.half_extent[0] + 0.05
    physics.forward()


def test_touched_success_cost_prices_a_success_only_after_a_touch():
    """task.rewards.touched_success_cost: the success step of an episode that touched an obstacle
    pays it; a clean success and a touch without a success do not; the success still ends the
    episode and counts as one."""
    config = load_config(["task.rewards.touched_success_cost=200"])
    env = PushOffEnv(config.task, config.safety, seed=0)  # no mechanism: LS, the sum of g

    def paid(td) -> float:
        return float(td["g"].sum()) - float(td["reward"])

    td = env.reset()  # a clean success
    _push_the_cube_off(env)
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    assert bool(td["terminated"]) and not bool(td["touched"]) and paid(td) == pytest.approx(0.0)
    assert env.completed[-1].success
    td = env.reset()  # a touch, then a success
    _touch_the_cube_with_an_obstacle(env)
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    assert bool(td["touched"]) and not bool(td["done"]) and paid(td) == pytest.approx(0.0)
    _push_the_cube_off(env)
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    assert bool(td["terminated"]) and paid(td) == pytest.approx(200.0)
    assert env.completed[-1].success and env.completed[-1].touched
    td = env.reset()  # the next episode starts clean
    _push_the_cube_off(env)
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    assert bool(td["terminated"]) and paid(td) == pytest.approx(0.0)
    with pytest.raises(ConfigError, match=r"task\.rewards\.touched_success_cost"):
        load_config(["task.rewards.touched_success_cost=-1"])
