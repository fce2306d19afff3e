"""The one configuration system (ahrm_stack/schema.py): every YAML file refuses unknown keys with
one line naming the key path and the file; the typed configuration writes itself back
(``to_dict``) and reads back equal; copies made with dataclasses.replace are not validated."""

import copy
import dataclasses
import pickle
import re
import shutil
from typing import Annotated

import pytest
import yaml

from ahrm_stack.config import (CONFIG_DIR, SECTIONS, Config, ConfigError, ExperimentConfig, VideoConfig,
                               config_from_dict, load_config, load_extra, load_arm, load_raw)
from ahrm_stack.deploy.settings import load_deploy_settings
from ahrm_stack.env.layout_catalog import load_layouts
from ahrm_stack.perception.settings import load_perception_settings
from ahrm_stack.schema import Float, Int, Section, gt, le, load_file, validate
from ahrm_stack.seeds import load_seed_table
from ahrm_stack.hardware.scene import StaticScene


@pytest.fixture
def configs(tmp_path):
    """A copy of configs/ to break."""
    shutil.copytree(CONFIG_DIR, tmp_path / "configs")
    return tmp_path / "configs"


def _edit(path, change):
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _put(*keys):
    """A change that adds ``colour: red`` under the nested ``keys``."""
    def change(data):
        for key in keys:
            data = data[key]
        data["colour"] = "red"
    return change


# (file under configs/, where the unknown key goes, how the file is read, the key path named)
UNKNOWN = [
    ("task.yaml", ("arm", "start_ik"), lambda d: load_config(config_dir=d), "task.arm.start_ik.colour"),
    ("scripted.yaml", (), lambda d: load_config(config_dir=d), "scripted.colour"),
    ("safety.yaml", (), lambda d: load_config(config_dir=d), "safety.colour"),
    ("mechanism.yaml", (), lambda d: load_config(config_dir=d), "mechanism.colour"),
    ("ppo.yaml", (), lambda d: load_config(config_dir=d), "ppo.colour"),
    ("train.yaml", (), lambda d: load_config(config_dir=d), "train.colour"),
    ("video.yaml", (), lambda d: load_extra(VideoConfig, "video", config_dir=d), "video.colour"),
    ("experiment.yaml", ("paper_table2", "ahrm"), lambda d: load_extra(ExperimentConfig, "experiment",
                                                                       config_dir=d),
     "experiment.paper_table2.ahrm.colour"),
    ("layouts.yaml", ("heldout",), lambda d: load_layouts(d / "layouts.yaml"), "heldout.colour"),
    ("seeds.yaml", (), lambda d: load_seed_table(d / "seeds.yaml"), "colour"),
    ("robots/j2s6s200.yaml", ("urdf",), lambda d: load_arm("j2s6s200", d / "robots"),
     "robots/j2s6s200.urdf.colour"),
    ("robots/jaco.yaml", (), lambda d: load_config(config_dir=d), "robots/jaco.colour"),
    ("deploy.yaml", ("kinova_gen2", "home"), lambda d: load_deploy_settings(d / "deploy.yaml"),
     "deploy.kinova_gen2.home.colour"),
    ("perception.yaml", ("camera",), lambda d: load_perception_settings(d / "perception.yaml"),
     "perception.camera.colour"),
    ("scenes/default.yaml", ("cube",), lambda d: StaticScene(d / "scenes/default.yaml"), "cube.colour"),
]


@pytest.mark.parametrize("name,keys,read,key", UNKNOWN, ids=[u[0] for u in UNKNOWN])
def test_every_file_refuses_an_unknown_key_naming_its_path_and_the_file(configs, name, keys, read, key):
    read(configs)  # the copy as it is loads
    _edit(configs / name, _put(*keys))
    with pytest.raises(ValueError) as error:  # ConfigError; deploy's and the scene's own classes
        read(configs)
    message = str(error.value)
    assert "\n" not in message
    assert f"unknown config key '{key}'; allowed keys here: [" in message, message
    assert message.endswith(f"{name})"), message


def test_a_profile_with_an_unknown_key_names_the_key_and_the_profile(configs):
    _edit(configs / "profiles" / "paper.yaml", lambda data: data["ppo"].update(colour="red"))
    with pytest.raises(ConfigError, match=r"unknown config key 'ppo\.colour' .*profiles/paper\.yaml\)$"):
        load_config(["profile=paper"], config_dir=configs)


def test_messages_name_the_file_or_the_override(configs):
    _edit(configs / "ppo.yaml", lambda data: data.update(learning_rate=-1))
    with pytest.raises(ConfigError, match=r"^ppo\.learning_rate must be > 0, got -1\.0 \(.*configs/ppo\.yaml\)$"):
        load_config(config_dir=configs)
    with pytest.raises(ConfigError, match=r"^ppo\.learning_rate must be > 0, got -2\.0 \(override\)$"):
        load_config(["ppo.learning_rate=-2"])
    with pytest.raises(ConfigError, match=r"^missing config key 'task\.cube\.mass' \(.*task\.yaml\)$"):
        _edit(configs / "task.yaml", lambda data: data["cube"].pop("mass"))
        load_config(config_dir=configs)


def test_numbers_are_numbers_except_the_exponents_yaml_1_1_leaves_as_strings():
    assert validate(Float, "1e-4") == 1e-4 and validate(Float, "-2.5E+3") == -2500.0  # unquoted in YAML
    assert yaml.safe_load("x: 1e-4")["x"] == "1e-4"  # PyYAML (YAML 1.1) reads it as a string
    for value in ("2", "0.5", "x", "nan", "inf", "1e", True):  # a quoted number is not one
        with pytest.raises(ConfigError, match=": expected a number, got"):
            validate(Float, value)


