"""The deploy settings (``configs/deploy.yaml``): sections of the project's configuration system.

:func:`load_deploy_settings` reads the file, applies the command line's values and returns a
frozen :class:`DeploySettings` (:mod:`ahrm_stack.schema`: the rules sit beside the fields); every
bad, missing or unknown key is a one-line :class:`DeployConfigError` naming it and the file
(``deploy.watchdog.max_feedback_age must be > 0, got 0.0 (configs/deploy.yaml)``), raised before
anything is written or the arm is touched. The ``kinova_gen2`` section is
:class:`ahrm_stack.hardware.kinova_gen2.Gen2Settings`.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from ahrm_stack.config import CONFIG_DIR, ROBOTS_DIR, arm_names, compose_deploy
from ahrm_stack.realism import RealismConfig, resolve_realism
from ahrm_stack.schema import (Bool, ConfigError, FilePath, Float, Int, Section, Str, count, ge, gt, le,
                               read_yaml, show_path, stricter, validate)
from ahrm_stack.hardware.kinova_gen2 import Gen2Settings

DEPLOY_CONFIG = CONFIG_DIR / "deploy.yaml"

Pos = Annotated[Float, gt(0)]
NonNeg = Annotated[Float, ge(0)]
PosInt = Annotated[Int, gt(0)]


class DeployConfigError(ValueError):
    """A deploy setting is missing, unknown or invalid; the message names the key."""


@dataclasses.dataclass(frozen=True)
class WatchdogSettings(Section):
    max_feedback_age: Pos  # control periods
    command_deadline: Annotated[Float, gt(0), le(1, " period")]  # control periods after the tick
    max_deadline_misses: Annotated[Int, ge(0)]  # tolerated before a stop (0: the first miss stops)
    velocity_tolerance: NonNeg  # fraction over the velocity limit a measured speed may reach
    velocity_alarm_ticks: Annotated[Int, ge(1)]  # consecutive readings over it that e-stop (1: the first)


@dataclasses.dataclass(frozen=True)
class SuccessSettings(Section):
    """When the loop declares success (:class:`~ahrm_stack.deploy.judging.SuccessJudge`)."""

    edge_margin: NonNeg  # m the perceived cube centre must be past a table edge (or below the top)
    sustain_ticks: PosInt  # consecutive control ticks it must be perceived there
    confirm_time: NonNeg  # s of perception re-read after the stop; the cube must still be off


@dataclasses.dataclass(frozen=True)
class TouchSettings(Section):
    """Touching estimated from the perceived obstacle positions
    (:class:`~ahrm_stack.deploy.judging.TouchEstimator`)."""

    displacement: Pos  # m, horizontal, from an obstacle's start position: more counts as touched
    reference_ticks: PosInt  # control ticks whose median perceived position is the start position
    sustain_ticks: PosInt  # consecutive control ticks an obstacle must be perceived displaced


@dataclasses.dataclass(frozen=True)
class ProgressSettings(Section):
    """The progress watchdog (:class:`~ahrm_stack.deploy.judging.ProgressWatchdog`)."""

    timeout: NonNeg  # s without task progress before the arm is stopped; 0: off
    epsilon: Pos  # m the best task progress must improve by to count as progress


@dataclasses.dataclass(frozen=True)
class ContactSettings(Section):
    """The contact stop (:class:`~ahrm_stack.deploy.contact.ContactStop`): a momentum observer's
    external torque over a joint's threshold e-stops the arm."""

    enabled: Bool  # false: no contact stop (the estimate is still not computed)
    observer_gain: Pos  # 1/s, K of the estimate's low-pass; K x the control period must be <= 1
    readings: PosInt  # consecutive feedback readings over a joint's threshold that make a contact
    threshold_nm: dict[Str, tuple[Pos, ...]]  # robot description (task.robot) -> N·m per joint: each
    # arm's contact_threshold_nm (configs/robots/<arm>.yaml)


