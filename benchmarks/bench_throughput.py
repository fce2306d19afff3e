"""Training throughput, interim evaluations included: today's setup against the faster ones.

Issue 55's benchmark. Trains for a fixed number of frames with ``python -m ahrm_stack.train`` (each
run a child process, its run folder in a temporary directory) in three setups:

* ``today``: the reference physics (``configs/``: 2 ms, 25 substeps, 5 noslip passes, Euler: every
  run so far) with the interim evaluations in the training's process (``train.eval_beside=false``,
  as every run before 2026-12-06 had them; their episode loop is the lean one either way);
* ``beside``: the same physics, the evaluations in a worker process beside training;
* ``fast``: ``profile=physics-fast`` (5 ms, 10 substeps, no noslip, implicitfast; not validated,
  ``docs/physics-fidelity.md``) with the evaluations beside.

For ``profile=scratch`` (from scratch, the experiment's recipe) in every setup, and the default
configuration (``make run``'s: cloning first, the warm start not counted) in ``today`` and
``fast``. Each run has interim evaluations of ``--eval-episodes`` episodes every ``--eval-every``
frames, as the experiment's runs have. A run's frames/s is its frames over its training loop's
wall time (``timing.json`` in the run folder: from the first interim evaluation to the end);
then two ``profile=scratch`` runs side by side (the experiment grid's way) in ``today`` and
``fast``: the sum of their frames/s. Also bare physics per control step (the scripted
controller's commands replayed on the task's model, as ``bench_physics.py`` does) under each
physics, and the ratios to ``today``. Fidelity is not measured here: ``studies/physics_fidelity.py``.

Usage: python benchmarks/bench_throughput.py [--frames N] [--eval-every N] [--eval-episodes N]
       [--no-pair] [--quick]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from ahrm_stack import cli  # noqa: E402

cli.quiet_argv()

from _scripted import QUICK_TRAINING, layout_configs, quick_parser, quiet, record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PHYSICS = {"reference": [], "fast": ["profile=physics-fast"]}  # the overrides of each physics
SETUPS = {"today": ["train.eval_beside=false"], "beside": ["train.eval_beside=true"],
          "fast": ["profile=physics-fast", "train.eval_beside=true"]}
CONFIGS = {"scratch": (["profile=scratch"], ("today", "beside", "fast")), "default": ([], ("today", "fast"))}
PAIRED = ("today", "fast")  # the setups of the two runs side by side


def train(overrides: list[str], runs_dir: Path, name: str) -> subprocess.Popen:
    """A training run in a child process (its output to ``runs_dir/NAME.log``)."""
    log = open(runs_dir / f"{name}.log", "w")
    return subprocess.Popen([sys.executable, "-m", "ahrm_stack.train", *overrides,
                             f"train.runs_dir={runs_dir / name}"],
                            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)


def finished(process: subprocess.Popen, runs_dir: Path, name: str) -> dict:
    if process.wait() != 0:
        sys.exit(f"training {name} failed:\n{(runs_dir / f'{name}.log').read_text()[-2000:]}")
    (run,) = [p for p in (runs_dir / name).iterdir() if p.is_dir()]
    return json.loads((run / "timing.json").read_text())


def bare_physics(episodes: int) -> dict[str, float]:
    """us of MuJoCo stepping per control step, the scripted episodes' commands replayed."""
    from ahrm_stack.config import load_config
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask

    out = dict.fromkeys(PHYSICS, 0.0)
    steps = 0
    for cfg in layout_configs(PHYSICS["reference"]):
        recorded = record(cfg, episodes)
        runners = {}
        for name, physics in PHYSICS.items():
            task_cfg = load_config([*physics, f"task.layout.mode={cfg.task.layout.mode}"]).task
            runners[name] = (TaskRunner(PushOffTask(task_cfg), seed=0), task_cfg.substeps)
        for episode in recorded:
            for name, (runner, substeps) in runners.items():
                runner.seed(episode.seed)
                runner.reset()
                ctrl, actuators = runner.physics.data.ctrl, runner.task._arm_actuators
                t0 = time.perf_counter()
                for command in episode.commands:
                    ctrl[actuators] = command
                    runner.physics.step(substeps)
                out[name] += time.perf_counter() - t0
            steps += len(episode.commands)
    return {name: seconds / steps * 1e6 for name, seconds in out.items()}


