"""The deploy settings (``configs/deploy.yaml``) and their validator.

:func:`load_deploy_settings` reads the file, applies the command line's values and returns a
frozen :class:`DeploySettings`; every bad, missing or unknown key is a one-line
:class:`DeployConfigError` naming it (``deploy.watchdog.max_feedback_age must be ...``), raised
before anything is written or the arm is touched.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Sequence

import yaml

from ahrm_stack.config import CONFIG_DIR

DEPLOY_CONFIG = CONFIG_DIR / "deploy.yaml"


class DeployConfigError(ValueError):
    """A deploy setting is missing, unknown or invalid; the message names the key."""


@dataclasses.dataclass(frozen=True)
class WatchdogSettings:
    max_feedback_age: float  # control periods
    command_deadline: float  # control periods after the tick
    max_deadline_misses: int  # tolerated before a stop (0: the first miss stops)
    velocity_tolerance: float  # fraction over the velocity limit a measured speed may reach


@dataclasses.dataclass(frozen=True)
class SimSettings:
    command_delay: float  # s


@dataclasses.dataclass(frozen=True)
class KortexSection:
    address: str | None
    port: int
    session_inactivity_timeout_ms: int
    connection_inactivity_timeout_ms: int
    credentials_file: str | None
    rpc_timeout_ms: int  # every feedback / motion / mode RPC
    session_rpc_timeout_ms: int  # CreateSession / CloseSession
    watchdog_periods: float  # control periods without a fresh command before Stop
    watchdog_poll_periods: float  # control periods between two watchdog checks
    reset_wait_ms: int  # clear_faults waits this long for the arm to leave fault
    reset_poll_ms: int  # feedback polls during that wait
    reset_estop_repeats: int  # ApplyEmergencyStop calls before ClearFaults
    feedback_tick_ms: float  # the arm's cyclic period: one step of Feedback.frame_id
    frame_id_modulus: int  # Feedback.frame_id wraps at this value


@dataclasses.dataclass(frozen=True)
class DeploySettings:
    rate_hz: float
    duration: float  # s
    realtime: bool
    seed: int
    telemetry: str  # path; '' for none
    watchdog: WatchdogSettings
    sim: SimSettings
    kortex: KortexSection
    kinova_gen2: Any  # hardware.kinova_gen2.Gen2Settings (validated there)

    @property
    def period(self) -> float:
        return 1.0 / self.rate_hz


def control_periods(duration: float, period: float) -> int:
    """Ticks of a run of ``duration`` s at ``period`` s per tick."""
    return int(round(duration / period))


def _number(value: Any, key: str, *, integer: bool = False, positive: bool = False,
            nonnegative: bool = False) -> float | int:
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not math.isfinite(value):
        raise DeployConfigError(f"deploy.{key} must be a finite {'integer' if integer else 'number'}, "
                                f"got {value!r}")
    if positive and value <= 0:
        raise DeployConfigError(f"deploy.{key} must be > 0, got {value!r}")
    if nonnegative and value < 0:
        raise DeployConfigError(f"deploy.{key} must be >= 0, got {value!r}")
    return int(value) if integer else float(value)


def _section(data: Any, key: str, fields: Sequence[str]) -> dict:
    if not isinstance(data, dict):
        raise DeployConfigError(f"deploy.{key} must be a mapping, got {data!r}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise DeployConfigError(f"unknown key deploy.{key + '.' if key else ''}{unknown[0]}; "
                                f"allowed: {sorted(fields)}")
    missing = [f for f in fields if f not in data]
    if missing:
        raise DeployConfigError(f"missing key deploy.{key + '.' if key else ''}{missing[0]}")
    return data


def _optional_str(value: Any, key: str) -> str | None:
    if value is not None and not isinstance(value, str):
        raise DeployConfigError(f"deploy.{key} must be a string or null, got {value!r}")
    return value


def _kortex_link(kx: dict) -> dict:
    """The Kortex link's timeouts, watchdog and reset numbers of ``deploy.kortex``, validated."""
    def number(key: str, **kinds):
        return _number(kx[key], f"kortex.{key}", **kinds)

    link = {key: number(key, integer=True, positive=True)
            for key in ("rpc_timeout_ms", "session_rpc_timeout_ms", "reset_wait_ms",
                        "reset_poll_ms", "reset_estop_repeats", "frame_id_modulus")}
    link.update({key: number(key, positive=True)
                 for key in ("watchdog_periods", "watchdog_poll_periods", "feedback_tick_ms")})
    if link["watchdog_periods"] <= 1.0:
        raise DeployConfigError(f"deploy.kortex.watchdog_periods must be > 1 (a healthy loop sends "
                                f"one command per period), got {link['watchdog_periods']!r}")
    if link["watchdog_poll_periods"] > 0.5 * link["watchdog_periods"]:
        raise DeployConfigError("deploy.kortex.watchdog_poll_periods must be <= half of "
                                f"deploy.kortex.watchdog_periods, got {link['watchdog_poll_periods']!r}")
    if link["reset_poll_ms"] > link["reset_wait_ms"]:
        raise DeployConfigError("deploy.kortex.reset_poll_ms must be <= deploy.kortex.reset_wait_ms, "
                                f"got {link['reset_poll_ms']!r}")
    if link["frame_id_modulus"] < 2:
        raise DeployConfigError(f"deploy.kortex.frame_id_modulus must be >= 2, got "
                                f"{link['frame_id_modulus']!r}")
    return link


