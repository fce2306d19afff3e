"""Learning without demonstrations (issue 18): the study's rows, runs and report.

    python studies/scratch_study.py list
    python studies/scratch_study.py run ROW --seed 0 [--frames 1000000] [--runs-dir runs/scratch]
    python studies/scratch_study.py run ROW --seed 0 --resume      # continue an interrupted run
    python studies/scratch_study.py report RUNS [RUNS ...] --out docs/scratch-study [--scripted DIR]
                                  (RUNS: a folder of run folders, or one run folder)
    python studies/scratch_study.py branch RUN NEW_RUN [key=value ...]   # continue a copy of RUN
    python studies/scratch_study.py compare A/evaluation.csv B/evaluation.csv [...] [--out FILE]
    python -m ahrm_stack.evaluate RUNS_DIR/ROW-seedN --episodes 40 --out RUNS_DIR/ROW-seedN/final/own
    python -m ahrm_stack.evaluate --policy scripted --config profile=scratch --episodes 40 --out DIR/own

A row is a list of config overrides on top of ``configs/`` (every row starts from
``profile=scratch``: no demonstrations, no BC anchor, no scripted actions). ``run`` trains one row
and seed into ``RUNS_DIR/ROW-seedN`` with interim deterministic evaluations on the run's own
evaluation seeds (the default family's distribution, 60 s episodes, the task's random starts).
``report`` reads the run folders' CSV files (nothing typed in by hand) and writes ``table.md``
and ``curves.png``: the training success rate and the evaluations against frames. Where run
folders hold a final per-episode evaluation (``final/own/evaluation.csv``, from the evaluate
command above, or the ``evaluation.csv`` training writes at its end: the run's own evaluation
seeds, the same episodes as its interim evaluations),
``table.md`` also compares the rows' final policies with intervals: Wilson 95 % intervals of the
success and touching shares (pooled over a row's seeds), and paired bootstrap differences against
the scripted controller on the same episodes (``--scripted DIR``) and against the LS row.
``branch`` copies a run folder and continues the copy from its last checkpoint with changed
settings (e.g. ``train.touch_end=true``): two branches of one checkpoint differ only in those.
``compare`` puts evaluations of the same episodes side by side (e.g. 200 episodes of two branches).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import gzip
import csv
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from ahrm_stack.learning.run_folder import has_checkpoint

METHODS = ("ahrm", "ls", "mhrm", "fhrm")
# the first round's settings (2026-12-01), pinned: profile=scratch has since moved to the second's
# (and the observation without lane_choice, added after it; the other keys that changed since do
# not act without demonstrations or with a frame budget)
# rounds 1-4 ran before profile=scratch took round 5's lane frame: pinned to the world frame
BEFORE_ROUND5 = ["profile=scratch", "ppo.lane_frame=none"]
ROUND1 = [*BEFORE_ROUND5, "task.rewards.time_reference=previous", "task.arm.near_cube.bearing=any",
          "train.time_limit=10", "ppo.init_std=0.5", "task.observation.lane_choice=false",
          "mechanism.priority_rule=magnitude"]

ROWS: dict[str, list[str]] = {
    # round 1: 10 s training episodes, near-cube starts at any bearing widening with success
    **{f"scratch-{m}": [*ROUND1, f"mechanism.method={m}"] for m in METHODS},
    # levers, one at a time (AHRM)
    "no-curriculum-ahrm": [*ROUND1, "mechanism.method=ahrm", "train.start_curriculum=none"],
    # the reverse curriculum from the scripted controller's states (no action labels)
    # (a trajectory is ~80 steps: a level step of 0.1 moves the start ~8 steps back)
    "reverse-ahrm": [*ROUND1, "mechanism.method=ahrm", "train.start_curriculum=scripted_states",
                     "train.curriculum_step=0.1"],
    "reverse-ls": [*ROUND1, "mechanism.method=ls", "train.start_curriculum=scripted_states",
                   "train.curriculum_step=0.1"],
    "full-episodes-ahrm": [*ROUND1, "mechanism.method=ahrm", "train.time_limit=0"],
    "joint-ahrm": [*ROUND1, "mechanism.method=ahrm", "task.action.mode=joint"],
    # round 2 (2026-12-02), profile=scratch as it is now: f3's budgets from the latest success (the
    # spec's previous-episode budget made fleeing to phase 1 pay: round 1's runs ended hovering
    # there), near-cube starts behind the cube for the episode's lane, 5 s training episodes (at
    # 10 s the policies spent 3/4 of each episode in phase 1 after a push; successes took
    # 0.75-3.5 s), and a quarter of round 1's exploration noise (ppo.init_std 0.25: `probe` shows
    # a linear steering policy winning 31/40 behind starts with noise 0.25, 13/40 with 0.5)
    # (round 2 ran before profile=scratch took round 3's priority rule: pinned to the spec's)
    **{f"lownoise-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "mechanism.priority_rule=magnitude"]
       for m in METHODS},
    # the same with round 1's noise, at 5 s and at 10 s
    **{f"behind-success-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "ppo.init_std=0.5",
                               "mechanism.priority_rule=magnitude"] for m in METHODS},
    **{f"behind-success-10s-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "ppo.init_std=0.5",
                                   "train.time_limit=10", "mechanism.priority_rule=magnitude"] for m in METHODS},
    # + exponential smoothing of the requests (task.action.smoothing 0.8: exploration noise
    # correlated over ~5 steps, a third of its per-step size): measured by `probe` only so far
    **{f"smooth-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "task.action.smoothing=0.8"] for m in METHODS},
    # round 3: AHRM ranks objectives by how often they are violated (the per-step average of f_i, low
    # first) instead of the spec's |mean episode sum| (high first), which ranked time first in phases
    # 2-3 of a policy that had never succeeded (time holds in every short visit) and locked it
    # (profile=scratch holds it since)
    "violation-ahrm": [*BEFORE_ROUND5, "mechanism.method=ahrm", "mechanism.priority_rule=violation"],
    # the other methods on round 3's profile (the rule acts only in AHRM: LS, MHRM and FHRM run as
    # lownoise-* would)
    **{f"round3-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}"] for m in METHODS if m != "ahrm"},
    # round 4: a touch ends the training episode as a terminal failure (train.touch_end)
    **{f"touch-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "train.touch_end=true"] for m in METHODS},
    # ... only after the first 1M frames (touch-ahrm learned to keep away from the cube instead)
    **{f"late-touch-{m}": [*BEFORE_ROUND5, f"mechanism.method={m}", "train.touch_end=true",
                           "train.touch_end_after=1000000"] for m in METHODS},
    # round 5: the policy reads the world in its episode's lane frame (mirrored x -> -x when the lane
    # is -x, its x action mirrored back: ppo.lane_frame), so that both lanes are learned as one;
    # with the arm's joint entries as measured (they have no mirror image) or zeroed
    # (profile=scratch holds mirror_no_joints since)
    **{f"mirror-{m}": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror"] for m in METHODS},
    **{f"mirror-nj-{m}": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror_no_joints"]
       for m in METHODS},
    # round 6's ablation: a hierarchy whose priority constraint never ends an episode (a margin no
    # per-step average can fall below: the first two objectives' average is >= -2), so that after
    # its first levels it trains on LS's reward and episodes alone
    **{f"mirror-nj-{m}-free": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror_no_joints",
                               "mechanism.constraint_margin=1000"] for m in ("ahrm", "fhrm")},
    # round 7: the same with MuJoCo's body sleeping (task.episode.sleep: resting objects leave the
    # physics step, ~1.3x the training frames per second): does learning stay as it was?
    **{f"mirror-nj-{m}-sleep": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror_no_joints",
                                "task.episode.sleep=true"] for m in METHODS},
    # round 9: every seed-1 run (all four methods) touched an obstacle in 60-64 % of its first 200
    # episodes and barely moved the cube, against 25-46 % for seeds 0 and 2: the seed's initial
    # network, shared by the methods, drifts the tip (its mean action, ~0.05 of the range, adds up
    # over an episode). The actor's output layer started 100x smaller (ppo.actor_init_scale 0.01,
    # Andrychowicz et al. 2021) centres every seed's first actions on zero
    **{f"mirror-nj-{m}-init01": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror_no_joints",
                                 "ppo.actor_init_scale=0.01"] for m in METHODS},
    # round 13: f1 also prices a near miss: -1 while the cube or the pusher is within 2 cm of an
    # obstacle (task.rewards.avoid_margin; the scripted controller comes that close in 3 of 40
    # evaluation episodes, 0.5 % of its steps), on round 10's centred initial policy
    **{f"mirror-nj-{m}-init01-margin02": ["profile=scratch", f"mechanism.method={m}",
                                          "ppo.lane_frame=mirror_no_joints", "ppo.actor_init_scale=0.01",
                                          "task.rewards.avoid_margin=0.02"] for m in METHODS},
    # round 10: MuJoCo without the noslip passes dm_control's composer arena sets (5 per step, more
    # than half of the physics step here; benchmarks/bench_physics.py): does learning stay as it was?
    **{f"mirror-nj-{m}-noslip0": ["profile=scratch", f"mechanism.method={m}", "ppo.lane_frame=mirror_no_joints",
                                  "task.episode.noslip_iterations=0"] for m in METHODS},
}


def run_command(row: str, seed: int, frames: int, runs_dir: Path, eval_every: int, resume: bool,
                workers: int = 1) -> list[str]:
    """The training command of ``row``'s run with ``seed`` (``workers`` > 1: ``train.env_workers``,
    the environments in that many processes, which also defers the mechanism's updates to each
    batch's end: another sample path than ``workers`` 1, not a copy of it)."""
    run_dir = runs_dir / f"{row}-seed{seed}"
    split = [f"train.env_workers={workers}"] if workers > 1 else []  # on resume: saved to its config.yaml
    if resume:
        return [sys.executable, "-m", "ahrm_stack.train", "--resume", str(run_dir), *split, "--no-progress"]
    return [sys.executable, "-m", "ahrm_stack.train", *ROWS[row], f"train.seed={seed}",
            f"train.frames={frames}", f"train.eval_every_frames={eval_every}", *split,
            "--run-dir", str(run_dir), "--no-progress"]


