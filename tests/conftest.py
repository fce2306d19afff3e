import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402

from ahrm_stack.config import load_config  # noqa: E402


@pytest.fixture(scope="session")
def config():
    return load_config()


@pytest.fixture(scope="session")
def task_config(config):
    return config.task