def deploy_settings_from_dict(data: Any) -> DeploySettings:
    """Validate a parsed ``deploy.yaml``; :class:`DeployConfigError` names the first bad key."""
    top = _section(data, "", [f.name for f in dataclasses.fields(DeploySettings)])
    wd = _section(top["watchdog"], "watchdog", [f.name for f in dataclasses.fields(WatchdogSettings)])
    sim = _section(top["sim"], "sim", [f.name for f in dataclasses.fields(SimSettings)])
    kx = _section(top["kortex"], "kortex", [f.name for f in dataclasses.fields(KortexSection)])
    if not isinstance(top["realtime"], bool):
        raise DeployConfigError(f"deploy.realtime must be true or false, got {top['realtime']!r}")
    if not isinstance(top["telemetry"], str):
        raise DeployConfigError(f"deploy.telemetry must be a path string ('' for none), "
                                f"got {top['telemetry']!r}")
    watchdog = WatchdogSettings(
        max_feedback_age=_number(wd["max_feedback_age"], "watchdog.max_feedback_age", positive=True),
        command_deadline=_number(wd["command_deadline"], "watchdog.command_deadline", positive=True),
        max_deadline_misses=_number(wd["max_deadline_misses"], "watchdog.max_deadline_misses",
                                    integer=True, nonnegative=True),
        velocity_tolerance=_number(wd["velocity_tolerance"], "watchdog.velocity_tolerance",
                                   nonnegative=True))
    if watchdog.command_deadline > 1.0:
        raise DeployConfigError("deploy.watchdog.command_deadline must be <= 1 period, got "
                                f"{watchdog.command_deadline!r}")
    kortex = KortexSection(
        address=_optional_str(kx["address"], "kortex.address"),
        port=_number(kx["port"], "kortex.port", integer=True, positive=True),
        session_inactivity_timeout_ms=_number(kx["session_inactivity_timeout_ms"],
                                              "kortex.session_inactivity_timeout_ms",
                                              integer=True, positive=True),
        connection_inactivity_timeout_ms=_number(kx["connection_inactivity_timeout_ms"],
                                                 "kortex.connection_inactivity_timeout_ms",
                                                 integer=True, positive=True),
        credentials_file=_optional_str(kx["credentials_file"], "kortex.credentials_file"),
        **_kortex_link(kx))
    from hardware.kinova_gen2 import gen2_settings_from_dict

    try:
        kinova_gen2 = gen2_settings_from_dict(top["kinova_gen2"])
    except ValueError as error:
        raise DeployConfigError(str(error)) from None
    rate_hz = _number(top["rate_hz"], "rate_hz", positive=True)
    duration = _number(top["duration"], "duration", positive=True)
    if control_periods(duration, 1.0 / rate_hz) < 1:
        raise DeployConfigError(f"deploy.rate_hz {rate_hz!r} Hz with deploy.duration "
                                f"{duration!r} s gives no control period: the loop would not run")
    if 1e3 / rate_hz > kortex.connection_inactivity_timeout_ms:
        raise DeployConfigError(f"deploy.rate_hz {rate_hz!r} Hz: a control period of "
                                f"{1 / rate_hz:g} s is longer than deploy.kortex.connection_inactivity_timeout_ms "
                                f"({kortex.connection_inactivity_timeout_ms} ms), after which the "
                                "arm stops itself between two commands")
    return DeploySettings(
        rate_hz=rate_hz,
        duration=duration,
        realtime=top["realtime"],
        seed=_number(top["seed"], "seed", integer=True, nonnegative=True),
        telemetry=top["telemetry"],
        watchdog=watchdog,
        sim=SimSettings(command_delay=_number(sim["command_delay"], "sim.command_delay",
                                              nonnegative=True)),
        kortex=kortex,
        kinova_gen2=kinova_gen2)


def load_deploy_settings(path: Path | str = DEPLOY_CONFIG, **overrides: Any) -> DeploySettings:
    """Read and validate ``path``; ``overrides`` replace top-level keys (None values are ignored)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise DeployConfigError(f"cannot read {path}: {error.strerror}") from None
    except yaml.YAMLError as error:
        raise DeployConfigError(f"{path} is not valid YAML: {error}") from None
    if isinstance(data, dict):
        data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return deploy_settings_from_dict(data)
    except DeployConfigError as error:
        given = [f"{k}={v!r}" for k, v in overrides.items()
                 if v is not None and f"deploy.{k} " in f"{error} "]
        where = f"{path} with {', '.join(given)} (command line)" if given else str(path)
        raise DeployConfigError(f"{where}: {error}") from None
