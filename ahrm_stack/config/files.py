"""Where the configuration's YAML files live: the ``configs/`` folder and the names under it."""

from __future__ import annotations


from ahrm_stack.paths import CONFIG_DIR  # noqa: F401 - decided there (checkout, packaged copy, or $AHRM_CONFIG_DIR)

SECTIONS = {"task": "task.yaml", "scripted": "scripted.yaml", "safety": "safety.yaml",
            "mechanism": "mechanism.yaml", "ppo": "ppo.yaml", "train": "train.yaml"}

PROFILE_DIR = "profiles"  # under the config folder: named sets of overrides

ROBOTS_DIR = CONFIG_DIR / "robots"  # configs/robots/<name>.yaml: arms built from a URDF
