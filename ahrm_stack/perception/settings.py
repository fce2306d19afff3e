"""The perception settings (``configs/perception.yaml``), validated.

Every error is one line that names the file and the key (``perception.camera.fovy_deg must be in
(0, 180), got 0``); nothing is built before the whole file has passed.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from ahrm_stack.config import CONFIG_DIR, ConfigError

PERCEPTION_CONFIG = CONFIG_DIR / "perception.yaml"
#: The families pupil-apriltags can detect (``pupil_apriltags.Detector(families=...)``).
TAG_FAMILIES = ("tag16h5", "tag25h9", "tag36h11", "tagCircle21h7", "tagCircle49h12",
                "tagCustom48h12", "tagStandard41h12", "tagStandard52h13")


class PerceptionConfigError(ConfigError):
    """A perception setting or a layout file is missing, unknown or invalid; names the key."""


@dataclasses.dataclass(frozen=True)
class CameraSettings:
    width: int  # px
    height: int  # px
    fovy_deg: float  # vertical field of view, degrees
    intrinsics: tuple[float, float, float, float] | None  # fx, fy, cx, cy (px); None: from fovy
    position: tuple[float, float, float]  # optical centre, m, world frame
    look_at: tuple[float, float, float] | None  # m, world frame
    quaternion: tuple[float, float, float, float] | None  # camera-to-world (w, x, y, z), optical


@dataclasses.dataclass(frozen=True)
class TagSettings:
    family: str
    id: int
    size: float  # m, black-square edge
    texture_cell_px: int  # sim texture pixels per tag cell


@dataclasses.dataclass(frozen=True)
class DetectorSettings:
    threads: int
    quad_decimate: float
    quad_sigma: float  # px
    refine_edges: bool
    decode_sharpening: float
    max_hamming: int
    min_decision_margin: float
    pose_iterations: int
    ambiguity_ratio: float


@dataclasses.dataclass(frozen=True)
class TrackerSettings:
    position_noise: float  # m
    acceleration_noise: float  # m/s^2/sqrt(Hz)
    initial_velocity_noise: float  # m/s
    max_hold: float  # s


@dataclasses.dataclass(frozen=True)
class SimCameraSettings:
    offscreen_samples: int


@dataclasses.dataclass(frozen=True)
class PerceptionSettings:
    camera: CameraSettings
    tag: TagSettings
    detector: DetectorSettings
    tracker: TrackerSettings
    sim: SimCameraSettings
    layout_file: str  # '' for none


def _fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _mapping(data: Any, key: str, fields: Sequence[str]) -> dict:
    where = f"perception.{key}" if key else "perception"
    if not isinstance(data, dict):
        raise PerceptionConfigError(f"{where} must be a mapping with keys {sorted(fields)}, "
                                    f"got {data!r:.80}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise PerceptionConfigError(f"unknown key {where}.{unknown[0]}; allowed: {sorted(fields)}")
    missing = [f for f in fields if f not in data]
    if missing:
        raise PerceptionConfigError(f"missing key {where}.{missing[0]}")
    return data


def _num(value: Any, key: str, *, integer: bool = False, low: float | None = None,
         high: float | None = None, open_low: bool = False, open_high: bool = False) -> Any:
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not math.isfinite(value):
        raise PerceptionConfigError(f"perception.{key} must be a finite "
                                    f"{'integer' if integer else 'number'}, got {value!r}")
    bad_low = low is not None and (value <= low if open_low else value < low)
    bad_high = high is not None and (value >= high if open_high else value > high)
    if bad_low or bad_high:
        lo = "" if low is None else f"{'(' if open_low else '['}{low}"
        hi = "" if high is None else f"{high}{')' if open_high else ']'}"
        if low is not None and high is not None:
            span = f"in {lo}, {hi}"
        elif low is not None:
            span = f"{'>' if open_low else '>='} {low}"
        else:
            span = f"{'<' if open_high else '<='} {high}"
        raise PerceptionConfigError(f"perception.{key} must be {span}, got {value!r}")
    return int(value) if integer else float(value)


def _vector(value: Any, key: str, size: int, optional: bool = False) -> tuple | None:
    if value is None and optional:
        return None
    if (not isinstance(value, list) or len(value) != size
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                   for v in value)):
        raise PerceptionConfigError(f"perception.{key} must be a list of {size} finite numbers"
                                    f"{' or null' if optional else ''}, got {value!r}")
    return tuple(float(v) for v in value)


def _bool(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise PerceptionConfigError(f"perception.{key} must be true or false, got {value!r}")
    return value


def perception_settings_from_dict(data: Any) -> PerceptionSettings:
    """Validate a parsed ``perception.yaml``; :class:`PerceptionConfigError` names the first bad
    key."""
    top = _mapping(data, "", _fields(PerceptionSettings))
    cam = _mapping(top["camera"], "camera", _fields(CameraSettings))
    tag = _mapping(top["tag"], "tag", _fields(TagSettings))
    det = _mapping(top["detector"], "detector", _fields(DetectorSettings))
    trk = _mapping(top["tracker"], "tracker", _fields(TrackerSettings))
    sim = _mapping(top["sim"], "sim", _fields(SimCameraSettings))

    width = _num(cam["width"], "camera.width", integer=True, low=16)
    height = _num(cam["height"], "camera.height", integer=True, low=16)
    intrinsics = _vector(cam["intrinsics"], "camera.intrinsics", 4, optional=True)
    if intrinsics is not None and (intrinsics[0] <= 0 or intrinsics[1] <= 0):
        raise PerceptionConfigError(f"perception.camera.intrinsics: fx and fy must be > 0, got "
                                    f"{list(intrinsics)}")
    position = _vector(cam["position"], "camera.position", 3)
    look_at = _vector(cam["look_at"], "camera.look_at", 3, optional=True)
    quaternion = _vector(cam["quaternion"], "camera.quaternion", 4, optional=True)
    if (look_at is None) == (quaternion is None):
        raise PerceptionConfigError("perception.camera: give exactly one of look_at and quaternion "
                                    f"(got look_at {cam['look_at']!r}, quaternion "
                                    f"{cam['quaternion']!r})")
    if quaternion is not None and abs(np.linalg.norm(quaternion) - 1.0) > 1e-3:
        raise PerceptionConfigError(f"perception.camera.quaternion must be a unit quaternion "
                                    f"(norm {np.linalg.norm(quaternion):.6g}), got {list(quaternion)}")
    if look_at is not None:
        axis = np.subtract(look_at, position)
        length = np.linalg.norm(axis)
        if length < 1e-6 or np.linalg.norm(np.cross(axis, [0, 0, 1])) < 1e-6 * length:
            raise PerceptionConfigError(f"perception.camera.look_at {list(look_at)} must differ from "
                                        f"camera.position {list(position)} and not lie straight above "
                                        "or below it (the image's up would be undefined)")
    camera = CameraSettings(
        width=width, height=height,
        fovy_deg=_num(cam["fovy_deg"], "camera.fovy_deg", low=0, high=180, open_low=True,
                      open_high=True),
        intrinsics=intrinsics, position=position, look_at=look_at,
        quaternion=None if quaternion is None else tuple(np.divide(quaternion, np.linalg.norm(quaternion))))

    if tag["family"] not in TAG_FAMILIES:
        raise PerceptionConfigError(f"perception.tag.family: {tag['family']!r} is not allowed; "
                                    f"choose one of {list(TAG_FAMILIES)}")
    tags = TagSettings(family=tag["family"], id=_num(tag["id"], "tag.id", integer=True, low=0),
                       size=_num(tag["size"], "tag.size", low=0, open_low=True),
                       texture_cell_px=_num(tag["texture_cell_px"], "tag.texture_cell_px",
                                            integer=True, low=1, high=256))
    detector = DetectorSettings(
        threads=_num(det["threads"], "detector.threads", integer=True, low=1),
        quad_decimate=_num(det["quad_decimate"], "detector.quad_decimate", low=1.0),
        quad_sigma=_num(det["quad_sigma"], "detector.quad_sigma", low=0.0),
        refine_edges=_bool(det["refine_edges"], "detector.refine_edges"),
        decode_sharpening=_num(det["decode_sharpening"], "detector.decode_sharpening", low=0.0),
        max_hamming=_num(det["max_hamming"], "detector.max_hamming", integer=True, low=0, high=2),
        min_decision_margin=_num(det["min_decision_margin"], "detector.min_decision_margin", low=0.0),
        pose_iterations=_num(det["pose_iterations"], "detector.pose_iterations", integer=True,
                             low=1),
        ambiguity_ratio=_num(det["ambiguity_ratio"], "detector.ambiguity_ratio", low=1.0))
    tracker = TrackerSettings(
        position_noise=_num(trk["position_noise"], "tracker.position_noise", low=0, open_low=True),
        acceleration_noise=_num(trk["acceleration_noise"], "tracker.acceleration_noise", low=0,
                                open_low=True),
        initial_velocity_noise=_num(trk["initial_velocity_noise"], "tracker.initial_velocity_noise",
                                    low=0, open_low=True),
        max_hold=_num(trk["max_hold"], "tracker.max_hold", low=0.0))
    sim_settings = SimCameraSettings(
        offscreen_samples=_num(sim["offscreen_samples"], "sim.offscreen_samples", integer=True,
                               low=0, high=16))
    if not isinstance(top["layout_file"], str):
        raise PerceptionConfigError(f"perception.layout_file must be a path string ('' for none), "
                                    f"got {top['layout_file']!r}")
    return PerceptionSettings(camera=camera, tag=tags, detector=detector, tracker=tracker,
                              sim=sim_settings, layout_file=top["layout_file"])


def load_perception_settings(path: Path | str = PERCEPTION_CONFIG) -> PerceptionSettings:
    """Read and validate ``path``; errors are one line naming the file and the key."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise PerceptionConfigError(f"cannot read {path}: {error.strerror or error}") from None
    except yaml.YAMLError as error:
        first = (str(error).splitlines() or [""])[0]
        raise PerceptionConfigError(f"{path} is not valid YAML ({first})") from None
    try:
        return perception_settings_from_dict(data)
    except PerceptionConfigError as error:
        raise PerceptionConfigError(f"{path}: {error}") from None
