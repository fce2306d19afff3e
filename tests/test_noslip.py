"""``task.episode.noslip_iterations``: MuJoCo's noslip passes per physics step.

dm_control's composer arena sets 5 (with ``noslip_tolerance`` 0, so all of them run every step); the
key makes that a config value, 5 by default, so every earlier run replays as it was. The physics
checks hold the cube on the table to Coulomb friction's closed forms (mass m, the contact's friction
coefficient mu as MuJoCo combines the two geoms', a horizontal force F at the cube's bottom face so
that it slides without tipping): above mu m g it slides with acceleration (F - mu m g) / m, with or
without the noslip passes; below, it holds, and the passes shrink the soft contacts' residual slip.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from ahrm_stack.config import ConfigError, config_from_dict, load_config
from ahrm_stack.env.runner import TaskRunner
from ahrm_stack.env.task import PushOffTask

ROOT = Path(__file__).resolve().parent.parent


def _runner(noslip: int) -> TaskRunner:
    config = load_config([f"task.episode.noslip_iterations={noslip}", "task.realism=ideal"])
    runner = TaskRunner(PushOffTask(config.task), seed=0)
    runner.reset()
    return runner


@pytest.mark.parametrize("noslip", [0, 2, 5])
def test_the_option_follows_the_config(noslip):
    assert _runner(noslip).physics.model.ptr.opt.noslip_iterations == noslip


def test_old_run_folders_and_the_default_keep_the_arena_s_five():
    run = ROOT / "tests/data/legacy_run_configs/scratch-study/round6/runs/mirror-nj-fhrm-seed0"  # as written
    assert "noslip_iterations" not in (run / "config.yaml").read_text()
    assert config_from_dict(yaml.safe_load((run / "config.yaml").read_text())).task.episode.noslip_iterations == 5
    assert load_config([]).task.episode.noslip_iterations == 5


def test_a_negative_count_is_a_one_line_error_naming_the_key():
    with pytest.raises(ConfigError, match="task.episode.noslip_iterations") as error:
        load_config(["task.episode.noslip_iterations=-1"])
    assert "\n" not in str(error.value)


def _push_cube(runner: TaskRunner, ratio: float, seconds: float) -> tuple[float, float, float]:
    """Push the resting cube along +x with ``ratio`` x mu m g at its bottom face for ``seconds``:
    (displacement m, mean acceleration over the second half m/s^2, the closed form's m/s^2)."""
    model, data = runner.physics.model.ptr, runner.physics.data.ptr
    cube = int(runner.task._cube_body)
    mass, g = float(model.body_mass[cube]), -float(model.opt.gravity[2])
    mus = [data.contact[i].friction[0] for i in range(data.ncon)
           if cube in (model.geom_bodyid[data.contact[i].geom1], model.geom_bodyid[data.contact[i].geom2])]
    assert mus, "the cube rests on the table"
    mu = float(mus[0])
    force = np.array([ratio * mu * mass * g, 0.0, 0.0])
    below = np.array([0.0, 0.0, runner.task.config.cube.size / 2 - 0.002])
    x0, dof = float(data.xpos[cube][0]), int(model.body_dofadr[cube])
    steps = round(seconds / model.opt.timestep)
    velocity = []
    for _ in range(steps):
        data.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(model, data, force, np.zeros(3), data.xpos[cube] - below, cube, data.qfrc_applied)
        mujoco.mj_step(model, data)
        velocity.append(float(data.qvel[dof]))
    data.qfrc_applied[:] = 0.0
    half = steps // 2
    acceleration = (velocity[-1] - velocity[half - 1]) / (model.opt.timestep * (steps - half))
    return float(data.xpos[cube][0]) - x0, acceleration, max(0.0, (force[0] - mu * mass * g) / mass)


@pytest.mark.parametrize("noslip", [0, 5])
@pytest.mark.parametrize("ratio", [1.5, 2.0])
def test_a_pushed_cube_slides_as_coulomb_friction_says(noslip, ratio):
    _, acceleration, expected = _push_cube(_runner(noslip), ratio, 0.1)
    assert acceleration == pytest.approx(expected, rel=0.05)  # 4.9 / 9.8 m/s^2


def test_below_the_friction_limit_the_cube_holds_and_noslip_holds_it_tighter():
    creep = {}
    for noslip in (0, 5):
        displacement, acceleration, expected = _push_cube(_runner(noslip), 0.9, 0.1)
        assert expected == 0.0 and abs(acceleration) < 0.05
        creep[noslip] = displacement
        assert 0.0 <= displacement < 5e-4  # under half a millimetre in 0.1 s
    assert creep[5] < creep[0]
