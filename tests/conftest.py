import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# CI runs the property tests on a fixed sequence of examples, so a submission's result does not
# depend on the draw; locally they explore new examples on every run.
settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")

from ahrm_stack.config import load_config  # noqa: E402


@pytest.fixture(scope="session")
def config():
    # the nominal simulation: the task's, the physics' and the controllers' tests check exact
    # values; a real arm's imperfections (task.realism) are tested in tests/test_realism.py
    return load_config(["task.realism=ideal"])


@pytest.fixture(scope="session")
def task_config(config):
    return config.task


@pytest.fixture(scope="session")
def library():
    """The compiled fake Kinova Gen2 SDK (tests/fake_kinova_sdk), shared by the Gen2 test files;
    skipped where no C compiler is found."""
    fake = pytest.importorskip("fake_kinova_sdk.fake")
    try:
        return fake.session_library()
    except fake.CompilerMissing as error:
        pytest.skip(str(error))



@pytest.fixture
def gen2_config(tmp_path):
    """A writer of configs/deploy.yaml with its ``kinova_gen2`` section updated by keyword
    arguments, to ``tmp_path/deploy.yaml``; returns the path (for ``--config``)."""
    import yaml

    from ahrm_stack.deploy import DEPLOY_CONFIG

    def write(**gen2):
        data = yaml.safe_load(DEPLOY_CONFIG.read_text())
        data["kinova_gen2"].update(gen2)
        path = tmp_path / "deploy.yaml"
        path.write_text(yaml.safe_dump(data))
        return path

    return write
