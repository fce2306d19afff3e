import os
import tempfile

os.environ.setdefault("MUJOCO_GL", "egl")
# Nothing a test does reaches the committed test ledger (docs/test-ledger.jsonl): every process of
# the session (xdist workers, Ray workers, subprocesses) inherits this one, set before any fixture,
# module-scoped ones included; each test then gets its own (own_test_ledger below).
os.environ["AHRM_TEST_LEDGER"] = os.path.join(tempfile.mkdtemp(prefix="ahrm-test-ledger-"), "test-ledger.jsonl")

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# CI runs the property tests on a fixed sequence of examples, so a submission's result does not
# depend on the draw; locally they explore new examples on every run.
settings.register_profile("ci", derandomize=True, deadline=None)
if os.environ.get("CI"):
    settings.load_profile("ci")

from ahrm_stack.config import load_config  # noqa: E402

# Test files that time real threads, processes or USB-like calls against the wall clock (a camera
# at 30 frames/s, the Gen2 USB thread at 100 Hz, the Kortex link and watchdogs): they are marked
# ``realtime``, and `make test` runs them on their own after the parallel part, so that no other
# test competes with them for the cores.
REALTIME_FILES = frozenset({
    "test_camera_video.py", "test_hardware_contract.py", "test_kinova_gen2.py",
    "test_kinova_gen2_check.py", "test_kinova_gen2_deploy.py", "test_kinova_gen2_estop.py",
    "test_kinova_gen2_move_home.py",
    "test_kortex_backend.py", "test_kortex_check.py", "test_kortex_deploy.py", "test_kortex_home.py",
    "test_kortex_link.py",
})
# and the brief runs of the benchmarks that pace threads or processes by the wall clock
REALTIME_BENCHMARKS = ("bench_camera_scene", "bench_camera_thread", "bench_gen2_budget", "bench_gen2_estop",
                       "bench_kinova_gen2", "bench_kortex_link")
# Files whose module-scoped fixture is expensive (a training run, the CLI's imports): their tests
# share one worker, so that the fixture is built once.
SHARED_FIXTURE_FILES = frozenset({"test_experiment.py", "test_cli_quiet.py"})


# The files with the longest tests (minutes of hypothesis examples, training runs, Ray) go first, so
# that the parallel workers end together instead of one waiting on a long test started last.
LONG_FIRST = ("test_experiment.py", "test_safety.py", "test_benchmarks.py", "test_collection.py",
              "test_pool.py", "test_train.py", "test_scratch_levers.py", "test_hardware_faults.py")


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """Before the other implementations: the long files first, the realtime and the shared-fixture
    markers. After them: the ``xdist_group`` suffix on each grouped test's id.

    pytest-xdist's worker names a test's group by appending ``@<group>`` to ``item._nodeid`` (its
    ``--dist loadgroup``, xdist 3.8); pytest 9 keeps the id in ``item._id``, so that assignment is
    lost and every grouped test was scheduled on its own: the shared-fixture files built their
    fixture once per worker (the experiment grid's ~75 s twice) and the Kinova SDK's tests did not
    share a worker. The suffix is set here where pytest 9 reads it (once, whichever version)."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_FIRST)))  # stable: same order on every worker
    for item in items:
        if item.path.name in REALTIME_FILES or (
                item.path.name == "test_benchmarks.py" and any(b in item.name for b in REALTIME_BENCHMARKS)):
            item.add_marker(pytest.mark.realtime)
        if item.path.name in SHARED_FIXTURE_FILES:
            item.add_marker(pytest.mark.xdist_group(item.path.stem))
    result = yield
    if getattr(config.option, "loadgroup", False):  # set on an xdist worker under --dist loadgroup
        from _pytest.nodeid import coerce_node_id

        for item in items:
            groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                             for m in item.iter_markers("xdist_group")})
            if groups and "@" not in item.nodeid:
                item._id = coerce_node_id(f"{item.nodeid}@{'_'.join(groups)}")
    return result


@pytest.fixture(autouse=True)
def own_test_ledger(tmp_path_factory, monkeypatch):
    """Each test reads the test split into a ledger of its own (never docs/test-ledger.jsonl): a
    policy trained twice from one seed is the same policy to the ledger."""
    from ahrm_stack.test_ledger import LEDGER_ENV
    monkeypatch.setenv(LEDGER_ENV, str(tmp_path_factory.mktemp("ledger") / "test-ledger.jsonl"))


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



def touched_off(data: dict, folder) -> None:
    """A parsed deploy.yaml whose Gen2 arm (``kinova_gen2.serial``) has passed its touch-off: a
    passing record in ``folder`` named by ``kinova_gen2.touch_off.record`` (deploy runs on the fake
    arm, as a real arm's would, need one; tests/test_kinova_gen2_touch_off.py tests the refusal)."""
    import json
    from pathlib import Path

    record = Path(folder) / "touch-off.json"
    record.write_text(json.dumps({"serial": data["kinova_gen2"].get("serial"), "passed": True, "points": []}))
    data["kinova_gen2"]["touch_off"]["record"] = str(record)


@pytest.fixture
def gen2_config(tmp_path):
    """A writer of configs/deploy.yaml with its ``kinova_gen2`` section updated by keyword
    arguments, to ``tmp_path/deploy.yaml``; returns the path (for ``--config``)."""
    import yaml

    from ahrm_stack.deploy import DEPLOY_CONFIG

    def write(**gen2):
        data = yaml.safe_load(DEPLOY_CONFIG.read_text())
        data["kinova_gen2"].update(gen2)
        touched_off(data, tmp_path)
        path = tmp_path / "deploy.yaml"
        path.write_text(yaml.safe_dump(data))
        return path

    return write