def run(row: str, seed: int, frames: int, runs_dir: Path, eval_every: int, resume: bool, workers: int = 1) -> int:
    return subprocess.call(run_command(row, seed, frames, runs_dir, eval_every, resume, workers))


def branch_command(destination: Path, overrides: list[str]) -> list[str]:
    """The command continuing the copied run ``destination`` with ``overrides`` (stored in its
    config.yaml by ``ahrm_stack.train``)."""
    return [sys.executable, "-m", "ahrm_stack.train", "--resume", str(destination), *overrides, "--no-progress"]


def branch(source: Path, destination: Path, overrides: list[str]) -> int:
    """Copy the run folder ``source`` to ``destination`` and continue the copy from its last
    checkpoint with ``overrides``. The source is left as it is; two branches of one checkpoint share
    everything before it (a resumed run restarts the episodes in flight, so a branch without
    overrides is another sample of the same continuation, not a replay of the source). Checked
    before anything is copied: the source is a run folder with a checkpoint, the destination does
    not exist, and the overrides apply to the source's configuration."""
    from ahrm_stack.config import ConfigError
    from ahrm_stack.learning.training import resolve_config

    if not (source / "config.yaml").is_file() or not has_checkpoint(source):
        raise ConfigError(f"branch: {source} is not a run folder with a checkpoint")
    if destination.exists():
        raise ConfigError(f"branch: {destination} exists; give a new folder")
    resolve_config(overrides, resume=source)  # one-line errors
    shutil.copytree(source, destination)
    return subprocess.call(branch_command(destination, overrides))


