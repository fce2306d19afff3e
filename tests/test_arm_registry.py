"""The arm registry (``configs/robots/<name>.yaml``, ahrm_stack/config/robots.py): a new arm is one
file there plus its model files, and every per-arm value the task, the safety filter and deploy read
comes from that file."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap

import pytest
import yaml

from ahrm_stack.config import CONFIG_DIR, ConfigError, arm_names, load_arm, load_config
from ahrm_stack.deploy import load_deploy_settings
from ahrm_stack.robot import describe, make_arm


def test_every_per_arm_value_comes_from_the_arms_file():
    config, deploy = load_config(), load_deploy_settings()
    assert arm_names() == ("gen3", "j2s6s200", "jaco")
    for name in arm_names():
        entry = load_arm(name)
        assert config.task.arm.home_deg[name] == entry.home_deg
        assert config.safety.self_collision_pairs[name] == entry.self_collision_pairs
        assert load_config([f"task.robot={name}"]).safety.acceleration_limit == entry.acceleration_limit
        if entry.kinova_gen2 is not None:
            assert deploy.kinova_gen2.joints[name].robot_types == tuple(entry.kinova_gen2["robot_types"])
        else:
            assert name not in deploy.kinova_gen2.joints
        if entry.kortex is not None:
            assert (deploy.kortex.models[name].model, deploy.kortex.models[name].dof) == (
                entry.kortex["model"], entry.kortex["dof"])
        robot = describe(name, make_arm(name))
        assert robot.commanded_joints == entry.commanded_joints
        assert robot.min_velocity_margin == entry.min_velocity_margin
        assert len(entry.home_deg) == len(entry.acceleration_limit) == robot.num_joints
    assert set(deploy.kortex.models) == {"gen3"}  # the one Kortex arm
    for section in ("task.yaml", "safety.yaml", "deploy.yaml"):  # said once: in the arms' files
        text = (CONFIG_DIR / section).read_text()
        assert not any(line.lstrip().startswith(("jaco:", "j2s6s200:", "gen3:")) for line in text.splitlines()), section


def test_a_bad_entry_is_one_line_naming_the_arms_file_and_key(tmp_path):
    robots = tmp_path / "robots"
    shutil.copytree(CONFIG_DIR / "robots", robots)
    for change, expected in (
            ({"source": "sdf"}, r"robots/jaco\.source"),
            ({"urdf": None, "source": "urdf"}, r"robots/jaco\.urdf: give it exactly when source is urdf"),
            ({"commanded_joints": [0, 0]}, r"robots/jaco\.commanded_joints: \[0, 0\] repeats a joint"),
            ({"self_collision_pairs": [["base", "elbow"]]}, r"robots/jaco\.self_collision_pairs\[0\]: 'elbow' is "
                                                             r"not an arm part"),
            ({"acceleration_limit": [4.0] * 5}, r"robots/jaco\.acceleration_limit has 5 values, home_deg 6"),
            ({"acceleration_limit": [4, 4, 4, 6, 6, 0]}, r"robots/jaco\.acceleration_limit\[5\] must be > 0"),
            ({"colour": 1}, r"unknown config key 'robots/jaco\.colour'")):
        entry = yaml.safe_load((CONFIG_DIR / "robots" / "jaco.yaml").read_text())
        entry.update(change)
        (robots / "jaco.yaml").write_text(yaml.safe_dump(entry))
        with pytest.raises(ConfigError, match=expected) as error:
            load_arm("jaco", robots)
        assert "\n" not in str(error.value) and str(error.value).endswith("jaco.yaml)")
    with pytest.raises(ConfigError, match=r"no arm 'ur5' in .*; registered: \['gen3', 'j2s6s200', 'jaco'\]"):
        load_arm("ur5", robots)


NEW_ARM = textwrap.dedent("""
    import numpy as np
    from ahrm_stack.config import arm_names, load_config
    from ahrm_stack.deploy import load_deploy_settings
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask

    assert arm_names() == ("gen3", "j2s6s200", "jaco", "spherical_copy"), arm_names()
    config = load_config(["task.robot=spherical_copy", "task.arm.start=home"])
    assert config.task.arm.home_deg["spherical_copy"][0] == 340.0
    assert config.safety.acceleration_limit == (4.0, 4.0, 4.0, 6.0, 6.0, 6.0)  # from its file
    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=0, safety=config.safety)
    runner.reset()
    assert task.robot.name == "spherical_copy" and len(runner.filter.distances.self_pairs) == 15
    rng = np.random.default_rng(0)
    for _ in range(10):
        runner.step_action(rng.uniform(-1, 1, runner.control.action_size))
    convention = load_deploy_settings().kinova_gen2.joints["spherical_copy"]
    print("ok", convention.robot_types)
""")


def test_a_new_arm_is_one_file_in_the_registry(tmp_path):
    """A worked example: a copy of configs/ with one more file, robots/spherical_copy.yaml (the
    j2s6s200's entry, another home posture), and nothing else changed: the task, its safety filter
    (with that file's self-collision pairs and acceleration limits) and deploy's Gen2 joint
    convention take the new arm."""
    configs = tmp_path / "configs"
    shutil.copytree(CONFIG_DIR, configs)
    entry = yaml.safe_load((CONFIG_DIR / "robots" / "j2s6s200.yaml").read_text())
    entry["home_deg"][0] = 340.0
    (configs / "robots" / "spherical_copy.yaml").write_text(yaml.safe_dump(entry))
    env = {**os.environ, "AHRM_CONFIG_DIR": str(configs)}
    done = subprocess.run([sys.executable, "-c", NEW_ARM], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "ok ('SPHERICAL_6DOF_SERVICE',)" in done.stdout
