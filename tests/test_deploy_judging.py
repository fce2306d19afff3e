"""How a deploy run went, judged from perception alone (``ahrm_stack/deploy/judging.py``): success
needs the cube perceived past the table edge by a margin for several ticks and still off after the
stop (or gone from view), so perception noise near the edge never makes one; an obstacle perceived displaced counts as
touched, perception noise does not; the progress watchdog stops a run without task progress and
leaves the scripted controller's episodes alone; the new settings are validated key by key."""

from __future__ import annotations

import dataclasses
import io
import json
import re

import numpy as np
import pytest
import yaml

from ahrm_stack.config import load_config
from ahrm_stack.deploy import (DEPLOY_CONFIG, DeployConfigError, DeployFault, DeployLoop,
                               ScriptedController, WorldModel, load_deploy_settings)
from ahrm_stack.deploy.loop import DeploySummary
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm

CONFIG = load_config()
HX, HY = CONFIG.task.table.half_extent
TOP = CONFIG.task.table.height


class NoisyArm(SimArm):
    """The sim arm whose perception adds N(0, sigma) noise (m, per axis) to the cube's and the
    obstacles' positions; ``true_cube`` keeps (clock time, true cube position) of every read."""

    def __init__(self, *args, cube_noise: float = 0.0, obstacle_noise: float = 0.0,
                 noise_seed: int = 0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.rng = np.random.default_rng(noise_seed)
        self.cube_noise, self.obstacle_noise = cube_noise, obstacle_noise
        self.true_cube: list[tuple[float, np.ndarray]] = []
        self.perceived: list[np.ndarray] = []

    def perception(self):
        poses = super().perception()
        self.true_cube.append((self.clock.now(), poses.cube_position.copy()))
        cube = poses.cube_position + self.rng.normal(0, self.cube_noise, 3)
        self.perceived.append(cube)
        return dataclasses.replace(
            poses, cube_position=cube, obstacle_positions=poses.obstacle_positions
            + self.rng.normal(0, self.obstacle_noise, poses.obstacle_positions.shape))

    def place_cube(self, x: float, y: float) -> None:
        """Move the cube (at rest, on the table top) to (x, y), m."""
        data = self.physics.data
        data.qpos[self._cube_qpos[:2]] = (x, y)
        data.qpos[self._cube_qpos[2]] = TOP + CONFIG.task.cube.size / 2
        data.qpos[self._cube_qpos[3:]] = (1.0, 0.0, 0.0, 0.0)
        data.qvel[self._cube_dof] = 0.0
        self.physics.forward()


class Still:
    """A controller that commands zero joint velocity."""

    stage = "still"
    cartesian = False

    def __init__(self, world: WorldModel) -> None:
        self.size = world.robot.num_joints

    def reset(self) -> None:
        pass

    def __call__(self) -> np.ndarray:
        return np.zeros(self.size)


def _settings(**sections):
    """Fast deploy settings; ``sections``: field overrides per section (``progress={...}``)."""
    settings = load_deploy_settings(realtime=False, telemetry="")
    return dataclasses.replace(settings, **{name: dataclasses.replace(getattr(settings, name), **fields)
                                            for name, fields in sections.items()})


def _run(arm: SimArm, world: WorldModel, controller, settings, duration: float):
    telemetry = io.StringIO()
    arm.connect()
    loop = DeployLoop(arm, world, controller, CONFIG.safety, settings, telemetry)
    summary = loop.run(duration)
    lines = [json.loads(line) for line in telemetry.getvalue().splitlines()]
    return loop, summary, lines


def _true_off_table(position) -> bool:
    x, y, z = position
    return abs(x) > HX or abs(y) > HY or z < TOP


# --------------------------------------------------------------------------- success
@pytest.mark.parametrize("x, y", [(HX - 0.004, -0.35), (-(HX - 0.004), -0.35), (0.0, -(HY - 0.004))])
def test_perception_noise_at_the_edge_is_not_a_success(x, y):
    """The cube at rest 4 mm inside an edge, perceived with 4 mm noise: single reads past the
    edge are common (the task's own test would call the run a success), the judged run is not
    one."""
    arm = NoisyArm(CONFIG.task, seed=0, clock=FastClock(), cube_noise=0.004, noise_seed=1)
    arm.place_cube(x, y)
    world = WorldModel(CONFIG.task, seed=0)
    loop, summary, lines = _run(arm, world, Still(world), _settings(), 3.0)
    assert not summary.success and summary.stop_reason == "duration of 3 s reached", summary
    assert not any(line.get("event") == "success judgement" for line in lines)
    assert sum(_true_off_table(p) for p in arm.perceived) >= 3  # the naive test fired
    assert not any(_true_off_table(truth) for _, truth in arm.true_cube)  # the cube stayed on


@pytest.mark.parametrize("seed", [3, 10, 13])
def test_a_real_push_off_with_noisy_perception_is_a_success(seed):
    """The scripted controller on 4 mm-noisy perception, on seeds where the task's own test (one
    read past the edge) saw the cube off the table while it was still on it: the judged success
    comes once the true cube is off. (Seeds 0-15: 16/16 successes, 4 such early reads.)"""
    arm = NoisyArm(CONFIG.task, seed=seed, clock=FastClock(), cube_noise=0.004, noise_seed=seed)
    world = WorldModel(CONFIG.task, seed=seed)
    loop, summary, lines = _run(arm, world, ScriptedController(world, CONFIG), _settings(), 20.0)
    assert summary.success and summary.stop_reason.startswith("success: "), summary
    naive = next(i for i, cube in enumerate(arm.perceived) if _true_off_table(cube))
    assert not _true_off_table(arm.true_cube[naive][1])  # the naive success would have been false
    at_stop = [truth for t, truth in arm.true_cube if t <= loop.stopped_at + 1e-9][-1]
    assert _true_off_table(at_stop), at_stop
    judgement = next(line for line in lines if line.get("event") == "success judgement")
    assert judgement["confirmed"] is True and len(judgement["cube"]) == 3
    assert judgement["sustained_ticks"] == 3 and len(judgement["confirmation_reads"]) == 10
    assert lines[-1]["summary"]["success"] is True


class GlitchArm(NoisyArm):
    """Perception reports the cube 0.6 m away in +x (off the table) for ``ticks`` reads from the
    ``start``-th on, then where it is."""

    def __init__(self, *args, start: int, ticks: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reads, self.start, self.ticks = 0, start, ticks

    def perception(self):
        poses = super().perception()
        self.reads += 1
        if self.start <= self.reads < self.start + self.ticks:
            return dataclasses.replace(poses, cube_position=poses.cube_position + (0.6, 0, 0))
        return poses


@pytest.mark.parametrize("ticks, judged", [(2, False), (6, True)])
def test_a_success_that_perception_takes_back_after_the_stop_is_not_one(ticks, judged):
    arm = GlitchArm(CONFIG.task, seed=0, clock=FastClock(), start=10, ticks=ticks)
    world = WorldModel(CONFIG.task, seed=0)
    loop, summary, lines = _run(arm, world, Still(world), _settings(), 2.0)
    assert not summary.success and not loop.success
    events = [line for line in lines if line.get("event") == "success judgement"]
    if not judged:  # 2 ticks < success.sustain_ticks
        assert not events and "duration" in summary.stop_reason
        return
    assert summary.stop_reason.startswith("success not confirmed: "), summary.stop_reason
    assert "back on the table" in summary.stop_reason and summary.fault == ""
    (event,) = events
    assert event["confirmed"] is False and event["cube"][0] > HX
    np.testing.assert_array_equal(arm.command, 0.0)  # stopped
    stop = [line for line in lines if line.get("event") == "stop"]
    assert stop[-1]["reason"] == summary.stop_reason == lines[-1]["summary"]["stop_reason"]


class VanishingArm(SimArm):
    """Perception raises (as a camera's tracker does once the tag turned away) from the ``after``-th
    read that has the cube past the table edge by ``margin`` on."""

    def __init__(self, *args, after: int, margin: float, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.after, self.margin, self.off_reads = after, margin, 0

    def perception(self):
        poses = super().perception()
        x, y, _ = poses.cube_position
        if abs(x) - HX > self.margin or abs(y) - HY > self.margin:
            self.off_reads += 1
            if self.off_reads > self.after:
                raise RuntimeError("tag not seen for 0.300 s")
        return poses


@pytest.mark.parametrize("after, reason", [
    (1, "for 1 tick, then gone from view (RuntimeError: tag not seen for 0.300 s)"),
    (3, "for 3 ticks, then gone from view at the first read after the stop (RuntimeError"),
    (5, "for 3 ticks, still off in 2 reads after the stop, then gone from view (RuntimeError")])
def test_a_cube_perceived_off_the_table_then_gone_from_view_is_a_success(after, reason):
    settings = _settings()
    arm = VanishingArm(CONFIG.task, seed=0, clock=FastClock(), after=after,
                       margin=settings.success.edge_margin)
    world = WorldModel(CONFIG.task, seed=0)
    _, summary, lines = _run(arm, world, ScriptedController(world, CONFIG), settings, 20.0)
    assert summary.success and summary.fault == "" and reason in summary.stop_reason, summary
    (event,) = [line for line in lines if line.get("event") == "success judgement"]
    assert event["confirmed"] and "tag not seen" in event["gone_from_view"]


def test_a_cube_gone_from_view_before_it_was_perceived_off_the_table_is_a_perception_fault():
    arm = VanishingArm(CONFIG.task, seed=0, clock=FastClock(), after=0, margin=0.0)
    world = WorldModel(CONFIG.task, seed=0)
    with pytest.raises(DeployFault, match="perception fault: RuntimeError: tag not seen") as fault:
        _run(arm, world, ScriptedController(world, CONFIG), _settings(), 20.0)
    assert not fault.value.summary.success


# --------------------------------------------------------------------------- touching
class ShiftedArm(SimArm):
    """Perception reports obstacle ``index`` moved by ``shift`` (m, x) from the ``start``-th read."""

    def __init__(self, *args, index: int, shift: float, start: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.index, self.shift, self.start, self.reads = index, shift, start, 0

    def perception(self):
        poses = super().perception()
        self.reads += 1
        if self.reads >= self.start:
            moved = poses.obstacle_positions.copy()
            moved[self.index, 0] += self.shift
            return dataclasses.replace(poses, obstacle_positions=moved)
        return poses


def test_an_obstacle_perceived_displaced_is_touched():
    settings = _settings()
    arm = ShiftedArm(CONFIG.task, seed=0, clock=FastClock(), index=2, shift=0.015, start=31)
    world = WorldModel(CONFIG.task, seed=0)
    loop, summary, lines = _run(arm, world, Still(world), settings, 3.0)
    # read 1 is start-up's; tick k (from 0) makes read k + 2, so the shift is seen from tick 29
    first = (29 + settings.touch.sustain_ticks - 1) * settings.period
    assert summary.touched and summary.touched_obstacles == [2]
    assert summary.first_touch_time == pytest.approx(first)
    ticks = [line for line in lines if "latency_ms" in line]
    assert [t["touched"] for t in ticks] == [t["t"] >= first - 1e-9 for t in ticks]
    (event,) = [line for line in lines if line.get("event") == "touch"]
    assert event["obstacle"] == 2 and event["first"] and event["displacement"] == pytest.approx(0.015)
    assert lines[-1]["summary"]["touched_obstacles"] == [2]
    assert "touched True (obstacles [2], first at" in str(summary) and "\n" not in str(summary)


def test_a_displacement_under_the_threshold_is_not_a_touch():
    arm = ShiftedArm(CONFIG.task, seed=0, clock=FastClock(), index=0, shift=0.008, start=31)
    world = WorldModel(CONFIG.task, seed=0)
    _, summary, _ = _run(arm, world, Still(world), _settings(), 3.0)
    assert not summary.touched and summary.touched_obstacles == [] and summary.first_touch_time is None


@pytest.mark.parametrize("controller", ["still", "scripted"])
def test_obstacle_perception_noise_is_not_a_touch(controller):
    """3 mm noise on every obstacle position for a whole run: 20 s standing still (400 ticks), and
    the scripted controller's push-off (which touches nothing)."""
    arm = NoisyArm(CONFIG.task, seed=1, clock=FastClock(), obstacle_noise=0.003, noise_seed=3)
    world = WorldModel(CONFIG.task, seed=1)
    chosen = Still(world) if controller == "still" else ScriptedController(world, CONFIG)
    _, summary, lines = _run(arm, world, chosen, _settings(progress={"timeout": 0.0}), 20.0)
    assert summary.success == (controller == "scripted"), summary
    assert not summary.touched and not any(line.get("touched") for line in lines)
    assert not any(line.get("event") == "touch" for line in lines)


# --------------------------------------------------------------------------- progress
def test_the_progress_watchdog_stops_a_run_without_progress():
    settings = _settings()
    timeout = settings.progress.timeout
    arm = SimArm(CONFIG.task, seed=0, clock=FastClock())
    world = WorldModel(CONFIG.task, seed=0)
    loop, summary, lines = _run(arm, world, Still(world), settings, 20.0)
    assert summary.stop_reason.startswith(f"watchdog: no task progress for {timeout:.1f} s (best progress ")
    # the sim arm sags under gravity at zero command (~2 mm/s): its progress measure creeps, by
    # less than progress.epsilon in the timeout, and it crosses into phase 3 (no progress either)
    assert re.search(r"best progress -?\d\.\d{3} m at t=\d+\.\d\d s, highest phase \d\)$",
                     summary.stop_reason), summary.stop_reason
    assert summary.duration == pytest.approx(timeout + settings.period)  # the tick at t = timeout
    assert not summary.success and summary.emergency_stops == 0 and summary.fault == ""
    np.testing.assert_array_equal(arm.command, 0.0)
    stop = [line for line in lines if line.get("event") == "stop"]
    assert len(stop) == 1 and stop[0]["reason"] == summary.stop_reason
    assert lines[-1]["summary"]["stop_reason"] == summary.stop_reason


def test_the_progress_watchdog_is_off_at_zero():
    arm = SimArm(CONFIG.task, seed=0, clock=FastClock())
    world = WorldModel(CONFIG.task, seed=0)
    _, summary, _ = _run(arm, world, Still(world), _settings(progress={"timeout": 0.0}), 10.0)
    assert summary.stop_reason == "duration of 10 s reached"


@pytest.mark.parametrize("seed", [4, 7])  # among the slowest scripted episodes (4.5-5.2 s)
def test_the_progress_watchdog_leaves_the_scripted_controller_alone(seed):
    """Its longest stretch without progress in 12 episodes was 1.55 s; with a timeout of 2.5 s
    (under a third of the configured 8 s) it still finishes."""
    arm = SimArm(CONFIG.task, seed=seed, clock=FastClock())
    world = WorldModel(CONFIG.task, seed=seed)
    _, summary, _ = _run(arm, world, ScriptedController(world, CONFIG),
                         _settings(progress={"timeout": 2.5}), 20.0)
    assert summary.success and "watchdog" not in summary.stop_reason, summary


# --------------------------------------------------------------------------- settings
@pytest.mark.parametrize("section, key, value, message", [
    ("success", "edge_margin", -0.01, "deploy.success.edge_margin must be >= 0"),
    ("success", "sustain_ticks", 0, "deploy.success.sustain_ticks must be > 0"),
    ("success", "sustain_ticks", 2.5, "deploy.success.sustain_ticks: expected an integer"),
    ("success", "confirm_time", "soon", "deploy.success.confirm_time: expected a number"),
    ("touch", "displacement", 0.0, "deploy.touch.displacement must be > 0"),
    ("touch", "reference_ticks", -3, "deploy.touch.reference_ticks must be > 0"),
    ("touch", "sustain_ticks", None, "deploy.touch.sustain_ticks"),
    ("touch", "colour", 1, "unknown config key 'deploy.touch.colour'"),
    ("progress", "timeout", -1.0, "deploy.progress.timeout must be >= 0"),
    ("progress", "timeout", 0.01, "deploy.progress.timeout must be 0 (off) or at least one control period"),
    ("progress", "epsilon", 0, "deploy.progress.epsilon must be > 0"),
    ("progress", "epsilon", float("nan"), "deploy.progress.epsilon: must be finite"),
])
def test_bad_judging_settings_are_one_line_errors_naming_the_key(tmp_path, section, key, value, message):
    data = yaml.safe_load(DEPLOY_CONFIG.read_text())
    if value is None:
        data[section].pop(key)
    else:
        data[section][key] = value
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(DeployConfigError) as error:
        load_deploy_settings(path)
    text = str(error.value)
    assert message in text and str(path) in text and "\n" not in text, text


def test_the_configured_judging_settings():
    settings = load_deploy_settings()
    assert settings.success.edge_margin > 0 and settings.success.sustain_ticks >= 2
    assert settings.touch.sustain_ticks >= 2 and settings.progress.timeout > 0


def test_the_summary_is_one_line_with_the_touch_fields():
    summary = DeploySummary(success=False, duration=1.0, ticks=20, interventions=0, fallbacks=0,
                            deadline_misses=0, latency_p50_ms=1.0, latency_p99_ms=2.0,
                            stop_reason="duration of 1 s reached", emergency_stops=0,
                            adapter_refusals=0)
    assert summary.touched is False and summary.touched_obstacles == [] and summary.first_touch_time is None
    assert "| touched False |" in str(summary) and "\n" not in str(summary)
    touched = dataclasses.replace(summary, touched=True, touched_obstacles=[1, 3], first_touch_time=0.65)
    assert "touched True (obstacles [1, 3], first at 0.65 s)" in str(touched)
    assert "\n" not in str(touched)
