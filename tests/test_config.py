"""Configuration: every bad key or value is named in the error."""

import math

import pytest

from ahrm_stack.config import ConfigError, load_config, load_raw, config_from_dict


def test_defaults_load_and_convert_degrees(config):
    assert config.task.arm.home[0] == pytest.approx(math.radians(240))
    assert config.task.substeps == 25
    assert config.task.max_steps == 1200


def test_unknown_key_is_named():
    raw = load_raw()
    raw["task"]["cube"]["colour"] = "red"
    with pytest.raises(ConfigError, match=r"unknown config key 'task\.cube\.colour'"):
        config_from_dict(raw)


def test_unknown_override_is_named_with_the_allowed_keys():
    with pytest.raises(ConfigError, match=r"'task\.episode\.lenght'.*allowed keys here: \[.*'duration'"):
        load_config(["task.episode.lenght=3"])
    with pytest.raises(ConfigError, match=r"unknown config key 'tsk' .*allowed keys here: \[.*'task'"):
        load_config(["tsk.episode.duration=3"])
    with pytest.raises(ConfigError, match=r"'task\.cube\.size' .* is a value, not a section"):
        load_config(["task.cube.size.x=3"])


def test_negative_size_is_named():
    with pytest.raises(ConfigError, match=r"task\.cube\.size must be > 0, got -0\.05"):
        load_config(["task.cube.size=-0.05"])
    with pytest.raises(ConfigError, match=r"task\.obstacles\.size\[1\] must be > 0"):
        load_config(["task.obstacles.size=[0.06, -0.06, 0.1]"])


def test_bad_choice_lists_allowed_values():
    with pytest.raises(ConfigError, match=r"task\.layout\.mode: 'spiral' is not allowed.*fixed"):
        load_config(["task.layout.mode=spiral"])


def test_wrong_type_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"task\.episode\.duration: expected a number"):
        load_config(["task.episode.duration=soon"])
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(config_dir=tmp_path)


def test_control_period_must_be_multiple_of_timestep():
    with pytest.raises(ConfigError, match="whole multiple"):
        load_config(["task.episode.control_period=0.005", "task.episode.physics_timestep=0.002"])