def sign_test(only_a: int, only_b: int) -> float:
    """Exact two-sided sign test (McNemar's exact test) of discordant pairs: the probability, under
    equal chances, of a split at least as uneven as ``only_a`` against ``only_b``."""
    n, k = only_a + only_b, min(only_a, only_b)
    if n == 0:
        return 1.0
    return min(1.0, 2.0 * sum(math.comb(n, i) for i in range(k + 1)) / 2.0 ** n)


def _split_of(evaluation_csv: Path) -> str:
    """The split an evaluation.csv was drawn from, as its evaluation.json says; files written before
    the split existed (2026-12-04) were on the range now called validation."""
    meta = evaluation_csv.with_name("evaluation.json")
    if meta.is_file():
        return str(json.loads(meta.read_text()).get("split", "validation"))
    return "validation"


def compare(paths: list[Path], names: list[str], samples: int = 10_000) -> list[str]:
    """Evaluations of the same episodes (``evaluation.csv`` files of one seed offset, the same
    count) side by side: each one's successes and touching episodes (Wilson 95 %), and against the
    first, the paired difference of each share (bootstrap 95 % over episodes) with the discordant
    episodes (``first only / this only``) and their exact sign-test p."""
    from ahrm_stack.config import ConfigError
    from ahrm_stack.suite_report import read_episodes

    if len(names) != len(paths):
        raise ConfigError(f"compare: {len(names)} names for {len(paths)} evaluations")
    for path in paths:
        if not path.is_file():
            raise ConfigError(f"compare: {path}: no such file")
    runs = []
    for path in paths:
        try:
            runs.append(read_episodes(path))
        except (KeyError, ValueError) as error:  # not an evaluation.csv, or a damaged one
            raise ConfigError(f"compare: {path}: not an evaluation's per-episode rows ({error})") from None
    counts = {len(r["success"]) for r in runs}
    if len(counts) != 1:
        raise ConfigError(f"compare: the evaluations hold different episode counts {sorted(counts)}; "
                          "they must be the same episodes")
    n = counts.pop()
    splits = {_split_of(path) for path in paths}
    if len(splits) != 1:
        raise ConfigError(f"compare: the evaluations are on different splits {sorted(splits)}")
    rng = np.random.default_rng(0)
    draws = rng.integers(n, size=(samples, n))
    lines = [f"Seeds: the {splits.pop()} split of configs/seeds.yaml.", "",
             f"{n} episodes each, the same seeds; intervals 95 %: Wilson for shares, bootstrap over "
             "episodes for paired differences; discordant: episodes where only the first / only this "
             "one has it; p: exact sign test of those", "",
             f"| policy | successes | touching | s to success | success − {names[0]} | discordant (p) "
             f"| touching − {names[0]} | discordant (p) |", "|" + "---|" * 8]
    base = runs[0]
    for name, run in zip(names, runs):
        k, t = int(run["success"].sum()), int(run["touched"].sum())
        (s_low, s_high), (t_low, t_high) = wilson(k, n), wilson(t, n)
        finite = run["time"][np.isfinite(run["time"])]
        cells = [f"{k}/{n} [{s_low:.2f}, {s_high:.2f}]", f"{t}/{n} [{t_low:.2f}, {t_high:.2f}]",
                 f"{finite.mean():.2f} ± {finite.std():.2f}" if len(finite) else "–"]
        for column in ("success", "touched"):
            if run is base:
                cells += ["–", "–"]
                continue
            d = run[column] - base[column]
            low, high = np.percentile(d[draws].mean(axis=1), [2.5, 97.5])
            only_base, only_this = int((d < 0).sum()), int((d > 0).sum())
            cells += [f"{d.mean():+.3f} [{low:+.3f}, {high:+.3f}]",
                      f"{only_base} / {only_this} ({sign_test(only_base, only_this):.2g})"]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _rows(path: Path) -> list[dict]:
    """A CSV file's rows, read from ``path`` or, where only that exists, ``path.gz`` (the run
    folders copied into docs/ keep their large episode logs compressed)."""
    if not path.exists():
        packed = path.with_name(path.name + ".gz")
        if not packed.exists():
            return []
        with gzip.open(packed, "rt", newline="") as handle:
            return list(csv.DictReader(handle))
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _first(rows: list[dict], test) -> tuple[int, int] | None:
    """(frames, training episodes) of the first row passing ``test`` (in evaluations.csv
    ``episode`` is the training episode, ``episodes`` the evaluation's own count)."""
    for row in rows:
        if test(row):
            return int(float(row["frames"])), int(float(row["episode"] if "episode" in row else row["episodes"]))
    return None


