"""The experiment's grid: one (method, seed) training run per Ray task, then its frozen policy's
evaluation, plus the scripted controller's row; resumable (a finished run is skipped, a stopped one
resumes from its checkpoint, a failed one is reported and the others go on). The command line is
``python -m ahrm_stack.experiment`` (:mod:`ahrm_stack.experiment`), which documents the folders.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time
import traceback
from pathlib import Path
from typing import Sequence

from ahrm_stack.atomic import write_atomically
from ahrm_stack.learning.run_folder import has_checkpoint, trained
from ahrm_stack.cli import library_log_level
from ahrm_stack.config import ConfigError, ExperimentConfig, VideoConfig, load_config, load_extra, load_raw

DONE, FAILED, GRID = "done.json", "failed.json", "grid.json"
RESULT_KEYS = ("overrides", "eval_episodes", "episodes", "layout", "split")  # a run's spec keys that change its result
LEGACY_SPEC = {"split": "validation"}  # a done.json written before the key: what it was


def _split_overrides(overrides: Sequence[str]) -> tuple[list[str], list[str], list[str]]:
    train, experiment, video = [], [], []
    for item in overrides:
        if item.startswith("experiment."):
            experiment.append(item[len("experiment."):])
        elif item.startswith("video."):
            video.append(item[len("video."):])
        else:
            train.append(item)
    return train, experiment, video


def build_grid(args: argparse.Namespace) -> dict:
    """The grid's plan (written to ``OUT/grid.json``): validated settings and one spec per run."""
    train_overrides, experiment_overrides, video_overrides = _split_overrides(args.config)
    if args.episodes is not None and args.frames is None:
        args.frames = 0  # an episode budget asked for on the command line: frames do not decide
    for flag, key in (("methods", "methods"), ("seeds", "seeds"), ("episodes", "episodes"),
                      ("frames", "frames")):
        value = getattr(args, flag)
        if value is not None:
            experiment_overrides.append(f"{key}={json.dumps(value)}")
    experiment = load_extra(ExperimentConfig, "experiment", experiment_overrides)
    load_extra(VideoConfig, "video", video_overrides)  # fail now, not in every task
    train = load_config(train_overrides).train  # fail now, not in every task
    # the experiment evaluates every run itself (run_one): a run's own final evaluation is skipped,
    # unless the training asks for interim (validation) evaluations, the runs' learning curves,
    # which train.eval_episodes sizes
    interim = bool(train.eval_every or train.eval_every_frames)
    from ahrm_stack.env.layout_catalog import apply_layout
    apply_layout(load_raw(), experiment.eval_layout)
    out = Path(args.out).resolve()
    with_video = not args.no_video and experiment.video_episode >= 0
    runs = []
    for method in experiment.methods:
        for seed in range(experiment.seeds):
            name = f"{method}-seed{seed}"
            runs.append({
                "name": name, "method": method, "seed": seed, "run_dir": str(out / "runs" / name),
                "overrides": train_overrides + [f"mechanism.method={method}", f"train.seed={seed}",
                                                f"train.episodes={experiment.episodes}",
                                                f"train.frames={experiment.frames}",
                                                *([] if interim else ["train.eval_episodes=0"])],
                "eval_episodes": experiment.eval_episodes, "layout": experiment.eval_layout,
                "split": experiment.split, "suite": experiment.suite,
                "suite_clone": experiment.suite and method == experiment.methods[0],
                "video": str(out / "videos" / f"{method}.mp4") if with_video and seed == 0 else None,
                "video_episode": experiment.video_episode, "video_overrides": video_overrides})
    return {"out": str(out), "methods": list(experiment.methods), "seeds": experiment.seeds,
            "episodes": experiment.episodes, "frames": experiment.frames,
            "eval_episodes": experiment.eval_episodes,
            "layout": experiment.eval_layout, "split": experiment.split, "train_overrides": train_overrides,
            "experiment_overrides": experiment_overrides, "video_overrides": video_overrides,
            "runs": runs,
            "scripted": {"name": "scripted", "run_dir": str(out / "scripted"),
                         "episodes": experiment.scripted_episodes, "layout": experiment.eval_layout,
                         "split": experiment.split, "overrides": train_overrides, "suite": experiment.suite,
                         "suite_episodes": experiment.eval_episodes,
                         "video": str(out / "videos" / "scripted.mp4") if with_video else None,
                         "video_episode": experiment.video_episode, "video_overrides": video_overrides}}


@contextlib.contextmanager
def _logged(run_dir: Path):
    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir / "log.txt", "a") as log, contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        yield


