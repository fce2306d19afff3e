"""Per-episode diagnostics: failure modes and the moving average, by hand."""

import numpy as np

from ahrm_stack.env.episode import EpisodeSummary
from ahrm_stack.learning.diagnostics import moving_average


def _summary(**changes):
    base = dict(steps=10, duration=0.5, success=False, time_to_success=float("nan"), touched_steps=0,
                learning_return=0.0, phase_steps=[10, 0, 0], phases_visited="1",
                component_sums=[[0.0] * 3] * 3, closest_approach=0.3, cube_displacement=0.0,
                cube_travel=0.0, constraint_terminated=False, constraint_phase=None)
    base.update(changes)
    return EpisodeSummary(**base)


def test_failure_modes():
    assert _summary().failure_mode() == "never reached the cube"
    assert _summary(phase_steps=[5, 3, 2]).failure_mode() == "reached the cube, could not push"
    assert _summary(phase_steps=[5, 3, 2], cube_displacement=0.2).failure_mode() == "stalled"
    assert _summary(touched_steps=3).failure_mode() == "hit obstacles"
    assert _summary(success=True, time_to_success=3.0).failure_mode() == "success"
    assert _summary(success=True, touched_steps=1).failure_mode() == "touched"


def test_moving_average_by_hand():
    np.testing.assert_allclose(moving_average(np.array([1.0, 2.0, 3.0, 4.0, 5.0]), 2),
                               [1.0, 1.5, 2.5, 3.5, 4.5])
    np.testing.assert_allclose(moving_average(np.array([0.0, 1.0, 1.0]), 10), [0.0, 0.5, 2 / 3])


def test_a_log_without_its_header_is_a_clear_error_not_a_crash(tmp_path):
    import pytest

    from ahrm_stack.learning.diagnostics import main, read_episodes

    (tmp_path / "episodes.csv").write_text('1,64,40,2.0,False,nan,0,0.0,"[0, 40, 0]"\n')
    with pytest.raises(ValueError, match=r"the first line is not the header .*--resume"):
        read_episodes(tmp_path)
    assert main([str(tmp_path)]) == 2
    (tmp_path / "episodes.csv").write_text("")
    with pytest.raises(ValueError, match="holds no episodes yet"):
        read_episodes(tmp_path)