def _rate_reached(success: np.ndarray, frames: np.ndarray, rate: float, window: int = 200) -> tuple[int, int] | None:
    """(frames, episodes) at the end of the first ``window`` consecutive training episodes of
    which a share >= ``rate`` succeeded; None if none."""
    if len(success) < window:
        return None
    rates = np.convolve(success.astype(float), np.ones(window) / window, mode="valid")
    hits = np.flatnonzero(rates >= rate - 1e-12)
    if not len(hits):
        return None
    end = int(hits[0]) + window - 1
    return int(frames[end]), end + 1


def summarize(run_dir: Path) -> dict:
    episodes = _rows(run_dir / "episodes.csv")
    batches = _rows(run_dir / "batches.csv")
    evaluations = _rows(run_dir / "evaluations.csv")
    success = np.array([row["success"] == "True" for row in episodes], dtype=bool)
    frames = np.array([int(row["frames"]) for row in episodes])
    first_train = next((i for i, s in enumerate(success) if s), None)
    count = lambda r: int(float(r["successes"]))  # noqa: E731
    n_eval = lambda r: round(count(r) / float(r["success_rate"])) if float(r["success_rate"]) else None  # noqa: E731
    episodes_per_eval = next((n_eval(r) for r in evaluations if n_eval(r)), 40)
    last = evaluations[-1] if evaluations else None
    return {
        "run": run_dir.name,
        "frames": int(batches[-1]["frames"]) if batches else 0,
        "episodes": len(episodes),
        "train_successes": int(success.sum()),
        "train_success_last_500": float(success[-500:].mean()) if len(success) else 0.0,
        "first_train_success": None if first_train is None else (int(frames[first_train]), first_train + 1),
        "train_10": _rate_reached(success, frames, 0.1),
        "train_50": _rate_reached(success, frames, 0.5),
        "first_eval_success": _first(evaluations, lambda r: count(r) >= 1),
        "eval_50": _first(evaluations, lambda r: count(r) >= 0.5 * episodes_per_eval),
        "eval_90": _first(evaluations, lambda r: count(r) >= 0.9 * episodes_per_eval),
        "best_eval": max((count(r) for r in evaluations), default=None),
        "last_eval": None if last is None else (count(last), episodes_per_eval,
                                                int(float(last["touched_episodes"])),
                                                float(last["time_mean"]) if last["time_mean"] else float("nan"),
                                                int(float(last["frames"]))),
        "curriculum_level": (float(batches[-1]["curriculum_level"])
                             if batches and batches[-1].get("curriculum_level") else None),
        "wall_minutes": sum(float(r["seconds"]) for r in batches) / 60,
        "_curve": (frames, success, evaluations, batches),
    }


def _behaviour(rows: list[dict]) -> dict:
    """What the training episodes ``rows`` (of episodes.csv) did: see :func:`behaviour_by_part`."""
    steps = np.array([ast.literal_eval(r["phase_steps"]) for r in rows], dtype=float)
    share = steps.sum(axis=0) / max(1.0, steps.sum())
    return {
        "episodes": (int(float(rows[0]["episode"])), int(float(rows[-1]["episode"]))),
        "frames": int(float(rows[-1]["frames"])),
        "successes": sum(r["success"] == "True" for r in rows),
        "displacement_mm": 1000 * float(np.mean([float(r["cube_displacement"]) for r in rows])),
        "touching": sum(int(float(r["touched_steps"])) > 0 for r in rows),
        "constraint": sum(r["constraint_terminated"] == "True" for r in rows),
        "phase_share": share.tolist(),
    }


def behaviour_by_part(run_dir: Path, parts: int = 5) -> list[dict]:
    """What the training episodes did, per consecutive part (a fifth by default) of a run's
    episodes: successes, mean cube displacement (mm), episodes touching an obstacle, episodes
    ended by the priority constraint, and the mean share of steps in each phase."""
    episodes = _rows(run_dir / "episodes.csv")
    return [_behaviour([episodes[i] for i in chunk])
            for chunk in np.array_split(np.arange(len(episodes)), parts) if len(chunk)]


STUDY_SEEDS = "Seeds: the validation split of configs/seeds.yaml (studies never read the sealed split)."
EARLY_EPISODES = 200  # the report's "first training episodes" (a few batches at 5 s episodes)


def early_behaviour(run_dir: Path, episodes: int = EARLY_EPISODES) -> dict | None:
    """:func:`_behaviour` of a run's first ``episodes`` training episodes (a few batches: the
    policy is still close to its initial network); None when the run has fewer."""
    rows = _rows(run_dir / "episodes.csv")
    return _behaviour(rows[:episodes]) if len(rows) >= episodes else None


