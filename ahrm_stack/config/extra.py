"""The configurations outside a run's ``config.yaml``, each in its own file (so run folders written
before these existed still load): evaluation videos (``configs/video.yaml``) and the four-method
experiment (``configs/experiment.yaml``), read by :func:`load_extra`."""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Sequence

from pydantic import AfterValidator

from ahrm_stack.config.fields import Frozen, Method, NonNegInt, Pair, Pos, PosInt
from ahrm_stack.config.files import CONFIG_DIR
from ahrm_stack.schema import Bool, ConfigError, Float, Int, Section, Str, count, fail, ge, legacy, load_file, within


def _even(value: int) -> int:
    if value % 2:
        fail(f" must be even (H.264), got {value}")
    return value


@Frozen
class VideoConfig(Section):
    """Offscreen evaluation videos (``configs/video.yaml``)."""

    camera: Str  # a named camera of the arena
    width: Annotated[PosInt, AfterValidator(_even)]  # px, even
    height: Annotated[PosInt, AfterValidator(_even)]  # px, even
    frame_every: PosInt  # control steps per frame
    shadows: Bool  # shadows cost most of the rendering time in software OpenGL
    quality: Annotated[Int, within(0, 10)]  # imageio-ffmpeg quality 0..10
    gl_backends: Annotated[tuple[Literal["egl", "osmesa", "glfw"], ...], count(1)]  # MUJOCO_GL values
    # tried in order when MUJOCO_GL is unset


@Frozen
class PaperRow(Section):
    """One method's row of the paper's Table II."""

    successes: NonNegInt
    episodes: PosInt
    touched: NonNegInt  # episodes touching an obstacle
    time: Pair  # mean, std time to success, s
    travel: Pair  # mean, std cube travel, m


@Frozen
class ExperimentConfig(Section):
    """The four-method grid, its budgets and its report (``configs/experiment.yaml``)."""

    methods: Annotated[tuple[Method, ...], count(1)]  # mechanism.method values, distinct
    reference: Annotated[Method, legacy("ahrm")]  # the method the report's findings are about (the paper's)
    seeds: PosInt  # training seeds 0 .. seeds-1
    episodes: PosInt  # training episodes per run (when frames is 0)
    frames: NonNegInt  # training frames per run, the same for every method (0: episodes decides)
    eval_episodes: PosInt  # deterministic evaluation episodes per run
    scripted_episodes: NonNegInt  # evaluation episodes of the scripted controller (0: no row)
    eval_layout: Str  # a name in configs/layouts.yaml
    split: Literal["validation", "test"]  # the final evaluation's seeds (configs/seeds.yaml); test is sealed
    video_episode: Annotated[Int, ge(-1)]  # evaluation episode rendered per method (-1: no videos)
    cpus_per_run: Pos  # Ray num_cpus of one run
    ray_temp_dir: Str
    ray_object_store_mb: PosInt
    success_threshold: Annotated[Float, within(0, 1, "(]")]  # fraction of successes for "episodes
    # to reach it"
    success_window: PosInt  # trailing training episodes of that fraction
    curve_window: PosInt  # trailing window of the learning curves, episodes
    suite: Bool  # also evaluate every run (and its clone, and the scripted controller) on the suite
    bootstrap_samples: PosInt  # resamples of the bootstrap intervals on differences between methods
    paper_table2: dict[Str, PaperRow]

    def check(self, key: str) -> None:
        if len(set(self.methods)) != len(self.methods):
            raise ConfigError(f"{key}.methods: {list(self.methods)} must be distinct values of "
                              f"{list(typing.get_args(Method))}")
        if self.video_episode >= self.eval_episodes:
            raise ConfigError(f"{key}.video_episode ({self.video_episode}) must be < eval_episodes "
                              f"({self.eval_episodes})")


def load_extra(cls: type, name: str, overrides: Sequence[str] = (),
               config_dir: Path | str = CONFIG_DIR) -> Any:
    """Load ``configs/<name>.yaml`` into ``cls`` (VideoConfig, ExperimentConfig) with ``key=value``
    overrides (keys relative to the file), validated; keys are named ``<name>.<key>``."""
    return load_file(cls, Path(config_dir) / f"{name}.yaml", name, overrides)