@dataclasses.dataclass(frozen=True)
class StartPostureSettings(Section):
    """How near the trained start the arm must be before the loop's first command
    (:func:`~ahrm_stack.deploy.start_check.start_refusal`)."""

    joint_tolerance_deg: Annotated[Float, ge(0), le(90)]  # deg beyond task.arm.joint_jitter, per joint
    # (task.arm.start: home)
    region_margin: Annotated[Float, ge(0), le(0.5)]  # m the start region is grown by (start: random)
    tilt_tolerance_deg: Annotated[Float, ge(0), le(90)]  # deg of the pusher from straight down
    # (start: random)


@dataclasses.dataclass(frozen=True)
class SimSettings(Section):
    command_delay: NonNeg  # s
    realism: RealismConfig  # the simulated arm's and camera's imperfections (a set of
    # configs/realism.yaml by name, e.g. ideal or jaco2, or the values)




@dataclasses.dataclass(frozen=True)
class KortexModelSection(Section):
    """The Kortex arm a robot description is (ahrm_stack/hardware/kortex/arm_model.py)."""

    model: Literal["MODEL_ID_L53", "MODEL_ID_L31", "MODEL_ID_HDK"]  # ProductConfiguration.ModelId
    dof: Annotated[Int, ge(1), le(7)]  # ProductConfiguration.degree_of_freedom


#: ``ControlConfig.ControlMode`` names (enums/ControlConfig/ControlMode.md) whose soft limits apply
KortexControlMode = Literal["ANGULAR_JOYSTICK", "CARTESIAN_JOYSTICK", "ANGULAR_TRAJECTORY",
                            "CARTESIAN_TRAJECTORY", "CARTESIAN_ADMITTANCE", "JOINT_ADMITTANCE",
                            "NULL_SPACE_ADMITTANCE", "FORCE_CONTROL", "FORCE_CONTROL_MOTION_RESTRICTED",
                            "CARTESIAN_WAYPOINT_TRAJECTORY", "IDLE"]


@dataclasses.dataclass(frozen=True)
class KortexHomeSection(Section):
    """``kortex.home``: the homing step (``--home``, ahrm_stack/hardware/kortex/home.py): one
    ``ReachJointAngles`` action to the policy's start, supervised."""

    # deg/s: the action's JOINT_CONSTRAINT_SPEED, every joint
    speed_deg_s: Annotated[Float, gt(0), le(20.0, " deg/s: the homing move is a slow, supervised "
                                             "first motion")]
    tolerance_deg: Annotated[Float, gt(0), le(5.0)]  # deg: each joint this near its target at ACTION_END
    still_deg_s: Annotated[Float, gt(0), le(5.0)]  # deg/s: every joint slower than this is still
    timeout: Annotated[Float, gt(0), le(600.0)]  # s the move may take before the arm is stopped
    # control periods between two feedback polls while the arm moves
    poll_periods: Annotated[Float, gt(0), le(0.5, " (a fault, the timeout or a lost link is then seen, "
                                                  "and Stop sent, within one control period)")]
    clearance: Annotated[Float, ge(0), le(0.5)]  # m: the pusher tip above the table top all along
    # the planned joint-space path
    path_tolerance_deg: Annotated[Float, gt(0), le(20.0)]  # deg: a joint further than this from the
    # planned straight joint-space path stops the arm