def write_json(path: Path, data: dict) -> None:
    write_atomically(path, json.dumps(data, indent=2))


def run_one(spec: dict) -> dict:
    """Train (or resume) and evaluate one (method, seed) run; never raises.

    Returns ``{"name", "status": "done" | "skipped" | "failed", ...}``; ``done.json`` /
    ``failed.json`` in the run folder hold the same.
    """
    run_dir = Path(spec["run_dir"])
    if (run_dir / DONE).is_file():
        return {**json.loads((run_dir / DONE).read_text()), "status": "skipped"}
    started = time.perf_counter()
    try:
        with _logged(run_dir):
            (run_dir / FAILED).unlink(missing_ok=True)
            if not trained(run_dir):
                from ahrm_stack.learning.training import train
                config = load_config(spec["overrides"])
                train(config, run_dir, resume=has_checkpoint(run_dir), progress=False)
            from ahrm_stack.evaluation import evaluate
            split = spec.get("split", "validation")
            evaluation = evaluate(run_dir, spec["eval_episodes"], spec["layout"], run_dir / "eval",
                                  Path(spec["video"]) if spec["video"] else None,
                                  [spec["video_episode"]], spec["video_overrides"], quiet=True, split=split)
            suites = {}
            if spec.get("suite"):
                from ahrm_stack.evaluation import evaluate_suite
                from ahrm_stack.learning.run_folder import CLONE_POLICY
                suites["policy"] = evaluate_suite(run_dir, spec["eval_episodes"], run_dir / "suite",
                                                  with_scripted=False, quiet=True, split=split)["results"]
                if spec.get("suite_clone") and (run_dir / CLONE_POLICY).is_file():
                    suites["clone"] = evaluate_suite(run_dir, spec["eval_episodes"], run_dir / "suite-clone",
                                                     with_scripted=False, quiet=True, split=split,
                                                     policy_file=run_dir / CLONE_POLICY)["results"]
        result = {"name": spec["name"], "method": spec["method"], "seed": spec["seed"],
                  "status": "done", "seconds": time.perf_counter() - started, "evaluation": evaluation,
                  "suite": suites, "spec": spec}
        write_json(run_dir / DONE, result)
        return result
    except BaseException as error:  # noqa: BLE001 - SystemExit from a diverged run included
        if isinstance(error, KeyboardInterrupt):
            raise
        result = {"name": spec["name"], "method": spec["method"], "seed": spec["seed"],
                  "status": "failed", "seconds": time.perf_counter() - started,
                  "error": f"{type(error).__name__}: {error}", "traceback": traceback.format_exc()}
        write_json(run_dir / FAILED, result)
        return result


def run_scripted(spec: dict) -> dict:
    """The scripted controller's evaluation row (skipped when its ``evaluation.json`` exists)."""
    out = Path(spec["run_dir"])
    if (out / DONE).is_file():
        return {**json.loads((out / DONE).read_text()), "status": "skipped"}
    started = time.perf_counter()
    try:
        with _logged(out):
            from ahrm_stack.evaluation import evaluate
            split = spec.get("split", "validation")
            evaluation = evaluate(None, spec["episodes"], spec["layout"], out,
                                  Path(spec["video"]) if spec["video"] else None,
                                  [spec["video_episode"]], spec["video_overrides"], quiet=True,
                                  overrides=spec["overrides"], split=split)
            suite = None
            if spec.get("suite"):
                from ahrm_stack.evaluation import evaluate_suite
                suite = evaluate_suite(None, spec["suite_episodes"], out / "suite", spec["overrides"],
                                       quiet=True, split=split)["results"]
        result = {"name": "scripted", "status": "done", "seconds": time.perf_counter() - started,
                  "evaluation": evaluation, "suite": suite, "spec": spec}
        write_json(out / DONE, result)
        return result
    except BaseException as error:  # noqa: BLE001
        if isinstance(error, KeyboardInterrupt):
            raise
        result = {"name": "scripted", "status": "failed", "error": f"{type(error).__name__}: {error}",
                  "traceback": traceback.format_exc()}
        write_json(out / FAILED, result)
        return result


