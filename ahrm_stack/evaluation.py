"""Evaluation of a frozen policy or the scripted controller on seeded episodes (spec §7).

:func:`evaluate` runs a run's deterministic policy (the distribution's mode), another policy file
of the run, or the mink scripted controller on ``split``'s seeds of one layout, through the safety
filter, on the nominal task (a family's cube mass and friction factors when it sets them), and
writes ``evaluation.csv`` (one row per episode) and ``evaluation.json`` (the Table II metrics, the
split, seeds, lanes and the layout's training support), optionally with a video of chosen episodes.
:func:`evaluate_suite` does so for every family of the evaluation suite (``configs/layouts.yaml``,
``suite: true``), with the scripted controller on the same episodes, and writes ``suite.md`` /
``suite.json``. The command line is ``python -m ahrm_stack.evaluate`` (:mod:`ahrm_stack.evaluate`).

This module is :data:`ahrm_stack.seeds.FINAL_EVALUATION`, the one that may read the sealed test split
(through :func:`ahrm_stack.seeds.evaluation_range`, refused while a training runs in the process).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from ahrm_stack.config import (Config, ConfigError, VideoConfig, apply_overrides, config_from_dict, config_source,
                               load_extra, load_raw)
from ahrm_stack.lane_agreement import LaneOutcome, LaneTable, taken_lane
from ahrm_stack.run_config import load_run_config
from ahrm_stack.seeds import RUN, SPLITS, Split, evaluation_range

if TYPE_CHECKING:
    from ahrm_stack.env.layout_catalog import NamedLayout


def _lane_outcome(task, physics, planned: int, start_xy, touched: bool) -> LaneOutcome:
    """The episode's :class:`~ahrm_stack.lane_agreement.LaneOutcome`: ``planned`` (the lane index
    planned at its start), the cube's start (m, world) and its position in ``physics`` now (the end)."""
    directions = task.config.layout.lane_directions
    return LaneOutcome(directions[planned], taken_lane(start_xy, task.cube_xy(physics), task.config.cube.size / 2),
                       touched)


def scripted_summaries(config: Config, episodes: int, seed_offset: int, camera_for: Callable | None = None,
                       filmed: Sequence[int] = ()):
    """Episodes ``seed_offset + i`` of the scripted controller through the safety filter, on
    ``config.task`` as it is (:func:`evaluate` passes the evaluation's task); with
    ``camera_for(physics)``, the episodes in ``filmed`` are rendered. Returns (summaries, each
    episode's :class:`~ahrm_stack.lane_agreement.LaneOutcome`, the camera or None)."""
    from ahrm_stack.env.episode import EpisodeRecorder
    from ahrm_stack.env.episode_loop import scripted_episode
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask

    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=seed_offset, safety=config.safety)
    controller = ScriptedPusher(task, config.scripted)
    camera = camera_for(runner.physics) if camera_for and filmed else None
    summaries, lanes = [], []
    for i in range(episodes):
        film = camera if i in filmed else None
        for step in scripted_episode(runner, controller, seed_offset + i):
            if step.sent is None:  # the reset (the controller's reset reads the physics only)
                planned, start_xy = task.plan_lane(runner.physics), task.cube_xy(runner.physics)
                recorder = EpisodeRecorder(step.info)
                if film:
                    film.start_episode()
            else:
                result = runner.last_filter_result
                recorder.step(step.info, float(step.info.g.sum()),
                              intervened=result is not None and result.modified)
            if film:
                film.capture(final=step.done)
        summaries.append(recorder.summary(joint_limit_violations=runner.limit_violations))
        lanes.append(_lane_outcome(task, runner.physics, planned, start_xy, summaries[-1].touched))
    return summaries, lanes, camera