@dataclasses.dataclass(frozen=True)
class KortexSection(Section):
    address: Optional[Str]  # the arm's IP address: required, never defaulted
    port: PosInt
    session_inactivity_timeout_ms: PosInt
    connection_inactivity_timeout_ms: PosInt
    credentials_file: Optional[Str]
    rpc_timeout_ms: PosInt  # every feedback / motion / mode RPC
    session_rpc_timeout_ms: PosInt  # CreateSession / CloseSession and the reads on connect
    # the best-effort Base.Stop (and CloseSession) after a lost link
    lost_link_stop_timeout_ms: Annotated[Int, gt(0), stricter("lower")]
    # control periods without a fresh command before Stop
    watchdog_periods: Annotated[Float, gt(1, " (a healthy loop sends one command per period)")]
    watchdog_poll_periods: Pos  # control periods between two watchdog checks
    reset_wait_ms: PosInt  # clear_faults waits this long for the arm to leave fault
    reset_poll_ms: PosInt  # feedback polls during that wait
    reset_estop_repeats: PosInt  # ApplyEmergencyStop calls before ClearFaults
    python: Optional[Str]  # the interpreter that runs kortex_api in its own process; null: this one
    process_start_timeout_ms: PosInt  # it must import kortex_api and answer within this
    process_margin_ms: PosInt  # ... and answer each call within the call's timeout plus this
    models: dict[Str, KortexModelSection]  # robot description (task.robot) -> the Kortex arm it is
    speed_limit_tolerance: Annotated[Float, ge(0), le(1), stricter("lower")]  # description's
    # velocity limit over the arm's joint speed hard limit, as a fraction
    refuse_zones_in_workspace: Annotated[Bool, stricter("on")]  # a protection zone in the task
    # workspace refuses the connection (false: it is reported only)
    workspace_height: Annotated[Float, gt(0), le(2.0), stricter("higher")]  # m above the table top
    # ControlConfig soft limits (GetAllKinematicSoftLimits) read on connect: the lowest joint speed
    # soft limit of these control modes must allow the policy's velocity limit
    soft_limit_modes: Annotated[tuple[KortexControlMode, ...], count(1)]
    soft_limit_tolerance: Annotated[Float, ge(0), le(1), stricter("lower")]  # the description's
    # velocity limit over the arm's soft limit, as a fraction
    action_rpc_timeout_ms: PosInt  # ExecuteAction, OnNotificationActionTopic, Unsubscribe (--home)
    contact_torques: Bool  # the BaseCyclic torques feed the deploy loop's contact stop (deploy.contact):
    # their zero and sign against the arm's model are unmeasured on an arm, so off by default
    check_ticks: Annotated[Int, ge(10), le(100000)]  # --check: control ticks measured
    home: KortexHomeSection  # --home
    scene: FilePath  # the static scene layout (ahrm_stack/hardware/scene.py) a run uses for perception

    def check(self, key: str) -> None:
        if self.watchdog_poll_periods > 0.5 * self.watchdog_periods:
            raise ConfigError(f"{key}.watchdog_poll_periods must be <= half of {key}.watchdog_periods, "
                              f"got {self.watchdog_poll_periods!r}")
        if self.reset_poll_ms > self.reset_wait_ms:
            raise ConfigError(f"{key}.reset_poll_ms must be <= {key}.reset_wait_ms, got "
                              f"{self.reset_poll_ms!r}")
        if self.python is not None and not self.python.strip():
            raise ConfigError(f"{key}.python must be null (this interpreter) or a path, got "
                              f"{self.python!r}")


@dataclasses.dataclass(frozen=True)
class DeploySettings(Section):
    rate_hz: Pos  # Hz, the control loop's rate
    duration: Pos  # s
    realtime: Bool
    seed: Annotated[Int, ge(0)]
    telemetry: Str  # path; '' for none
    record_mcap: Bool  # the telemetry's records also in MCAP beside it (<telemetry>.mcap; deploy/record.py)
    # the perception's camera frames in that MCAP too (/camera/image, foxglove.CompressedImage); needs
    # record_mcap, and --scene camera (a run without a camera is refused in one line naming this key)
    record_frames: Bool
    record_frames_every: Annotated[Int, ge(1)]  # every N-th frame of the camera is recorded (1: each; the sim
    # camera renders one per control tick, a real camera perception.source.fps a second)
    record_frames_format: Literal["jpeg", "png"]  # jpeg: quality 90, lossy; png: lossless, several times larger
    watchdog: WatchdogSettings
    success: SuccessSettings
    touch: TouchSettings
    progress: ProgressSettings
    contact: ContactSettings
    start_posture: StartPostureSettings
    sim: SimSettings
    kortex: KortexSection
    kinova_gen2: Gen2Settings

    @property
    def period(self) -> float:
        """s per control period."""
        return 1.0 / self.rate_hz

    def check(self, key: str) -> None:
        if control_periods(self.duration, self.period) < 1:
            raise ConfigError(f"{key}.rate_hz {self.rate_hz!r} Hz with {key}.duration {self.duration!r} s "
                              "gives no control period: the loop would not run")
        if 0 < self.progress.timeout < self.period:
            raise ConfigError(f"{key}.progress.timeout must be 0 (off) or at least one control period "
                              f"({self.period:g} s), got {self.progress.timeout!r}")
        if self.record_frames and not self.record_mcap:
            raise ConfigError(f"{key}.record_frames needs {key}.record_mcap true: the frames go into the "
                              "telemetry's MCAP twin")
        timeout = self.kortex.connection_inactivity_timeout_ms
        if 1e3 / self.rate_hz > timeout:
            raise ConfigError(f"{key}.rate_hz {self.rate_hz!r} Hz: a control period of {self.period:g} s "
                              f"is longer than {key}.kortex.connection_inactivity_timeout_ms ({timeout} ms), "
                              "after which the arm stops itself between two commands")
        if self.contact.enabled and self.contact.observer_gain * self.period > 1:
            raise ConfigError(f"{key}.contact.observer_gain {self.contact.observer_gain!r} 1/s times the control "
                              f"period {self.period:g} s must be <= 1 (the estimate's low-pass step; or set "
                              f"{key}.contact.enabled false)")


