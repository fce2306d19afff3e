"""``safety.acceleration_limit`` is per arm: each arm's file in the registry
(``configs/robots/<name>.yaml``) gives its values, composed as a mapping arm name -> values; one
flat list (a run's ``config.yaml``, an override) applies to task.robot. A loaded config, the safety
filter, deploy's checkpoint merge and its Kortex backend all get the arm in use's values through one
resolver (``ahrm_stack.config.arm_acceleration_limit``); bad values are one line naming the key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from ahrm_stack.config import (CONFIG_DIR, ConfigError, arm_acceleration_limit, arm_names, config_from_dict,
                               load_arm, load_config, load_raw)
from ahrm_stack.schema import FrozenDict

JACO = (4.0, 4.0, 4.0, 6.0, 6.0, 6.0)  # configs/safety.yaml's list before the registry held it
GEN3 = (4.0, 4.0, 4.0, 4.0, 6.0, 6.0, 6.0)
COMMITTED = Path(__file__).resolve().parents[1] / "docs" / "policies" / "ahrm-default-seed0" / "config.yaml"


def test_each_arm_has_its_own_limits_from_its_file_and_gen3_needs_no_override():
    raw = load_raw()["safety"]["acceleration_limit"]
    assert raw == {name: list(load_arm(name).acceleration_limit) for name in arm_names()}
    assert "acceleration_limit" not in yaml.safe_load((CONFIG_DIR / "safety.yaml").read_text())
    assert load_config().safety.acceleration_limit == JACO  # make run: the values it always had
    for name in arm_names():
        assert load_config([f"task.robot={name}"]).safety.acceleration_limit == load_arm(name).acceleration_limit
    assert load_arm("gen3").acceleration_limit == GEN3
    assert load_arm("j2s6s200").acceleration_limit == load_arm("jaco").acceleration_limit == JACO


def test_a_flat_list_applies_to_task_robot_and_is_what_a_run_records():
    # the registered paper-diagnosis override (studies/paper_diagnosis.py), unchanged
    assert load_config(["safety.acceleration_limit=[1000,1000,1000,1000,1000,1000]"]).safety.acceleration_limit \
        == (1000.0,) * 6
    gen3 = load_config(["task.robot=gen3", "safety.acceleration_limit=[3,3,3,3,5,5,5]"])
    assert gen3.safety.acceleration_limit == (3.0, 3.0, 3.0, 3.0, 5.0, 5.0, 5.0)
    # a run's config.yaml records the arm in use's list, as before the registry, and reads back equal
    for config in (load_config(), gen3):
        data = config.to_dict()
        assert data["safety"]["acceleration_limit"] == list(config.safety.acceleration_limit)
        assert config_from_dict(yaml.safe_load(yaml.safe_dump(data))) == config
    # a committed run config (a flat list) means what it meant
    committed = yaml.safe_load(COMMITTED.read_text())
    assert committed["safety"]["acceleration_limit"] == list(JACO)
    assert config_from_dict(committed, runnable=False).safety.acceleration_limit == JACO


def test_a_mapping_entry_changes_only_its_arm():
    override = "safety.acceleration_limit.gen3=[3,3,3,3,5,5,5]"
    assert load_config(["task.robot=gen3", override]).safety.acceleration_limit == (3.0,) * 4 + (5.0,) * 3
    assert load_config([override]).safety.acceleration_limit == JACO
    assert arm_acceleration_limit(FrozenDict({"gen3": GEN3, "jaco": JACO}), "gen3") == GEN3
    assert arm_acceleration_limit(JACO, "jaco", 6) == JACO


@pytest.mark.parametrize("overrides,message", [
    (["task.robot=gen3", "safety.acceleration_limit=[1000,1000,1000,1000,1000,1000]"],
     r"safety\.acceleration_limit has 6 values, task\.arm\.home_deg 7: both give one value per joint of "
     r"task\.robot \(gen3\) \(one list applies to task\.robot; or give a mapping arm name -> rad/s\^2 per joint\)$"),
    (["safety.acceleration_limit=[4,4,4]"], r"safety\.acceleration_limit has 3 values, task\.arm\.home_deg 6"),
    (["safety.acceleration_limit.gen3=[4,4,4,4,6,6]"],
     r"safety\.acceleration_limit\.gen3: 6 values, arm 'gen3' has 7 joints: give one per joint"),
    (["safety.acceleration_limit={jaco: [4,4,4,6,6,6], ur5: [1,1,1,1,1,1]}"],
     r"safety\.acceleration_limit\.ur5: no arm 'ur5'; registered \(configs/robots/\): \['gen3', 'j2s6s200', "
     r"'jaco'\] \(override\)"),
    (["safety.acceleration_limit={gen3: [4,4,4,4,6,6,6]}"],
     r"safety\.acceleration_limit has no entry for arm 'jaco' \(task\.robot\); entries: \['gen3'\]"),
    (["safety.acceleration_limit.jaco=[4,4,4,6,6,0]"], r"safety\.acceleration_limit\.jaco\[5\] must be > 0, got 0\.0"),
    (["safety.acceleration_limit=[4,4,4,6,6,-6]"],
     r"safety\.acceleration_limit\[5\] must be > 0, got -6\.0 \(override\)$"),
    (["safety.acceleration_limit=[4,4,4,6,6,.nan]"], r"safety\.acceleration_limit\[5\]: must be finite"),
    (["safety.acceleration_limit=4"], r"safety\.acceleration_limit: expected a list of rad/s\^2 per joint, got 4"),
])
def test_bad_limits_are_one_line_naming_the_key(overrides, message):
    with pytest.raises(ConfigError, match=f"^{message}") as error:
        load_config(overrides)
    assert "\n" not in str(error.value)


def test_a_registry_entry_of_the_wrong_length_names_its_file(tmp_path):
    import shutil

    robots = tmp_path / "robots"
    shutil.copytree(CONFIG_DIR / "robots", robots)
    entry = yaml.safe_load((robots / "gen3.yaml").read_text())
    entry["acceleration_limit"] = list(JACO)
    (robots / "gen3.yaml").write_text(yaml.safe_dump(entry))
    with pytest.raises(ConfigError, match=r"^robots/gen3\.acceleration_limit has 6 values, home_deg 7: both "
                                          r"give one value per joint \(.*gen3\.yaml\)$"):
        load_arm("gen3", robots)


def test_the_safety_filter_takes_the_arm_in_use_s_limits():
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.safety import SafetyFilterError, make_filter

    config = load_config(["task.robot=gen3", "task.arm.start=home"])
    runner = TaskRunner(PushOffTask(config.task), seed=0, safety=config.safety)
    runner.reset()
    assert tuple(runner.filter.acceleration.limit) == GEN3
    task = runner.task

    def build(safety):
        return make_filter(task.robot, task.kinematics, safety, control_period=config.task.episode.control_period,
                           table_height=config.task.table.height, tip_site=task.pusher.tip_site,
                           wrist_site=task.arm.wrist_site, scene=task.make_collision_scene(runner.physics))

    # a section that still holds the per-arm mapping (not through Config): the arm's own entry
    mapping = FrozenDict({"gen3": (2.0,) * 7, "jaco": JACO})
    assert tuple(build(dataclasses.replace(config.safety, acceleration_limit=mapping)).acceleration.limit) == (2.0,) * 7
    with pytest.raises(SafetyFilterError, match=r"^safety\.acceleration_limit has no entry for arm 'gen3'"):
        build(dataclasses.replace(config.safety, acceleration_limit=FrozenDict({"jaco": JACO})))


def test_deploy_merges_a_checkpoint_with_its_own_arms_limits(monkeypatch, tmp_path):
    """A gen3 checkpoint is merged with deploy's gen3 limits (configs/robots/gen3.yaml), not the
    default arm's six values; its stricter entry is taken."""
    import ahrm_stack.learning.rollouts as rollouts
    from ahrm_stack.deploy import load_controller_config

    gen3 = load_config(["task.robot=gen3"])
    theirs = dataclasses.replace(gen3, safety=dataclasses.replace(gen3.safety, acceleration_limit=(3.0,) + GEN3[1:]))
    monkeypatch.setattr(rollouts, "load_policy", lambda run, policy_file=None, runnable=True: (theirs, None))
    (tmp_path / "config.yaml").write_text("{}")
    (tmp_path / "policy.pt").write_bytes(b"")
    notes: list = []
    config, _ = load_controller_config(tmp_path, notes=notes)
    assert config.safety.acceleration_limit == (3.0,) + GEN3[1:]
    assert [(n.key, n.kind) for n in notes] == [("acceleration_limit", "stricter")]


def test_the_kortex_backend_checks_the_arm_in_use_s_limits(monkeypatch):
    import ahrm_stack.hardware.kortex as kortex
    from ahrm_stack.deploy.backends import kortex_adapter
    from ahrm_stack.deploy.settings import load_deploy_settings

    seen = {}
    monkeypatch.setattr(kortex, "make_kortex_backend", lambda settings, robot, **kwargs: seen.update(kwargs))
    config, settings = load_config(["task.robot=gen3"]), load_deploy_settings()
    kortex_adapter(config, settings)  # a run's adapter (BACKENDS["kortex"].make wraps it with its scene)
    assert tuple(seen["acceleration_limit"]) == GEN3