def test_derived_fields_are_not_keys():
    raw = load_raw()
    raw["task"]["arm"]["home"] = [0.0] * 6
    with pytest.raises(ConfigError, match=r"unknown config key 'task\.arm\.home'; allowed keys here: "
                                          r"\[.*'home_deg'"):
        config_from_dict(raw)


@pytest.mark.parametrize("overrides", [[], ["profile=paper"], ["task.robot=j2s6s200"],
                                       ["task.arm.home_deg=[270, 180, 90, 0, 90, 0]", "ppo.hidden_sizes=[8]"]])
def test_write_back_and_read_again_is_equal(overrides):
    config = load_config(overrides)
    text = yaml.safe_dump(config.to_dict(), sort_keys=False)
    again = config_from_dict(yaml.safe_load(text))
    assert again == config
    assert again.task.arm.home == config.task.arm.home and again.task.arm.base_yaw == config.task.arm.base_yaw
    assert yaml.safe_load(text) == config.to_dict()  # plain YAML: lists, numbers, strings, mappings


def test_the_written_config_keeps_the_yaml_keys_and_the_per_robot_home():
    data = load_config().to_dict()
    assert set(data) == set(SECTIONS) == set(load_raw())
    assert set(data["task"]["arm"]) == set(load_raw()["task"]["arm"])  # home_deg, base_yaw_deg; no radians
    # switching the arm of a written config still finds that arm's home posture
    data["task"]["robot"] = "j2s6s200"
    assert config_from_dict(data) == load_config(["task.robot=j2s6s200"])


def test_train_writes_the_typed_config_back(tmp_path):
    from ahrm_stack.learning.run_folder import write_config

    config = load_config(["train.episodes=7", "profile=paper"])
    write_config(tmp_path / "run", config)
    assert config_from_dict(yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())) == config


def test_replace_does_not_validate_and_sections_stay_frozen():
    config = load_config()
    odd = dataclasses.replace(config.safety, position_margin=float("nan"), obstacle_activation_distance=-1.0)
    assert odd.obstacle_activation_distance == -1.0  # deploy.merge_safety and the tests rely on this
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.ppo.learning_rate = 1.0
    assert isinstance(config, Config) and dataclasses.is_dataclass(config)
    # hashable, copied and pickled (Ray ships configs to its workers) whole
    assert hash(config) == hash(load_config())
    assert copy.deepcopy(config) == config == pickle.loads(pickle.dumps(config))


def test_old_run_folders_missing_keys_are_filled():
    raw = load_raw()
    del raw["task"]["observation"], raw["train"]["dagger_rounds"], raw["task"]["arm"]["start"]
    del raw["train"]["update_threads"]  # a run written before 2026-12-04: the default fills it
    config = config_from_dict(raw)
    assert config.task.arm.start == "home" and config.train.dagger_rounds == 0
    assert config.train.update_threads == load_config().train.update_threads
    assert not config.task.observation.relative
    assert config_from_dict(config.to_dict()) == config


# ------------------------------------------------------------------ a file of another module


class DeployError(ValueError):
    """A module's own error class (deploy.py raises DeployConfigError)."""


@dataclasses.dataclass(frozen=True)
class Watchdog(Section):
    max_feedback_age: Annotated[Float, gt(0)]  # control periods
    max_deadline_misses: Annotated[Int, le(10)]


@dataclasses.dataclass(frozen=True)
class Settings(Section):
    rate_hz: Annotated[Float, gt(0)]  # Hz
    watchdog: Watchdog

    def check(self, key):
        if self.rate_hz > 1000:
            raise ConfigError(f"{key}.rate_hz ({self.rate_hz} Hz) is faster than the arm's 1 kHz")


def test_another_module_defines_its_file_in_a_few_lines_and_keeps_its_error_class(tmp_path):
    path = tmp_path / "deploy.yaml"
    path.write_text("rate_hz: 20\nwatchdog: {max_feedback_age: 0.5, max_deadline_misses: 0}\n")
    settings = load_file(Settings, path, "deploy", error=DeployError)
    assert settings.watchdog.max_feedback_age == 0.5 and settings.rate_hz == 20.0
    assert validate(Settings, settings.to_dict()) == settings
    for text, message in (
            ("rate_hz: 20\nwatchdog: {max_feedback_age: 0.5, max_deadline_misses: 0, extra: 1}\n",
             "unknown config key 'deploy.watchdog.extra'"),
            ("rate_hz: 2000\nwatchdog: {max_feedback_age: 0.5, max_deadline_misses: 0}\n",
             "deploy.rate_hz (2000.0 Hz) is faster"),
            ("rate_hz: 20\nwatchdog: {max_feedback_age: .nan, max_deadline_misses: true}\n",
             "deploy.watchdog.max_feedback_age: must be finite, got nan")):
        path.write_text(text)
        with pytest.raises(DeployError, match=re.escape(message)):
            load_file(Settings, path, "deploy", error=DeployError)
    with pytest.raises(DeployError, match=r"deploy\.watchdog\.max_deadline_misses must be <= 10, got 11 \(override\)"):
        load_file(Settings, path, "deploy", ["watchdog.max_feedback_age=1", "watchdog.max_deadline_misses=11"],
                  error=DeployError)