def policy_summaries(config: Config, run_dir: Path, episodes: int, seed_offset: int,
                     camera_for: Callable | None = None, filmed: Sequence[int] = (),
                     policy_file: Path | None = None):
    """Episodes ``seed_offset + i`` of the run's deterministic policy (``policy_file``, default
    ``policy.pt``) on ``config.task`` as it is (:func:`evaluate` passes the evaluation's task);
    the ``filmed`` ones rendered. Returns (summaries, each episode's
    :class:`~ahrm_stack.lane_agreement.LaneOutcome`, the camera or None)."""
    from ahrm_stack.env.torchrl_env import PushOffEnv
    from ahrm_stack.learning.rollouts import load_policy, run_episodes

    _, policy = load_policy(run_dir, policy_file)
    env = PushOffEnv(config.task, config.safety, seed=seed_offset)
    camera = camera_for(env.runner.physics) if camera_for and filmed else None

    start: dict[str, object] = {}  # the episode's plan and cube position, at its first action

    def planned_policy(tensordict):
        if not start:  # the first state after the reset: where the planner plans (reading only)
            start.update(planned=env.task.plan_lane(env.runner.physics), xy=env.task.cube_xy(env.runner.physics))
        return policy(tensordict)

    def filmed_policy(tensordict):
        camera.capture()  # the state the action is chosen in; rendering reads it only
        return planned_policy(tensordict)

    summaries, lanes = [], []
    for i in range(episodes):
        start.clear()
        if camera and i in filmed:
            camera.start_episode()
            summaries += run_episodes(env, filmed_policy, 1, seed_offset=seed_offset + i)
            camera.capture(final=True)
        else:
            summaries += run_episodes(env, planned_policy, 1, seed_offset=seed_offset + i)
        lanes.append(_lane_outcome(env.task, env.runner.physics, start["planned"], start["xy"],
                                   summaries[-1].touched))
    return summaries, lanes, camera


def evaluation_configs(run_dir: Path | None, overrides: Sequence[str] = (), layout: str | None = None,
                       needs_policy: bool = False) -> tuple[Config, NamedLayout | None, Config]:
    """The config an evaluation starts from (the run's ``config.yaml`` read by
    :func:`~ahrm_stack.run_config.load_run_config`, or ``configs/`` for the scripted controller,
    with ``overrides``, then the named ``layout`` applied), the layout's entry (None without one)
    and the config training used (the run's as written, or ``configs/`` with ``overrides``: what
    a run would train with). Raises :class:`ConfigError` when ``run_dir`` is not a finished run
    (``needs_policy``: with ``policy.pt``) or a key, override or layout is bad."""
    from ahrm_stack.env.layout_catalog import apply_layout, run_config_in_layout

    if run_dir is None:
        raw = load_raw()
        apply_overrides(raw, overrides)
        source = config_source(overrides=overrides)
        trained = config_from_dict(copy.deepcopy(raw), source=source)
        entry = apply_layout(raw, layout) if layout is not None else None
        return config_from_dict(raw, source=source), entry, trained
    for name in ["config.yaml"] + (["policy.pt"] if needs_policy else []):
        if not (Path(run_dir) / name).is_file():
            raise ConfigError(f"{Path(run_dir) / name} not found: RUN_DIR must be a finished training run")
    trained = load_run_config(run_dir)
    if layout is None:
        return load_run_config(run_dir, overrides), None, trained
    config, entry = run_config_in_layout(run_dir, layout, overrides)
    return config, entry, trained


def _write_outputs(out: Path, summaries, lanes: Sequence[LaneOutcome], table, header: dict) -> None:
    from ahrm_stack.learning.rollouts import write_episodes_csv

    out.mkdir(parents=True, exist_ok=True)
    write_episodes_csv(out / "evaluation.csv", summaries, [lane.row() for lane in lanes])
    (out / "evaluation.json").write_text(json.dumps(
        {**header, **dataclasses.asdict(table), "success_rate": table.success_rate,
         "lanes": LaneTable.from_outcomes(lanes).as_dict()}, indent=2))


