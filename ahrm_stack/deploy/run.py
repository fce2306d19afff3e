"""Building one deploy run: the controller's config (a checkpoint's, with the safety settings
merged), the telemetry file, the adapter, world model, controller and loop; a fault while
building is recorded like a fault in the loop (:func:`deploy`)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from ahrm_stack.config import Config, ConfigError, load_config
from ahrm_stack.deploy.loop import DeployFault, DeployLoop, DeploySummary
from ahrm_stack.deploy.record import RunLog
from ahrm_stack.deploy.safety_settings import SafetyNote, merge_safety, require_filter
from ahrm_stack.deploy.session import DeploySession
from ahrm_stack.deploy.settings import DeployConfigError, DeploySettings

if TYPE_CHECKING:
    from ahrm_stack.perception.frame_record import FrameRecording

log = logging.getLogger("ahrm_stack.deploy")


def load_controller_config(checkpoint: Path | None, overrides: Sequence[str] = (),
                           notes: list[SafetyNote] | None = None,
                           policy_file: Path | None = None) -> tuple[Config, object]:
    """The config (and actor) of a checkpoint run, or the repository's config with ``overrides``
    (``key=value``, e.g. ``task.robot=j2s6s200``) and no actor. ``policy_file``: another policy of
    the run (e.g. ``policies/episode-N.pt``, the best evaluation) instead of its final
    ``policy.pt``; it needs ``checkpoint`` (the run's config). A checkpoint fixes its own task
    (the arm it was trained on), so it takes no overrides; its safety section never weakens the
    repository's ``configs/safety.yaml`` (:func:`merge_safety`: each difference is logged, and
    appended to ``notes``). Errors are one line: :class:`ConfigError` (the run folder or its
    ``config.yaml``), :class:`~ahrm_stack.learning.checkpoint.CheckpointError` (``policy.pt``,
    e.g. a refused pickle), :class:`DeployConfigError` (the merged safety settings)."""
    if checkpoint is None and policy_file is not None:
        raise ConfigError(f"--policy-file {policy_file} needs --checkpoint (the run folder whose "
                          "config.yaml it was trained with)")
    if checkpoint is None:
        config = load_config(overrides)
        require_filter(config.safety)
        return config, None
    if overrides:
        raise ConfigError(f"overrides {list(overrides)} cannot change a checkpoint's config "
                          f"({checkpoint}/config.yaml fixes the arm and the task)")
    run = Path(checkpoint)
    for name in ("config.yaml",) + (("policy.pt",) if policy_file is None else ()):
        if not (run / name).is_file():
            raise ConfigError(f"--checkpoint {run}: no {name} there (a training run folder holds "
                              "config.yaml and policy.pt)")
    if policy_file is not None and not Path(policy_file).is_file():
        raise ConfigError(f"--policy-file {policy_file}: no such file")
    policy_path = run / "policy.pt" if policy_file is None else Path(policy_file)
    load_config()  # deploy's own configs/ first: a broken file is named before the checkpoint is read
    import torch

    from ahrm_stack.learning.checkpoint import CheckpointError
    from ahrm_stack.learning.rollouts import load_policy

    torch.set_num_threads(1)
    try:
        config, actor = load_policy(run, policy_file, runnable=False)  # its safety section is
        # replaced below
    except (ConfigError, CheckpointError):
        raise
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        first = (str(error).splitlines() or [""])[0][:200]
        raise CheckpointError(f"{policy_path} does not fit {run / 'config.yaml'} "
                              f"({type(error).__name__}: {first})") from None
    # deploy's safety settings for the checkpoint's arm (safety.acceleration_limit is per arm)
    deploy_safety = load_config([f"task.robot={config.task.robot}"]).safety
    safety, differences = merge_safety(deploy_safety, config.safety)
    for note in differences:
        log.log(logging.WARNING if note.kind == "weaker" else logging.INFO, "deploy: %s", note.text)
    if notes is not None:
        notes.extend(differences)
    return dataclasses.replace(config, safety=safety), actor


def open_telemetry(path: str, mcap: bool = False, frames: FrameRecording | None = None) -> RunLog | None:
    """The run's log opened for writing (its folder made): the JSONL telemetry and, with ``mcap``,
    its MCAP twin (:class:`~ahrm_stack.deploy.record.RunLog`), with ``frames`` the camera frames
    put there too; None for ''. A path that cannot be
    written, or a telemetry path ending in .mcap (its twin's name), is a one-line
    :class:`DeployConfigError`."""
    if not path:
        return None
    target = Path(path)
    if mcap and target.suffix == ".mcap":
        raise DeployConfigError(f"deploy.telemetry: {target} ends in .mcap, the suffix of its MCAP twin "
                                "(deploy.record_mcap); name the JSONL telemetry .jsonl")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        return RunLog(target, mcap, frames)
    except OSError as error:
        raise DeployConfigError(f"deploy.telemetry: cannot write {target}: "
                                f"{error.strerror or error}") from None


def _start_up_fault(arm, telemetry, error: BaseException) -> DeployFault:
    """A fault before the loop existed (building the sim, the world model, the controller, the
    filter): stop the arm if it is connected, record the stop and a summary; the DeployFault to
    raise."""
    text = (str(error).splitlines() or [""])[0][:300]
    reason = f"start-up fault: {type(error).__name__}" + (f": {text}" if text else "")
    if arm is not None and arm.is_connected:
        try:
            arm.stop()
        except Exception as stop_error:  # noqa: BLE001 - disconnecting stops it as well
            log.error("deploy: could not stop the arm (%s)", type(stop_error).__name__)
    log.error("deploy: STOP: %s", reason)
    summary = DeploySummary(success=False, duration=0.0, ticks=0, interventions=0, fallbacks=0,
                            deadline_misses=0, latency_p50_ms=math.nan, latency_p99_ms=math.nan,
                            stop_reason=reason, emergency_stops=0, adapter_refusals=0, fault=reason)
    if telemetry is not None:
        try:
            telemetry.write(json.dumps({"t": 0.0, "event": "stop", "reason": reason}) + "\n")
            telemetry.write(json.dumps({"summary": dataclasses.asdict(summary)}) + "\n")
        except (OSError, ValueError):
            pass
    return DeployFault(reason, summary)


def deploy(settings: DeploySettings, checkpoint: Path | None = None,
           overrides: Sequence[str] = (), backend: str = "sim", scene: str = "sim",
           layout_file: Path | str | None = None, policy_file: Path | None = None,
           dry_run: bool = False) -> DeployLoop:
    """One run of the deploy loop against ``backend`` (a name of
    :data:`ahrm_stack.deploy.backends.BACKENDS`, whose ``check`` runs before anything is written or
    contacted and whose ``make`` builds the adapter); returns the finished loop (its
    :meth:`DeployLoop.summary`, :attr:`DeployLoop.interrupted`). ``overrides``: config
    ``key=value`` pairs for the scripted controller's run (no checkpoint). ``policy_file``: another
    policy of the checkpoint's run (:func:`load_controller_config`).

    ``scene``: ``sim`` (the adapter's own ``perception()``: the simulator's exact object poses, or a
    backend's static layout) or ``camera`` (:mod:`ahrm_stack.perception.camera_scene`: the cube from
    the AprilTag on frames of ``perception.source``, MuJoCo renders on the sim backend or a real
    camera or video file in its own thread on any backend, ``configs/perception.yaml``; the
    obstacles from ``layout_file``, or ``perception.layout_file``, or else, on the sim backend,
    surveyed from the simulator at the start into ``layout.yaml`` beside the telemetry, or with no
    telemetry into a temporary folder removed when the run ends).

    ``deploy.record_frames`` puts the camera's frames into the record's MCAP twin
    (:mod:`ahrm_stack.deploy.record`); with ``scene`` ``sim`` it is bad input.

    ``dry_run``: the backend's feedback and scene, every command computed, filtered and logged,
    none sent (:class:`~ahrm_stack.hardware.dry_run.DryRunArm`); stops still reach the arm.

    Bad input (the settings, the checkpoint, its safety settings, the backend's settings, the
    telemetry path) raises a one-line error before anything is written or the arm is touched. From
    then on every end is recorded: a fault in set-up, start-up or the loop stops the arm, writes the
    stop event and the summary to the telemetry and raises :class:`DeployFault`."""
    from ahrm_stack.deploy import backends

    notes: list[SafetyNote] = []
    config, actor = load_controller_config(checkpoint, overrides, notes, policy_file)
    try:
        chosen = backends.get(backend)
        chosen.check(config, settings)
    except ValueError as error:
        raise DeployConfigError(str(error)) from None
    perception = None
    if scene == "camera":  # bad settings, frame source or layout file: one line, nothing written
        from ahrm_stack.perception.calibration import load_calibrated_settings
        from ahrm_stack.perception.camera_scene import check_camera_scene

        perception = load_calibrated_settings()
        layout_file = layout_file or perception.layout_file or None
        check_camera_scene(perception, backend, config.task, layout_file, settings.realtime)
    elif scene != "sim":
        raise DeployConfigError(f"--scene {scene!r}: choose sim or camera")
    recording = None
    if settings.record_frames:
        if perception is None:
            raise DeployConfigError("deploy.record_frames is true, but this run's perception has no camera "
                                    "(--scene sim: the adapter's poses): run --scene camera or set it false")
        from ahrm_stack.perception.frame_record import FrameRecording

        recording = FrameRecording(settings.record_frames_every, settings.record_frames_format)
    control_period = config.task.episode.control_period
    if not math.isclose(settings.period, control_period, rel_tol=1e-9):
        log.warning("deploy: the loop runs at %g Hz; the controller was built for %g Hz "
                    "(task.episode.control_period %g s)", settings.rate_hz, 1.0 / control_period,
                    control_period)
    telemetry = open_telemetry(settings.telemetry, settings.record_mcap, recording)
    arm = source = scratch = None
    try:
        for note in notes if telemetry is not None else ():
            telemetry.write(json.dumps({"t": 0.0, "event": "safety setting", "key": note.key,  # type: ignore[union-attr]
                                        "kind": note.kind, "reason": note.text}) + "\n")
        try:
            arm = chosen.make(config, settings)
            if dry_run:
                from ahrm_stack.hardware.dry_run import DryRunArm

                arm = DryRunArm(arm)
                if telemetry is not None:
                    telemetry.write(json.dumps({"t": 0.0, "event": "dry run", "reason": "commands computed, "
                                                "filtered and logged; none sent"}) + "\n")
                log.info("deploy: DRY RUN: commands are computed, filtered and logged, never sent")
            session = DeploySession.open(arm, config, actor, settings)
            arm.connect()
            if perception is not None:
                from ahrm_stack.perception.camera_scene import camera_scene
                from ahrm_stack.perception.sim_camera import survey_obstacles

                if not layout_file:  # a survey of the simulated table stands in for a measurement
                    if settings.telemetry:
                        folder = Path(settings.telemetry).parent
                    else:  # read once below, then removed with the run
                        import tempfile

                        scratch = tempfile.TemporaryDirectory(prefix="deploy-layout-")
                        folder = Path(scratch.name)
                    layout_file = survey_obstacles(arm, folder / "layout.yaml")
                source = camera_scene(arm, config.task, perception, layout_file,
                                      recording if telemetry is not None else None)
            loop = session.loop(telemetry, source)
        except Exception as error:  # noqa: BLE001 - recorded, then raised as a fault
            raise _start_up_fault(arm, telemetry, error) from error
        except KeyboardInterrupt as error:  # Ctrl-C during set-up: stopped and recorded too
            _start_up_fault(arm, telemetry, error)
            raise
        loop.run(settings.duration)
    finally:
        try:
            if arm is not None and arm.is_connected:
                arm.disconnect()  # stops the arm as well
            if source is not None:
                source.close()
        finally:  # the record is closed (its MCAP twin finished) whatever the above raised
            if telemetry is not None:
                telemetry.close()
            if scratch is not None:
                scratch.cleanup()
    return loop


def deploy_sim(settings: DeploySettings, checkpoint: Path | None = None,
               overrides: Sequence[str] = (), scene: str = "sim",
               layout_file: Path | str | None = None, policy_file: Path | None = None,
               dry_run: bool = False) -> DeployLoop:
    """:func:`deploy` against the sim backend."""
    return deploy(settings, checkpoint, overrides, backend="sim", scene=scene, layout_file=layout_file,
                  policy_file=policy_file, dry_run=dry_run)