def probe(noises: list[float], smoothings: list[float], episodes: int, speed: float, gain: float,
          overrides: list[str]) -> list[dict]:
    """How much exploration noise a good policy survives: a hand-written linear steering policy
    (tip velocity along the episode's lane at ``speed``, the lateral and vertical offsets from the
    cube centre times ``gain`` 1/m, all in normalised action units), with the noise a
    TanhNormal actor of that std adds (tanh(atanh(mean) + N(0, std))), from near-cube starts
    behind the cube (episodes of the profile's train.time_limit, its speed cap), for each noise
    and smoothing. Returns per cell: wins, episodes touching an obstacle, and the share of steps
    on which f2 (manipulate) is satisfied. Uses the task and the safety filter, no learning."""
    from ahrm_stack.config import load_config
    from ahrm_stack.env.runner import TaskRunner
    from ahrm_stack.env.task import PushOffTask

    cells = []
    for smoothing in smoothings:
        base = ["profile=scratch", "task.arm.near_cube.bearing=behind", f"task.action.smoothing={smoothing}",
                *overrides]
        # episodes as long as the profile's training episodes (train.time_limit)
        config = load_config([*base, f"task.episode.duration={load_config(base).train.time_limit}"])
        task = PushOffTask(config.task)
        task.near_cube_share = 1.0
        runner = TaskRunner(task, seed=0, safety=config.safety)
        cube_geom = task._cube.geom
        for noise in noises:
            rng = np.random.default_rng(0)
            wins = touching = 0
            satisfied = []
            for episode in range(episodes):
                runner.seed(10_000 + episode)
                runner.reset()
                lane = config.task.layout.lane_directions[int(np.argmax(task.lane_choice(runner.physics)))]
                sign = 1.0 if lane == "+x" else -1.0
                done, touched, good, steps = False, False, 0, 0
                while not done:
                    tip, cube = task.step_info.tip, runner.physics.bind(cube_geom).xpos
                    mean = np.clip([sign * speed, gain * (cube[1] - tip[1]), gain * (cube[2] - tip[2])],
                                   -0.999, 0.999)
                    action = np.tanh(np.arctanh(mean) + rng.normal(0.0, noise, 3)) if noise else mean
                    info, terminated, truncated = runner.step_action(action)
                    touched |= bool(info.touched)
                    good += int(info.f[1] > 0)
                    steps += 1
                    done = terminated or truncated
                wins += int(info.success)
                touching += int(touched)
                satisfied.append(good / steps)
            cells.append({"noise": noise, "smoothing": smoothing, "wins": wins, "episodes": episodes,
                          "touching": touching, "f2_share": float(np.mean(satisfied))})
            print(f"noise {noise} smoothing {smoothing}: {wins}/{episodes} wins, {touching} touching, "
                  f"f2 satisfied on {100 * np.mean(satisfied):.0f} % of steps", flush=True)
    return cells


def easy_eval(run_dir: Path, policy_file: Path | None, episodes: int) -> dict:
    """The run's deterministic policy at the easy end of its start curriculum: every episode
    starts near the cube as the run's ``task.arm.near_cube`` says (level 0), truncated at its
    ``train.time_limit``, on the evaluation seeds (never trained on). ``policy_file``: default
    the newest of ``policy.pt`` and ``policies/episode-*.pt``. Returns the evaluation table's
    figures and the policy file used."""
    from ahrm_stack.env.torchrl_env import PushOffEnv
    from ahrm_stack.learning.rollouts import VALIDATION_SEED_OFFSET, EvaluationTable, load_policy, run_episodes

    if policy_file is None:
        candidates = sorted(run_dir.glob("policies/episode-*.pt")) + sorted(run_dir.glob("policy.pt"))
        if not candidates:
            raise SystemExit(f"error: no policy file in {run_dir} (policy.pt or policies/episode-*.pt)")
        policy_file = candidates[-1]
    config, policy = load_policy(run_dir, policy_file)
    env = PushOffEnv(config.task, config.safety, seed=VALIDATION_SEED_OFFSET, time_limit=config.train.time_limit)
    env.task.near_cube_share = 1.0
    table = EvaluationTable.from_summaries(run_episodes(env, policy, episodes))
    print(f"{run_dir.name} {policy_file.name}: near-cube starts ({config.task.arm.near_cube.bearing}), "
          f"{config.train.time_limit or config.task.episode.duration:g} s: {table}")
    return {"policy": policy_file.name, **dataclasses.asdict(table)}


