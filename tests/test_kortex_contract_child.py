"""The adapter contract (tests/test_hardware_contract.py) once more for the Kortex backend with
``kortex_api`` in its own process: the fake ``kortex_api`` behind ahrm_stack/hardware/kortex/child_link.py
(this interpreter, the fake on the child's path). The contract's tests are imported and run here
with only this backend."""

from __future__ import annotations

import pytest

from test_hardware_contract import *  # noqa: F401,F403 - the contract's tests, collected here
from test_hardware_contract import _robot


@pytest.fixture
def arm(task_config, monkeypatch):  # noqa: F811 - this backend only
    """KortexArm through the child process; the watchdog relaxed to 5 s as in the contract's
    in-process Kortex case (its tests hold one command for up to 0.5 s)."""
    from fake_kortex_api.rig import make_child, options

    adapter = make_child(_robot(task_config.robot), monkeypatch,
                         opts=options(watchdog_timeout=5.0))
    yield adapter
    adapter.disconnect()