def _test_read_key(config: Config, run_dir: Path | None, scripted: bool, policy_file: Path | None,
                   evaluation_set: str, reason: str) -> str:
    """The ledger's key of this test-split read, after checking that the policy has not read
    ``evaluation_set``'s test split before (or that a ``reason`` is given): refused before any
    episode runs."""
    from ahrm_stack import test_ledger
    from ahrm_stack.run_config import run_config_text

    if run_dir is None or scripted:
        key = test_ledger.policy_key(None, run_config_text(config))
    else:
        key = test_ledger.policy_key(Path(policy_file) if policy_file else Path(run_dir) / "policy.pt")
    test_ledger.check_read(key, evaluation_set, reason, scripted=run_dir is None or scripted)
    return key


def evaluate(run_dir: Path | None, episodes: int, layout: str | None = None, out: Path | None = None,
             video_path: Path | None = None, video_episodes: Sequence[int] = (0,),
             video_overrides: Sequence[str] = (), quiet: bool = False,
             overrides: Sequence[str] = (), scripted: bool = False,
             policy_file: Path | None = None, split: Split = "validation", reason: str = "") -> dict:
    """Evaluate a run (``run_dir``) or the scripted controller (``None``) on ``split``'s seeds of
    ``layout`` (default: the run's own layouts) and write the outputs.

    ``overrides`` (``key=value``) change the run's (or the default) config before the layout is
    applied. ``scripted=True`` with a ``run_dir`` evaluates the scripted controller on the run's
    own config (the same episodes the run's policy gets); ``policy_file`` evaluates another policy
    file of the run (e.g. ``policies/episode-00000.pt``, the clone before any PPO update). ``split``:
    ``validation`` or the sealed ``test`` (refused while a training runs, see
    :func:`ahrm_stack.seeds.evaluation_range`; every read is appended to the test ledger, and a
    policy's second read of one evaluation set needs a ``reason``, see :mod:`ahrm_stack.test_ledger`).
    Returns the contents of ``evaluation.json``, which
    names the split, the seeds and the layout's training support (the run's config, or for the
    scripted controller the default config with ``overrides``, against the evaluation's; see
    :mod:`ahrm_stack.env.support`). Raises :class:`ConfigError` on bad input (a missing run, an
    unknown layout or split, a bad video setting), before anything is written, and ``RenderError``
    when a video is asked for and offscreen rendering is impossible.
    """
    if split not in SPLITS:
        raise ConfigError(f"split must be one of {list(SPLITS)}, got {split!r}")
    video = load_extra(VideoConfig, "video", video_overrides) if video_path else None
    if video is not None:
        from ahrm_stack.env.video import select_gl_backend
        select_gl_backend(video.gl_backends)  # before mujoco is imported
    if run_dir is not None:
        run_dir = Path(run_dir)
    config, entry, trained = evaluation_configs(run_dir, overrides, layout,
                                                needs_policy=not (scripted or policy_file))
    if policy_file is not None and not Path(policy_file).is_file():
        raise ConfigError(f"--policy-file {policy_file} not found")
    from ahrm_stack.env.layout_catalog import evaluation_task
    from ahrm_stack.env.support import as_dict, training_support

    config = dataclasses.replace(config, task=evaluation_task(config.task, entry))
    support = as_dict(training_support(trained.task, config.task))
    seed_offset = evaluation_range(layout or RUN, split).start  # the test split: sealed but here
    read_key = (_test_read_key(config, run_dir, scripted, policy_file, layout or RUN, reason)
                if split == "test" else None)  # recorded in the test ledger once the read is done

    from ahrm_stack.learning.rollouts import EvaluationTable

    camera_for = None
    if video is not None:
        from ahrm_stack.env.video import EpisodeFilm
        camera_for = functools.partial(EpisodeFilm, video=video)
    filmed = tuple(video_episodes) if video is not None else ()
    started = time.perf_counter()
    if run_dir is not None and not scripted:
        summaries, lanes, camera = policy_summaries(config, run_dir, episodes, seed_offset, camera_for, filmed,
                                                    policy_file)
        out = Path(out) if out else run_dir / ("test" if split == "test" else "")
        name = str(policy_file or run_dir)
    else:
        summaries, lanes, camera = scripted_summaries(config, episodes, seed_offset, camera_for, filmed)
        default = "scripted-eval-test" if split == "test" else "scripted-eval"
        out = Path(out) if out else Path(config.train.runs_dir) / default
        name = "scripted controller"
    seconds = time.perf_counter() - started
    table = EvaluationTable.from_summaries(summaries)
    header = {"policy": name, "layout": layout or config.task.layout.mode,
              "layout_mode": config.task.layout.mode, "evaluation_set": layout or RUN, "split": split,
              "seed_offset": seed_offset,
              "training_support": support, "wall_seconds": seconds}
    if camera is not None:
        from ahrm_stack.env.video import write_mp4
        fps = 1.0 / (config.task.episode.control_period * video.frame_every)
        write_mp4(video_path, camera.frames, fps, video.quality)
        camera.renderer.close()
        header["video"] = {"path": str(video_path), "episodes": list(filmed), "frames": len(camera.frames),
                           "fps": fps, "width": video.width, "height": video.height,
                           "render_seconds": camera.render_seconds}
    _write_outputs(out, summaries, lanes, table, header)
    result = json.loads((out / "evaluation.json").read_text())
    if read_key is not None:
        from ahrm_stack import test_ledger
        test_ledger.record(test_ledger.new_read(
            read_key, name, layout or RUN, seed_offset, episodes, reason,
            {k: (None if isinstance(result[k], float) and result[k] != result[k] else result[k])  # NaN: None
             for k in ("successes", "touched_episodes", "episodes", "time_mean") if k in result}))
    if not quiet:
        print(f"{name} ({header['layout']} layout, {split} split, seeds {seed_offset}+; training support: "
              f"{support['verdict']}): {table}")
        print(f"lanes (the cube's against the scripted controller's plan): {LaneTable.from_outcomes(lanes)}")
        print(f"written: {out / 'evaluation.csv'}, {out / 'evaluation.json'}")
        if camera is not None:
            v = header["video"]
            print(f"video: {video_path} ({v['frames']} frames, {v['width']}x{v['height']}, "
                  f"{v['fps']:.0f} fps; rendering {1000 * camera.render_seconds / max(1, v['frames']):.0f} ms/frame)")
    return result