def _start_ray(address: str | None, experiment: ExperimentConfig):
    import ray

    env_vars = {k: os.environ[k] for k in ("MUJOCO_GL", "PYTHONPATH") if k in os.environ}
    if address:  # the nodes have their own installation: only the rendering backend travels
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 logging_level=library_log_level(),
                 runtime_env={"env_vars": {k: v for k, v in env_vars.items() if k == "MUJOCO_GL"}})
    else:
        Path(experiment.ray_temp_dir).mkdir(parents=True, exist_ok=True)
        ray.init(include_dashboard=False, log_to_driver=False, num_cpus=os.cpu_count(),
                 logging_level=library_log_level(),
                 _temp_dir=experiment.ray_temp_dir,
                 object_store_memory=experiment.ray_object_store_mb * 1024 * 1024,
                 runtime_env={"env_vars": env_vars})
    return ray


def check_finished(grid: dict) -> None:
    """A finished run is only reused for the same plan: raise :class:`ConfigError` naming the run
    when its ``done.json`` was made with settings that change its result (:data:`RESULT_KEYS`)."""
    for spec in grid["runs"] + [grid["scripted"]]:
        done = Path(spec["run_dir"]) / DONE
        if done.is_file():
            before = {**LEGACY_SPEC, **(json.loads(done.read_text()).get("spec") or {})}
            changed = [k for k in RESULT_KEYS if before.get(k) != spec.get(k)]
            if changed:
                raise ConfigError(f"{done} was made with other settings ({', '.join(changed)} differ); "
                                  "use another --out for a new grid, or delete that run folder")


def schedule(grid: dict) -> list[dict]:
    """The unfinished runs in the order they are handed to Ray: first those that have a checkpoint
    (they resume), then seed by seed, every method of a seed before the next seed (``ahrm-seed0,
    mhrm-seed0, ..., ahrm-seed1, ...``), so that a grid stopped part-way holds whole seeds of every
    method, the unit the analysis pairs on. The order changes when a run starts, never what it
    computes (each run has its own seeds)."""
    methods = list(grid["methods"])
    pending = [spec for spec in grid["runs"] if not (Path(spec["run_dir"]) / DONE).is_file()]
    return sorted(pending, key=lambda spec: (not has_checkpoint(Path(spec["run_dir"])), spec["seed"],
                                             methods.index(spec["method"])))


def run_grid(grid: dict, experiment: ExperimentConfig, address: str | None) -> list[dict]:
    """Run every unfinished run of the grid on Ray; returns one result per run (and the scripted
    row last when it has episodes). A task that dies (worker crash) is reported as failed."""
    check_finished(grid)
    pending = schedule(grid)
    results = [run_one(spec) for spec in grid["runs"] if spec not in pending]
    scripted = grid["scripted"]
    do_scripted = scripted["episodes"] > 0 and not (Path(scripted["run_dir"]) / DONE).is_file()
    for result in results:
        print(f"  {result['name']}: finished before, skipped")
    if not pending and not do_scripted:
        return results + ([run_scripted(scripted)] if scripted["episodes"] > 0 else [])
    ray = _start_ray(address, experiment)
    try:
        remote_run = ray.remote(num_cpus=experiment.cpus_per_run, max_retries=0)(run_one)
        remote_scripted = ray.remote(num_cpus=experiment.cpus_per_run, max_retries=0)(run_scripted)
        queue = [(remote_run, spec) for spec in pending] + ([(remote_scripted, scripted)] if do_scripted else [])
        # no more tasks handed to Ray than it can run at once, so that they start in the schedule's order
        slots = max(1, int(ray.cluster_resources().get("CPU", 1) // experiment.cpus_per_run))
        refs: dict = {}
        waiting: list = []
        while queue or waiting:
            while queue and len(waiting) < slots:
                task, spec = queue.pop(0)
                ref = task.remote(spec)
                refs[ref] = spec
                waiting.append(ref)
            ready, waiting = ray.wait(waiting, num_returns=1)
            spec = refs[ready[0]]
            try:
                result = ray.get(ready[0])
            except Exception as error:  # noqa: BLE001 - the task's process died
                result = {"name": spec["name"], "method": spec.get("method"), "seed": spec.get("seed"),
                          "status": "failed", "error": f"{type(error).__name__}: {error}"}
                run_dir = Path(spec["run_dir"])
                run_dir.mkdir(parents=True, exist_ok=True)
                write_json(run_dir / FAILED, result)
            detail = result.get("error", "") if result["status"] == "failed" else \
                f"success rate {result['evaluation']['success_rate']:.0%}"
            print(f"  {result['name']}: {result['status']} ({result.get('seconds', 0):.0f} s) {detail}",
                  flush=True)
            results.append(result)
    finally:
        ray.shutdown()
    if not do_scripted and scripted["episodes"] > 0:
        results.append(run_scripted(scripted))
    return results