def main() -> None:
    parser = quick_parser(__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40960, help="training frames per run (default 40960)")
    parser.add_argument("--eval-every", type=int, default=20480, help="frames between interim evaluations")
    parser.add_argument("--eval-episodes", type=int, default=10, help="episodes per interim evaluation")
    parser.add_argument("--no-pair", action="store_true", help="skip the two runs side by side")
    args = parser.parse_args()
    extra: list[str] = []
    if args.quick:
        args.frames, args.eval_every, args.eval_episodes = 128, 64, 1
        extra = [*QUICK_TRAINING, "task.episode.duration=6"]
        args.no_pair = True  # and only the from-scratch runs, today and fast: it checks the benchmark works
    quiet()
    common = [f"train.frames={args.frames}", f"train.eval_every_frames={args.eval_every}",
              f"train.eval_episodes={args.eval_episodes}", "train.eval_every=0", "train.checkpoint_every=1000",
              *extra]
    rates: dict[tuple[str, str], float] = {}
    with tempfile.TemporaryDirectory(prefix="bench-throughput-") as tmp:
        runs_dir = Path(tmp)
        for config, (overrides, setups) in CONFIGS.items():
            if args.quick and config != "scratch":
                continue
            for setup in setups if not args.quick else PAIRED:  # one run at a time: the machine to itself
                name = f"{config}-{setup}"
                timing = finished(train([*overrides, *SETUPS[setup], *common], runs_dir, name), runs_dir, name)
                rates[(config, setup)] = timing["frames_per_second"]
                print(f"{name:15s}: {timing['frames_per_second']:7.1f} frames/s ({timing['frames']} frames in "
                      f"{timing['loop_seconds']:.1f} s; batches {timing['batch_seconds']:.1f} s; "
                      f"{timing['evaluations']} evaluations {timing['evaluation_seconds']:.1f} s, "
                      f"{timing['evaluation_steps']} steps, the loop waited {timing['evaluation_wait_seconds']:.1f} s "
                      f"= {100 * timing['evaluation_share']:.0f} %)", flush=True)
        pairs = {}
        if not args.no_pair:
            for setup in PAIRED:
                names = [f"pair-{setup}-{i}" for i in range(2)]
                processes = [train([*CONFIGS["scratch"][0], *SETUPS[setup], *common, f"train.seed={i}"], runs_dir, n)
                             for i, n in enumerate(names)]
                timings = [finished(p, runs_dir, n) for p, n in zip(processes, names)]
                pairs[setup] = sum(t["frames_per_second"] for t in timings)
                print(f"two scratch runs side by side, {setup}: {pairs[setup]:7.1f} frames/s in all "
                      f"({', '.join(str(round(t['frames_per_second'])) for t in timings) } each)", flush=True)
    bare = bare_physics(1 if args.quick else 2)
    print(f"bare physics per control step: reference {bare['reference']:.0f} us, fast {bare['fast']:.0f} us")
    print("ratios to today:")
    for (config, setup), rate in rates.items():
        if setup != "today":
            print(f"  {config}, {setup}: training frames/s (interim evaluations included) "
                  f"x{rate / rates[(config, 'today')]:.2f}")
    if pairs:
        print(f"  two scratch runs side by side, fast: x{pairs['fast'] / pairs['today']:.2f}")
    print(f"  bare physics per control step, fast: x{bare['reference'] / bare['fast']:.2f}")
    print(f"ratio fast/reference frames/s, scratch: {rates[('scratch', 'fast')] / rates[('scratch', 'today')]:.2f}")


if __name__ == "__main__":
    main()