def control_periods(duration: float, period: float) -> int:
    """Ticks of a run of ``duration`` s at ``period`` s per tick."""
    return int(round(duration / period))


def deploy_settings_from_dict(data: Any) -> DeploySettings:
    """Validate a parsed ``deploy.yaml``; :class:`DeployConfigError` names the first bad key."""
    return validate(DeploySettings, data, "deploy", error=DeployConfigError)


def load_deploy_settings(path: Path | str = DEPLOY_CONFIG, robots_dir: Path | str = ROBOTS_DIR,
                         **overrides: Any) -> DeploySettings:
    """Read and validate ``path``, with ``kinova_gen2.joints`` and ``kortex.models`` composed from
    the arm registry ``robots_dir`` (``configs/robots/<arm>.yaml``) where ``path`` does not give
    them; ``overrides`` (the command line's values) replace top-level keys (None values are
    ignored). An error names the key, the file (an arm's file for a composed value) and the
    command-line values it involves."""
    data = read_yaml(path, DeployConfigError)
    given_here = {section for section, key in (("kinova_gen2", "joints"), ("kortex", "models"))
                  if isinstance(data.get(section), dict) and key in data[section]}
    try:
        compose_deploy(data, robots_dir)
    except ConfigError as error:
        raise DeployConfigError(str(error)) from None
    given = {k: v for k, v in overrides.items() if v is not None}
    realism = given.pop("realism", None)  # a set of configs/realism.yaml for the sim backend
    data.update(given)
    try:
        sim = data.get("sim")
        if isinstance(sim, dict):
            if realism is not None:
                sim = {**sim, "realism": realism}
            data["sim"] = {**sim, "realism": resolve_realism(sim.get("realism"), "deploy.sim.realism")}
        return deploy_settings_from_dict(data)
    except (DeployConfigError, ConfigError) as error:
        named = [f"{k}={v!r}" for k, v in given.items() if re.search(rf"deploy\.{k}\b", str(error))]
        arm = re.search(r"deploy\.(kinova_gen2)\.joints\.(\w+)|deploy\.(kortex)\.models\.(\w+)", str(error))
        section, name = (arm.group(1) or arm.group(3), arm.group(2) or arm.group(4)) if arm else ("", "")
        if arm and section not in given_here and name in arm_names(robots_dir):  # from the arm's entry
            text = re.sub(rf"deploy\.kinova_gen2\.joints\.{name}\b", f"robots/{name}.kinova_gen2", str(error))
            text = re.sub(rf"deploy\.kortex\.models\.{name}\b", f"robots/{name}.kortex", text)
            raise DeployConfigError(f"{text} ({show_path(Path(robots_dir) / f'{name}.yaml')})") from None
        where = f"command line {', '.join(named)}; {show_path(path)}" if named else show_path(path)
        raise DeployConfigError(f"{error} ({where})") from None
