"""Evaluate a trained policy or the scripted controller: the paper's Table II metrics (spec §7).

    python -m ahrm_stack.evaluate RUN_DIR [--episodes 40] [--layout fixed|random] [--out DIR]
    python -m ahrm_stack.evaluate --policy scripted [--episodes 40] [--layout fixed|random]

Episodes use fresh seeds (never used in training) and the deterministic policy (the distribution's
mode), or the mink scripted controller. Every command passes through the safety filter. Prints the
table and writes ``evaluation.csv`` (one row per episode) and ``evaluation.json`` (the table) to
``--out`` (default: the run folder, or ``runs/scripted-eval`` for the scripted controller).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
from pathlib import Path

import yaml

from ahrm_stack.config import ConfigError, apply_override, config_from_dict, load_raw


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m ahrm_stack.evaluate",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", nargs="?", help="a training run folder (with policy.pt)")
    parser.add_argument("--policy", choices=["scripted"], help="evaluate the scripted controller")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--layout", choices=["fixed", "random"], help="layout mode (default: the config's)")
    parser.add_argument("--out", help="folder for evaluation.csv and evaluation.json")
    args = parser.parse_args(argv)
    if (args.run_dir is None) == (args.policy is None):
        parser.error("give either RUN_DIR or --policy scripted")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    return args


def _scripted_summaries(config, episodes: int):
    from ahrm_stack.env.episode import EpisodeRecorder
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.scripted import ScriptedPusher
    from ahrm_stack.env.task import PushOffTask
    from ahrm_stack.learning.evaluation import EVAL_SEED_OFFSET

    task = PushOffTask(config.task)
    runner = TaskRunner(task, seed=EVAL_SEED_OFFSET, safety=config.safety)
    controller = ScriptedPusher(task, config.scripted)
    summaries = []
    for i in range(episodes):
        runner.seed(EVAL_SEED_OFFSET + i)
        transition = runner.reset()
        controller.reset(runner.physics)
        recorder = EpisodeRecorder(transition.info)
        terminated = truncated = False
        while not (terminated or truncated):
            info, terminated, truncated = runner.step_only(controller(runner.physics))
            result = runner.last_filter_result
            recorder.step(info, float(info.g.sum()), intervened=result is not None and result.modified)
        summaries.append(recorder.summary(joint_limit_violations=runner.limit_violations))
    return summaries


def main(argv: list[str] | None = None) -> int:
    args = _parse(sys.argv[1:] if argv is None else argv)
    layout = [f"task.layout.mode={args.layout}"] if args.layout else []
    try:
        if args.run_dir:
            run_dir = Path(args.run_dir)
            for name in ("config.yaml", "policy.pt"):
                if not (run_dir / name).is_file():
                    raise ConfigError(f"{run_dir / name} not found: RUN_DIR must be a finished training run")
            raw = yaml.safe_load((run_dir / "config.yaml").read_text())
        else:
            raw = load_raw()
        for override in layout:
            apply_override(raw, override)
        config = config_from_dict(raw)
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2

    from ahrm_stack.env.torchrl_env import PushOffEnv
    from ahrm_stack.learning.evaluation import EVAL_SEED_OFFSET, EvaluationTable, load_policy, run_episodes

    if args.run_dir:
        _, policy = load_policy(run_dir)
        env = PushOffEnv(config.task, config.safety, seed=EVAL_SEED_OFFSET)
        summaries = run_episodes(env, policy, args.episodes)
        out = Path(args.out) if args.out else run_dir
        name = str(run_dir)
    else:
        summaries = _scripted_summaries(config, args.episodes)
        out = Path(args.out) if args.out else Path(config.train.runs_dir) / "scripted-eval"
        name = "scripted controller"
    table = EvaluationTable.from_summaries(summaries)
    out.mkdir(parents=True, exist_ok=True)
    rows = [dataclasses.asdict(s) | {"failure_mode": s.failure_mode()} for s in summaries]
    for row in rows:
        row.pop("events", None)
    with open(out / "evaluation.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out / "evaluation.json").write_text(json.dumps(
        {"policy": name, "layout": config.task.layout.mode, **dataclasses.asdict(table),
         "success_rate": table.success_rate}, indent=2))
    print(f"{name} ({config.task.layout.mode} layout): {table}")
    print(f"written: {out / 'evaluation.csv'}, {out / 'evaluation.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