def _at(value) -> str:
    return "–" if value is None else f"{value[0]:,} ({value[1]})"


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial share k/n (95 % by default)."""
    if n <= 0:
        return float("nan"), float("nan")
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _row_name(run_name: str) -> str:
    head, _, tail = run_name.rpartition("-seed")
    return head if head and tail.isdigit() else run_name


def final_section(runs: list[Path], scripted_dir: Path | None, samples: int = 10_000) -> list[str]:
    """The final policies compared on their own evaluation episodes (``final/own/evaluation.csv``),
    per row (seeds pooled): successes and touching with Wilson 95 % intervals, seconds to success,
    and paired differences (row - scripted controller, row - LS) in success and touching shares
    with bootstrap 95 % intervals over seeds, then episodes (``suite_report.paired_difference``).
    Empty when no run has a final evaluation."""
    from ahrm_stack.suite_report import paired_difference, read_episodes, read_suite

    rows: dict[str, list] = {}
    for path in runs:
        episodes = read_suite(path / "final")
        if not (episodes and "own" in episodes) and (path / "evaluation.csv").exists():
            episodes = {"own": read_episodes(path / "evaluation.csv")}  # training's final evaluation
        if episodes and "own" in episodes:
            rows.setdefault(_row_name(path.name), []).append(episodes)
    if not rows:
        return []
    scripted = read_suite(scripted_dir) if scripted_dir else None
    if not (scripted and "own" in scripted):
        scripted = None
    rows_shown = ({"scripted controller": [scripted]} if scripted else {}) | rows
    ls_row = next((name for name in rows if name.endswith("-ls")), None)
    rng = np.random.default_rng(0)
    lines = ["", "Final policies on their own evaluation episodes (60 s, the task's starts; seeds pooled; "
             "intervals 95 %: Wilson for shares, paired bootstrap over seeds then episodes for "
             "differences):", "",
             "| row | seeds | successes | touching | s to success | success − scripted | touching − scripted "
             "| success − LS | touching − LS |", "|" + "---|" * 9]

    def diff(a, b, column):
        if b is None:
            return "–"
        point, low, high = paired_difference(a, b * len(a) if len(b) == 1 else b, ["own"], column, samples, rng)
        return f"{point:+.2f} [{low:+.2f}, {high:+.2f}]"

    for name, seeds in rows_shown.items():
        success = np.concatenate([e["own"]["success"] for e in seeds])
        touched = np.concatenate([e["own"]["touched"] for e in seeds])
        times = np.concatenate([e["own"]["time"] for e in seeds])
        n, k, t = len(success), int(success.sum()), int(touched.sum())
        s_low, s_high = wilson(k, n)
        t_low, t_high = wilson(t, n)
        finite = times[np.isfinite(times)]
        time_text = f"{finite.mean():.2f} ± {finite.std():.2f}" if len(finite) else "–"
        is_scripted = name == "scripted controller"
        scripted_ref = None if is_scripted or scripted is None else [scripted]
        ls_ref = None if is_scripted or ls_row is None or name == ls_row else rows[ls_row]
        if ls_ref is not None and len(ls_ref) not in (1, len(seeds)):
            ls_ref = None
        lines.append(f"| {name} | {len(seeds)} | {k}/{n} [{s_low:.2f}, {s_high:.2f}] | {t}/{n} "
                     f"[{t_low:.2f}, {t_high:.2f}] | {time_text} | {diff(seeds, scripted_ref, 'success')} | "
                     f"{diff(seeds, scripted_ref, 'touched')} | {diff(seeds, ls_ref, 'success')} | "
                     f"{diff(seeds, ls_ref, 'touched')} |")
    return lines


def _evaluations_by_row(runs: list[Path]) -> dict[str, list[dict[int, tuple[int, int, int]]]]:
    """Per row (run names less ``-seedN``), per seed: frames -> (successes, episodes, touching)
    of its interim evaluations."""
    per_row: dict[str, list[dict[int, tuple[int, int, int]]]] = {}
    for path in runs:
        evaluations = {}
        for row in _rows(path / "evaluations.csv") if (path / "evaluations.csv").exists() else []:
            evaluations[int(float(row["frames"]))] = (int(float(row["successes"])), int(float(row["episodes"])),
                                                      int(float(row["touched_episodes"])))
        if evaluations:
            per_row.setdefault(_row_name(path.name), []).append(evaluations)
    return per_row


def matched_frames_section(runs: list[Path]) -> list[str]:
    """The interim evaluations at matched frame budgets: per row (seeds pooled), at each frame
    count where every seed of the row has an evaluation, the successes out of the episodes with
    their Wilson 95 % interval, and the episodes touching an obstacle. Rows are the run names less
    ``-seedN``; budgets are the evaluations' own frame counts (the same for every run that shares
    ``ppo.frames_per_batch`` and ``--eval-every``). Empty when no run has interim evaluations."""
    per_row = _evaluations_by_row(runs)
    if not per_row:
        return []

    def cell(name: str, seeds: list[dict[int, tuple[int, int, int]]], frames: int) -> str:
        k, n, t = (sum(e[frames][i] for e in seeds) for i in range(3))
        low, high = wilson(k, n)
        return f"{k}/{n} [{low:.2f}, {high:.2f}] ({t})"

    return _budget_table(per_row, "Interim evaluations at matched frame budgets (seeds pooled; successes / "
                         "episodes [Wilson 95 %], episodes touching in brackets; – where a seed has no "
                         "evaluation there):", cell)


def _budget_table(per_row: dict[str, list[dict[int, tuple[int, int, int]]]], caption: str, cell) -> list[str]:
    """A table of rows by the evaluations' frame budgets (after 0 frames): ``cell(row, seeds,
    frames)`` where every seed of the row has an evaluation at ``frames``, – elsewhere."""
    budgets = sorted({f for seeds in per_row.values() for e in seeds for f in e if f > 0})
    lines = ["", caption, "", "| row | seeds | " + " | ".join(f"{f / 1e6:.1f}M" for f in budgets) + " |",
             "|" + "---|" * (len(budgets) + 2)]
    for name, seeds in per_row.items():
        cells = [cell(name, seeds, frames) if all(frames in e for e in seeds) else "–" for frames in budgets]
        lines.append(f"| {name} | {len(seeds)} | " + " | ".join(cells) + " |")
    return lines


def seed_bootstrap(shares: list[float], rng: np.random.Generator, samples: int,
                   other: list[float] | None = None) -> tuple[float, float, float]:
    """Mean of per-seed success shares (minus ``other``'s mean when given) with a percentile 95 %
    interval from resampling the seeds with replacement (each row's seeds on their own): the
    seed, not the episode, is the unit, so the spread between runs counts in full."""
    a = np.asarray(shares, dtype=float)
    means = a[rng.integers(0, len(a), (samples, len(a)))].mean(axis=1)
    point = float(a.mean())
    if other is not None:
        b = np.asarray(other, dtype=float)
        means = means - b[rng.integers(0, len(b), (samples, len(b)))].mean(axis=1)
        point -= float(b.mean())
    low, high = np.percentile(means, [2.5, 97.5])
    return point, float(low), float(high)


def seed_level_section(runs: list[Path], samples: int = 10_000, budget: int | None = None) -> list[str]:
    """The interim evaluations with the seed as the unit: per row and matched frame budget, each
    seed's successes, the mean success share over seeds with a bootstrap-over-seeds 95 % interval
    (:func:`seed_bootstrap`), and how many seeds reached half the episodes (Wilson 95 % over seeds);
    then, for the rows with two seeds or more, at ``budget`` (default: the largest budget every seed
    of those rows was evaluated at), the difference in mean success share between each pair of
    rows, resampling each row's seeds.
    With two or three seeds a row the intervals are coarse; that is what they say."""
    per_row = _evaluations_by_row(runs)
    if not per_row:
        return []
    rng = np.random.default_rng(0)
    shares: dict[str, dict[int, list[float]]] = {}

    def cell(name: str, seeds: list[dict[int, tuple[int, int, int]]], frames: int) -> str:
        values = [e[frames][0] / e[frames][1] for e in seeds]
        shares.setdefault(name, {})[frames] = values
        point, low, high = seed_bootstrap(values, rng, samples)
        half = sum(e[frames][0] >= 0.5 * e[frames][1] for e in seeds)
        w_low, w_high = wilson(half, len(seeds))
        return (", ".join(str(e[frames][0]) for e in seeds)
                + f": {point:.2f} [{low:.2f}, {high:.2f}]; {half}/{len(seeds)} [{w_low:.2f}, {w_high:.2f}]")

    lines = _budget_table(per_row, "The same evaluations with the seed as the unit (each seed's successes; the "
                          "mean share over seeds [95 %, bootstrap over seeds]; seeds with at least half the "
                          "episodes won, [Wilson 95 % over seeds]):", cell)
    # compared: the rows with two seeds or more (one seed has no spread to resample)
    several = [name for name, seeds in per_row.items() if len(seeds) >= 2]
    budgets = sorted({f for name in several for f in shares.get(name, {})})
    common = [f for f in budgets if all(f in shares.get(name, {}) for name in several)]
    if budget is None and common:
        budget = common[-1]
    names = [name for name in several if budget in shares.get(name, {})]
    if budget is None or len(names) < 2:
        return lines
    lines += ["", f"Differences in mean success share at {budget:,} frames (row − column; 95 %, bootstrap "
              "over each row's seeds):", "", "| row | " + " | ".join(names[1:]) + " |",
              "|" + "---|" * len(names)]
    for i, name in enumerate(names[:-1]):
        cells = ["" if j <= i else "{:+.2f} [{:+.2f}, {:+.2f}]".format(
            *seed_bootstrap(shares[name][budget], rng, samples, shares[other][budget]))
            for j, other in enumerate(names) if j > 0]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _is_run(path: Path) -> bool:
    return (path / "episodes.csv").exists() or (path / "episodes.csv.gz").exists()


def report(runs_dirs: list[Path], out: Path, scripted_dir: Path | None = None) -> None:
    """``runs_dirs``: run folders, or folders of run folders (a round's runs and runs of another
    round it compares with)."""
    runs = []
    for path in runs_dirs:
        if not path.is_dir():
            raise SystemExit(f"error: {path} is not a folder")
        runs += [path] if _is_run(path) else [p for p in path.iterdir() if _is_run(p)]
    runs = sorted(runs, key=lambda p: p.name)
    if not runs:
        raise SystemExit(f"error: no run folders with episodes.csv in {', '.join(map(str, runs_dirs))}")
    summaries = [summarize(p) for p in runs]
    out.mkdir(parents=True, exist_ok=True)
    lines = [STUDY_SEEDS, "",
             "| run | frames | episodes | training successes (last 500 episodes) | first training success: "
             "frames (episode) | training success rate >= 10 % / >= 50 % (200 episodes) | "
             "first evaluation success | evaluation >= 50 % | evaluation >= 90 % | "
             "best evaluation | last evaluation (touching, s to success, at frames) | curriculum "
             "level | wall minutes |", "|" + "---|" * 13]
    for s in summaries:
        last = s["last_eval"]
        last_text = "–" if last is None else (f"{last[0]}/{last[1]} ({last[2]} touching, "
                                              f"{last[3]:.2f} s, {last[4]:,})")
        share = "–" if s["curriculum_level"] is None else f"{s['curriculum_level']:.2f}"
        lines.append(f"| {s['run']} | {s['frames']:,} | {s['episodes']} | {s['train_successes']} "
                     f"({100 * s['train_success_last_500']:.0f} %) | {_at(s['first_train_success'])} | "
                     f"{_at(s['train_10'])} / {_at(s['train_50'])} | "
                     f"{_at(s['first_eval_success'])} | {_at(s['eval_50'])} | {_at(s['eval_90'])} | "
                     f"{s['best_eval'] if s['best_eval'] is not None else '–'} | {last_text} | {share} | "
                     f"{s['wall_minutes']:.0f} |")
    lines += ["", "Per fifth of each run's training episodes:", "",
              "| run | episodes | frames up to | training successes | mean cube displacement (mm) | "
              "episodes touching | ended by the priority constraint | steps in phase 1 / 2 / 3 |",
              "|" + "---|" * 8]
    for path in runs:
        for i, part in enumerate(behaviour_by_part(path)):
            shares = " / ".join(f"{100 * v:.0f} %" for v in part["phase_share"])
            lines.append(f"| {path.name if i == 0 else ''} | {part['episodes'][0]}–{part['episodes'][1]} | "
                         f"{part['frames']:,} | {part['successes']} | {part['displacement_mm']:.1f} | "
                         f"{part['touching']} | {part['constraint']} | {shares} |")
    early = [(path.name, early_behaviour(path)) for path in runs]
    lines += ["", f"The first {EARLY_EPISODES} training episodes (the policy still close to its initial network, "
              "which a seed's runs share across methods):", "",
              "| run | frames up to | episodes touching | mean cube displacement (mm) | successes |",
              "|---|---|---|---|---|"]
    lines += [f"| {name} | {e['frames']:,} | {e['touching']} ({100 * e['touching'] / EARLY_EPISODES:.0f} %) | "
              f"{e['displacement_mm']:.1f} | {e['successes']} |" for name, e in early if e is not None]
    lines += matched_frames_section(runs)
    lines += seed_level_section(runs)
    lines += final_section(runs, scripted_dir)
    (out / "table.md").write_text("\n".join(lines) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 4, figsize=(21, 4.5))
    for s in summaries:
        frames, success, evaluations, batches = s["_curve"]
        if len(success):
            window = min(200, len(success))
            rate = np.convolve(success.astype(float), np.ones(window) / window, mode="valid")
            axes[0].plot(frames[window - 1:], rate, label=s["run"])
        if evaluations:
            axes[1].plot([int(r["frames"]) for r in evaluations],
                         [float(r["success_rate"]) for r in evaluations], "o-", label=s["run"])
        if evaluations and batches:
            # wall minutes at each evaluation: the batches' seconds summed up to its frame count
            batch_frames = np.array([int(r["frames"]) for r in batches])
            minutes = np.cumsum([float(r["seconds"]) for r in batches]) / 60
            at = [float(np.interp(int(r["frames"]), np.r_[0, batch_frames], np.r_[0.0, minutes]))
                  for r in evaluations]
            axes[3].plot(at, [float(r["success_rate"]) for r in evaluations], "o-", label=s["run"])
        if batches and batches[0].get("curriculum_level") not in (None, ""):
            axes[2].plot([int(r["frames"]) for r in batches],
                         [float(r["curriculum_level"]) for r in batches], label=s["run"])
    axes[0].set(title="training success rate (200 episodes)", xlabel="frames", ylim=(0, 1))
    axes[1].set(title="deterministic evaluation (60 s, task starts)", xlabel="frames", ylim=(0, 1))
    axes[2].set(title="start curriculum level", xlabel="frames", ylim=(0, 1.05))
    axes[3].set(title="deterministic evaluation against wall time",
                xlabel="training minutes (evaluations excluded; 2 runs on 2 cores)", ylim=(0, 1))
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=110)
    print((out / "table.md").read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list")
    p_run = sub.add_parser("run")
    p_run.add_argument("row", choices=sorted(ROWS))
    p_run.add_argument("--seed", type=int, default=0)
    p_run.add_argument("--frames", type=int, default=2_000_000)
    p_run.add_argument("--eval-every", type=int, default=100_000, help="frames between evaluations")
    p_run.add_argument("--runs-dir", type=Path, default=Path("runs/scratch"))
    p_run.add_argument("--resume", action="store_true")
    p_run.add_argument("--workers", type=int, default=1,
                       help="train.env_workers: environment processes (pays when the run has the machine alone)")
    p_probe = sub.add_parser("probe", help="a hand-written steering policy under exploration noise")
    p_probe.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.1, 0.25, 0.5])
    p_probe.add_argument("--smoothing", type=float, nargs="+", default=[0.0, 0.8])
    p_probe.add_argument("--episodes", type=int, default=30)
    p_probe.add_argument("--speed", type=float, default=0.4, help="normalised push speed along the lane")
    p_probe.add_argument("--gain", type=float, default=20.0, help="steering gain, 1/m")
    p_probe.add_argument("overrides", nargs="*", help="config overrides (key=value)")
    p_easy = sub.add_parser("easy-eval", help="the policy from the curriculum's easy starts")
    p_easy.add_argument("run_dir", type=Path)
    p_easy.add_argument("--policy", type=Path, default=None)
    p_easy.add_argument("--episodes", type=int, default=40)
    p_report = sub.add_parser("report")
    p_report.add_argument("runs_dir", type=Path, nargs="+", help="run folders, or folders of them")
    p_report.add_argument("--out", type=Path, default=Path("docs/scratch-study"))
    p_report.add_argument("--scripted", type=Path, default=None,
                          help="a folder holding own/evaluation.csv of the scripted controller")
    p_branch = sub.add_parser("branch", help="continue a copy of a run folder with changed settings")
    p_branch.add_argument("source", type=Path)
    p_branch.add_argument("destination", type=Path)
    p_branch.add_argument("overrides", nargs="*", help="config overrides (key=value)")
    p_compare = sub.add_parser("compare", help="evaluations of the same episodes side by side")
    p_compare.add_argument("evaluations", type=Path, nargs="+", help="evaluation.csv files")
    p_compare.add_argument("--names", nargs="+", default=None, help="one per file (default: folder names)")
    p_compare.add_argument("--out", type=Path, default=None, help="also write the table here (markdown)")
    args = parser.parse_args(argv)
    if args.command in ("branch", "compare"):
        from ahrm_stack.config import ConfigError
        try:
            if args.command == "branch":
                return branch(args.source, args.destination, args.overrides)
            names = args.names or [path.parent.name for path in args.evaluations]
            lines = compare(args.evaluations, names)
        except ConfigError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        text = "\n".join(lines) + "\n"
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(text)
        print(text, end="")
        return 0
    if args.command == "list":
        for name, overrides in ROWS.items():
            print(f"{name}: {' '.join(overrides)}")
        return 0
    if args.command == "run":
        if args.workers < 1:
            parser.error(f"--workers must be >= 1, got {args.workers}")
        return run(args.row, args.seed, args.frames, args.runs_dir, args.eval_every, args.resume, args.workers)
    if args.command == "easy-eval":
        easy_eval(args.run_dir, args.policy, args.episodes)
        return 0
    if args.command == "probe":
        probe(args.noise, args.smoothing, args.episodes, args.speed, args.gain, args.overrides)
        return 0
    report(args.runs_dir, args.out, args.scripted)
    return 0


if __name__ == "__main__":
    sys.exit(main())