SUITE_COLUMNS = ("successes", "touched_episodes", "time_mean", "time_std")


def _cell(result: dict | None) -> list[str]:
    if result is None:
        return ["", "", ""]
    time = "–" if result["successes"] == 0 else f"{result['time_mean']:.2f} ± {result['time_std']:.2f}"
    return [f"{result['successes']}/{result['episodes']}", str(result["touched_episodes"]), time]


def _support_cell(result: dict | None) -> str:
    """A family's training support in one cell (``–`` for results written before it was computed)."""
    return (result or {}).get("training_support", {}).get("verdict", "–")


def suite_markdown(suite: dict) -> str:
    """The suite's table: per family whether it lies inside the training support (computed, see
    :mod:`ahrm_stack.env.support`), the policy's and the scripted controller's success, touching
    episodes and time to success (mean ± std over successes, s), and their time ratio."""
    scripted_only = suite["policy"] == "scripted controller"
    with_scripted = scripted_only or bool(suite.get("scripted"))
    head = ["family", "training support"]
    if not scripted_only:
        head += ["policy successes", "touching", "time (s)"]
    if with_scripted:
        head += ["scripted successes", "touching", "time (s)"]
    if not scripted_only and suite.get("scripted"):
        head += ["time / scripted"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for family in suite["families"]:
        mine = suite["results"].get(family)
        theirs = (suite.get("scripted") or {}).get(family)
        row = [family, _support_cell(mine)]
        if not scripted_only:
            row += _cell(mine)
        if with_scripted:
            row += _cell(theirs if not scripted_only else mine)
        if not scripted_only and suite.get("scripted"):
            ok = mine and theirs and mine["successes"] and theirs["successes"]
            row.append(f"{mine['time_mean'] / theirs['time_mean']:.2f}" if ok else "–")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def evaluate_suite(run_dir: Path | None, episodes: int, out: Path | None = None,
                   overrides: Sequence[str] = (), with_scripted: bool = True,
                   policy_file: Path | None = None, families: Sequence[str] | None = None,
                   quiet: bool = False, robustness: bool = False, split: Split = "validation",
                   reason: str = "") -> dict:
    """Evaluate a run (or the scripted controller) on every family of the evaluation suite
    (``configs/layouts.yaml`` entries with ``suite: true``), each on its own seed range of
    ``split``, and for a run the scripted controller on the same episodes (the run's config).
    Writes ``suite.json`` and ``suite.md`` (the table, naming the split, with each family's
    training support) and each family's ``evaluation.csv`` under ``OUT/<family>/``
    (``OUT/<family>/scripted/`` for the controller's row). Every family and its seeds are checked
    before the first episode (a :class:`ConfigError` names the bad one; nothing is written)."""
    from ahrm_stack.env.layout_catalog import suite_names

    if split not in SPLITS:
        raise ConfigError(f"split must be one of {list(SPLITS)}, got {split!r}")
    if robustness and split == "test":
        raise ConfigError("--robustness runs on its own seeds (configs/seeds.yaml 'robustness'), which have "
                          "no test split: evaluate the test split without it")
    names = list(families) if families else suite_names()
    evaluated = Path(run_dir) if run_dir is not None else None
    evaluation_configs(evaluated, overrides, needs_policy=policy_file is None)  # a finished run, good overrides
    if policy_file is not None and not Path(policy_file).is_file():
        raise ConfigError(f"--policy-file {policy_file} not found")
    for family in names:  # every family applies and has seeds in the split, before anything runs
        family_config, _, _ = evaluation_configs(evaluated, overrides, family)
        evaluation_range(family, split)
        if split == "test" and evaluated is not None:  # and the policy has not read its test seeds
            _test_read_key(family_config, evaluated, False, policy_file, family, reason)
    suffix = "-test" if split == "test" else ""
    if run_dir is not None:
        run_dir = Path(run_dir)
        default_out = run_dir / (("suite" if policy_file is None else f"suite-{Path(policy_file).stem}") + suffix)
    else:
        default_out = Path(load_raw()["train"]["runs_dir"]) / f"scripted-suite{suffix}"
    out = Path(out) if out else default_out
    suite = {"policy": str(policy_file or run_dir) if run_dir else "scripted controller",
             "episodes": episodes, "split": split, "families": names, "results": {},
             "scripted": {} if run_dir and with_scripted else None}
    for family in names:
        suite["results"][family] = evaluate(run_dir, episodes, family, out / family, quiet=True,
                                            overrides=overrides, policy_file=policy_file, split=split,
                                            reason=reason)
        if run_dir is not None and with_scripted:
            suite["scripted"][family] = evaluate(run_dir, episodes, family, out / family / "scripted",
                                                 quiet=True, overrides=overrides, scripted=True, split=split)
        if not quiet:
            print(f"{family}: " + " | ".join(_cell(suite["results"][family])), flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "suite.json").write_text(json.dumps(suite, indent=2))
    table = suite_markdown(suite)
    if robustness and run_dir is not None:  # the same policy through the deploy loop, imperfect
        from ahrm_stack import robustness as robust

        data = robust.evaluate(run_dir, episodes, "jaco2", True, 2, 30.0, out / "robustness")
        suite["robustness"] = str(out / "robustness" / "robustness.json")
        (out / "suite.json").write_text(json.dumps(suite, indent=2))
        table += "\n" + robust.table(data)
    (out / "suite.md").write_text(f"Evaluation suite of {suite['policy']}, {episodes} episodes per family, "
                                  f"{split} split (deterministic policy; scripted controller on the same "
                                  "episodes; training support: the family's config against the training "
                                  "config, the run's or, for the scripted controller alone, configs/ with "
                                  "the overrides; ahrm_stack/env/support.py)\n\n" + table)
    if not quiet:
        print(table)
        print(f"written: {out / 'suite.md'}, {out / 'suite.json'}")
    return suite
