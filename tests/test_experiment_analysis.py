"""studies/experiment_analysis.py (docs/protocol.md's analysis) on a synthetic experiment folder,
its statistics by hand."""

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def analysis():
    spec = importlib.util.spec_from_file_location("experiment_analysis", ROOT / "studies" / "experiment_analysis.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["experiment_analysis"] = module  # its dataclass looks its module up
    spec.loader.exec_module(module)
    return module


def test_statistics_by_hand(analysis):
    assert analysis.holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert analysis.sign_test(5, 0) == pytest.approx(2 / 32)
    assert analysis.sign_test(0, 0) == 1.0
    assert analysis.clopper_pearson(0, 10) == pytest.approx((0.0, 1 - 0.025 ** 0.1))
    mean, lo, hi, p = analysis.paired_t(np.array([0.2, 0.1, 0.3]))
    half = 4.302653 * 0.1 / math.sqrt(3)  # t(0.975, 2 df) x sd / sqrt(n)
    assert (mean, lo, hi) == pytest.approx((0.2, 0.2 - half, 0.2 + half), abs=1e-6)
    t = 0.2 / (0.1 / math.sqrt(3))
    assert p == pytest.approx(1 - t / math.sqrt(t * t + 2))  # two-sided, 2 df: closed form
    assert analysis._interval(analysis.paired_t(np.array([0.05]))) == "+0.050 (one seed: no interval, no test)"


def _evaluation(path: Path, success, touched, times=None, lanes=None):
    path.mkdir(parents=True, exist_ok=True)
    times = times or [3.0] * len(success)
    lanes = lanes or ["True"] * len(success)
    rows = ["success,touched_steps,time_to_success,lane_agrees"]
    rows += [f"{s},{int(t)},{time if s else 'nan'},{lane if s else ''}"
             for s, t, time, lane in zip(success, touched, times, lanes)]
    (path / "evaluation.csv").write_text("\n".join(rows) + "\n")


def _experiment(tmp_path: Path, skip: str | None = None) -> Path:
    out = tmp_path / "experiment"
    specs = [{"name": f"{m}-seed{s}", "method": m, "seed": s} for m in ("ahrm", "ls") for s in (0, 1)]
    (out / "runs").mkdir(parents=True)
    (out / "grid.json").write_text(json.dumps({"runs": specs}))
    results = {("ahrm", 0): ([1, 1, 1, 1], [0, 0, 0, 1]), ("ahrm", 1): ([1, 1, 1, 0], [0, 0, 0, 0]),
               ("ls", 0): ([1, 0, 0, 0], [1, 1, 0, 1]), ("ls", 1): ([1, 1, 0, 0], [1, 0, 0, 0])}
    for (method, seed), (success, touched) in results.items():
        name = f"{method}-seed{seed}"
        (out / "runs" / name).mkdir()
        if name != skip:
            _evaluation(out / "runs" / name / "eval", [bool(s) for s in success], [bool(t) for t in touched])
        events = [{"episode": 3, "kind": "order_changed", "phase": 2, "detail": ""}] if name == "ahrm-seed0" else []
        (out / "runs" / name / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    _evaluation(out / "scripted", [True] * 4, [False] * 4)
    return out


def test_the_analysis_of_a_synthetic_experiment(analysis, tmp_path):
    text = analysis.analyse(_experiment(tmp_path))
    assert "PARTIAL" not in text
    assert "| ahrm-seed0 | 4/4 | 1 | 3.00 | 3.00 / 3.00 (4) | 4/4 | changed |" in text
    assert "| ahrm-seed1 | 3/4 | 0 | 3.00 | 3.00 / 3.00 (3) | 3/3 | order never changed (FHRM) |" in text
    assert "| ls-seed1 | 2/4 | 1 | 3.00 | 3.00 / 3.00 (2) | 2/2 | — |" in text
    # pooled: ahrm 7/8 successes, 1/8 touching; against the scripted controller 0 / 1 discordant
    assert "| ahrm | 2 | 7/8 (87.5%" in text and "| 0 / 1, p = 1 | 1 / 0, p = 1 |" in text
    # ahrm - ls per seed: success 1 - 0.25 = 0.75, 0.75 - 0.5 = 0.25; mean 0.5, 1 df
    half = 12.7062 * 0.25  # t(0.975, 1 df) x se; se = sd(0.75, 0.25) / sqrt 2 = 0.3536 / 1.414 = 0.25
    assert f"| ahrm − ls | 0, 1 | +0.500 [{0.5 - half:+.3f}, {0.5 + half:+.3f}]" in text
    # touching: only ahrm touched in 0 paired episodes, only ls in 3 (seed 0: episodes 0 and 1;
    # seed 1: episode 0); sign test 2 / 8
    assert "0 only ahrm / 3 only ls, p = 0.25 |" in text
    assert "touching 1/8" in text and text.rstrip().endswith("not met")


def test_the_hypotheses_are_called_as_registered(analysis, tmp_path):
    """H1–H3: Holm-adjusted two-sided p below 0.05, in the direction of the mean; H4: the exact
    sign test on paired episodes, uncorrected, with the seed-level interval beside it."""
    stat = (0.3, 0.1, 0.5, 0.01)
    assert analysis.call_success(stat, 0.03, False, "ahrm") == "**established**: ahrm higher (Holm p = 0.03)"
    assert analysis.call_success((-0.3, -0.5, -0.1, 0.01), 0.03, False, "ahrm").startswith(
        "**established**: ahrm lower")
    assert analysis.call_success(stat, 0.06, False, "ahrm").startswith("not established (Holm p = 0.06;")
    assert analysis.call_success(stat, 0.01, True, "ahrm") == "not called (partial)"
    assert analysis.call_success((0.3, math.nan, math.nan, math.nan), math.nan, False, "ahrm").startswith("not tested")
    # 0 vs 6 discordant: p = 2 / 64 = 0.03125 < 0.05; 0 vs 5: p = 0.0625
    assert analysis.call_touching((-0.1, -0.2, -0.01, 0.04), 0, 6, False, "ahrm") == (
        "0 only ahrm / 6 only the other, p = 0.0312: ahrm touches less; seed level -0.100 [-0.200, -0.010], excludes 0")
    assert "p = 0.0625: no difference shown; seed level -0.100 [-0.300, +0.100], holds 0" in analysis.call_touching(
        (-0.1, -0.3, 0.1, 0.2), 0, 5, False, "ahrm")
    assert analysis.call_touching(stat, 0, 6, True, "ahrm") == "not called (partial)"
    text = analysis.analyse(_experiment(tmp_path))
    # ahrm - ls: +0.5, se 0.25 on 1 df: t = 2, p = 2 * (1/2 - atan(2) / pi); one comparison, so Holm p = p
    p = 2 * (0.5 - math.atan(2) / math.pi)
    assert f"| H1 | ahrm wins more episodes than ls | not established (Holm p = {p:.3g};" in text
    assert "| H4 (secondary) | ahrm touches in fewer episodes than ls | 0 only ahrm / 3 only the other, p = 0.25: " \
           "no difference shown; seed level -0.375 [" in text


def test_a_missing_run_makes_it_partial(analysis, tmp_path):
    text = analysis.analyse(_experiment(tmp_path, skip="ls-seed1"))
    assert "**PARTIAL**: missing ls-seed1" in text and text.rstrip().endswith("not called (partial)")
    assert "| H1 | ahrm wins more episodes than ls | not called (partial) |" in text
    assert analysis.main([str(tmp_path / "nothing")]) == 2


def test_a_partial_experiment_reports_how_far_each_run_is(analysis, tmp_path):
    """Unfinished runs: frames from episodes.csv against the grid's budget, the latest interim
    (validation) evaluation, and whether AHRM's order has changed so far."""
    out = _experiment(tmp_path, skip="ahrm-seed1")
    grid = json.loads((out / "grid.json").read_text())
    (out / "grid.json").write_text(json.dumps({**grid, "frames": 1000}))
    run = out / "runs" / "ahrm-seed1"
    (run / "episodes.csv").write_text("episode,frames,steps\n0,128,50\n1,250,61\n")
    (run / "evaluations.csv").write_text("episode,frames,episodes,successes,touched_episodes\n"
                                         "0,0,40,0,3\n1,250,40,12,1\n")
    text = analysis.analyse(out)
    assert "**PARTIAL**: missing ahrm-seed1." in text
    assert "| ahrm-seed1 | 250 (25%) | 12/40 (1 touching) at 250 | not yet |" in text
    assert "| ahrm-seed0 | 0 (0%) | — | changed |" in text
    assert "| ls-seed0 | 0 (0%) | — | — |" in text


def test_the_first_line_says_whether_the_planner_is_used(analysis):
    """Computed from the configuration the overrides give (docs/protocol.md's first line)."""
    assisted = analysis.planner_line(["profile=scratch"])
    assert assisted.startswith("**Planner-assisted: the network runs on the scripted controller's lane plan**")
    assert "observes its lane choice" in assisted and "behind the cube" in assisted
    assert analysis.planner_line(["profile=scratch-own-lane"]).startswith("**Planner-free")


def test_interim_curves_and_their_seed_band(analysis, tmp_path):
    """Interim evaluations read per run, frames rounded to the evaluation step; the band is the
    seeds' range (the registered one); the figure is written."""
    out = _experiment(tmp_path)
    grid = json.loads((out / "grid.json").read_text())
    (out / "grid.json").write_text(json.dumps({**grid, "train_overrides": ["train.eval_every_frames=100"]}))
    for seed, successes in ((0, (0, 10)), (1, (2, 20))):
        (out / "runs" / f"ahrm-seed{seed}" / "evaluations.csv").write_text(
            "episode,frames,episodes,successes,touched_episodes\n"
            f"0,0,40,{successes[0]},4\n9,104,40,{successes[1]},2\n")
    curves = analysis.interim_curves(out)
    assert curves == {"ahrm": {0: [(0, 0.0, 0.1), (100, 0.25, 0.05)], 1: [(0, 0.05, 0.1), (100, 0.5, 0.05)]}}
    assert analysis.seed_band([0.25, 0.5]) == (0.375, 0.25, 0.5)
    assert analysis.seed_band([0.1, 0.6, 0.2]) == pytest.approx((0.3, 0.1, 0.6))
    assert analysis.plot_curves(out, tmp_path / "curves.png").stat().st_size > 1000


def test_collect_keeps_what_the_analysis_reads(analysis, tmp_path):
    """The copy gives the same analysis as the folder: frames from the gzipped batches.csv, only
    the order events; the copy's bytes do not depend on when it was made."""
    out = _experiment(tmp_path, skip="ahrm-seed1")
    grid = json.loads((out / "grid.json").read_text())
    (out / "grid.json").write_text(json.dumps({**grid, "frames": 1000, "out": "/somewhere/experiment-7"}))
    run = out / "runs" / "ahrm-seed1"
    (run / "batches.csv").write_text("batch,frames,episodes\n1,128,0\n2,256,1\n")
    (run / "episodes.csv").write_text("episode,frames,steps\n0,128,50\n1,250,61\n")
    (run / "events.jsonl").write_text('{"kind": "constraint_termination"}\n{"kind": "order_locked", "phase": 1}\n')
    (run / "checkpoints").mkdir()
    (run / "checkpoints" / "ckpt-0000002.pt").write_bytes(b"big")
    copy = analysis.collect(out, tmp_path / "copy")
    assert analysis.analyse(copy) == analysis.analyse(out)
    assert analysis.analyse(copy).startswith("# Analysis of experiment-7 ")
    assert "| ahrm-seed1 | 256 (26%) |" in analysis.analyse(copy)  # batches.csv before episodes.csv
    assert (copy / "runs" / "ahrm-seed1" / "events.jsonl").read_text() == '{"kind": "order_locked", "phase": 1}\n'
    assert not (copy / "runs" / "ahrm-seed1" / "checkpoints").exists()
    again = analysis.collect(out, tmp_path / "again")
    for name in ("batches.csv.gz", "events.jsonl"):
        assert (again / "runs" / "ahrm-seed1" / name).read_bytes() == (copy / "runs" / "ahrm-seed1" / name).read_bytes()


def test_the_committed_report_is_what_the_committed_data_give(analysis):
    """docs/experiment-42.md is the analysis of docs/experiment-42/data (plus its figure's link)."""
    committed = (ROOT / "docs" / "experiment-42.md").read_text()
    text = analysis.analyse(ROOT / "docs" / "experiment-42" / "data")
    assert committed.startswith(text), (
        "docs/experiment-42.md is out of date: python studies/experiment_analysis.py /work/experiment-42 "
        "--collect docs/experiment-42/data --write docs/experiment-42.md "
        "--curves docs/experiment-42/interim-curves.png")
    figure = "![interim evaluations against frames](experiment-42/interim-curves.png)"
    assert committed[len(text):].strip() in ("", figure)


def test_a_lost_attempt_is_listed_with_how_far_it_got(analysis, tmp_path):
    """An attempt lost with its checkpoints (OUT/lost/<run>/): collected, listed with its frames
    and latest interim evaluation; the run's own rows stay the restart's."""
    out = _experiment(tmp_path)
    grid = json.loads((out / "grid.json").read_text())
    (out / "grid.json").write_text(json.dumps({**grid, "out": "/somewhere/experiment-7"}))
    lost = out / "lost" / "ahrm-seed1"
    lost.mkdir(parents=True)
    (lost / "batches.csv").write_text("batch,frames,episodes\n1,128,0\n2,256,1\n")
    (lost / "evaluations.csv").write_text("episode,frames,episodes,successes,touched_episodes\n1,250,40,3,7\n")
    (lost / "events.jsonl").write_text('{"kind": "order_changed"}\n')
    text = analysis.analyse(out)
    assert "## Attempts lost with their checkpoints" in text
    assert "| ahrm-seed1 | 256 | 3/40 (7 touching) at 250 | changed |" in text
    copy = analysis.collect(out, tmp_path / "copy")
    assert (copy / "lost" / "ahrm-seed1" / "batches.csv.gz").is_file()
    assert analysis.analyse(copy) == text
    assert "Attempts lost" not in analysis.analyse(_experiment(tmp_path / "other"))


def _record(condition, controller, seed, success, touched, time):
    return {"condition": condition, "controller": controller, "seed": seed, "success": success,
            "touched": touched, "time": time if success else None, "judged_success": success,
            "judged_touched": touched, "emergency_stops": 0}


def test_runs_through_the_deploy_loop_get_a_secondary_section(analysis, tmp_path):
    """OUT/robustness/<run>/robustness.json (ahrm_stack.robustness's format): each judged run's ideal
    and all-imperfections rows, its count of conditions meeting the robustness goal, the pooled row
    with its sign tests (by hand); runs not yet judged are named; collected gzipped."""
    out = _experiment(tmp_path)
    grid = json.loads((out / "grid.json").read_text())
    (out / "grid.json").write_text(json.dumps({**grid, "out": "/somewhere/experiment-7"}))
    records = [_record("ideal", "policy", s, True, False, 3.0) for s in (1, 2)]
    records += [_record("ideal", "scripted", s, True, False, 4.0) for s in (1, 2)]
    records += [_record("all (jaco2)", "policy", 1, True, True, 3.0),
                _record("all (jaco2)", "policy", 2, False, False, 0)]
    records += [_record("all (jaco2)", "scripted", s, True, False, 4.0) for s in (1, 2)]
    judged = out / "robustness" / "ahrm-seed0"
    judged.mkdir(parents=True)
    (judged / "robustness.json").write_text(json.dumps(
        {"profile": "jaco2", "conditions": ["ideal", "all (jaco2)"], "records": records}))
    for name in ("ahrm-seed1", "ls-seed1"):  # finished; ls-seed1's policy is there, ahrm-seed1's lost
        (out / "runs" / name / "done.json").write_text("{}")
    (out / "runs" / "ls-seed1" / "policy.pt").write_bytes(b"weights")
    text = analysis.analyse(out)
    assert "Not yet through it: ls-seed0, ls-seed1. Finished, but its final policy is lost" in text
    assert "(not in the run folder): ahrm-seed1." in text
    # ideal: both won both, policy faster -> goal met; all: the policy won 1 of 2 and touched once -> missed
    assert "| ahrm-seed0 | jaco2 | 2/2 of 2 (0/0) | 1/2 of 2 (1/0) | 1 of 2 |" in text
    low, high = analysis.clopper_pearson(1, 2)
    assert f"| ahrm | 1 | 1/2 (50.0% [{low:.1%}, {high:.1%}]) |" in text
    deploy = text[text.index("## Through the deploy loop"):]
    # only the scripted controller won seed 2; only the policy touched
    assert deploy.rstrip().endswith("| 0 / 1, p = 1 | 1 / 0, p = 1 |")
    copy = analysis.collect(out, tmp_path / "copy")
    assert (copy / "robustness" / "ahrm-seed0" / "robustness.json.gz").is_file()
    assert (copy / "runs" / "ls-seed1" / "policy.pt").read_bytes() == b"weights"
    assert analysis.analyse(copy) == text
    assert "deploy loop" not in analysis.analyse(_experiment(tmp_path / "other"))


def test_the_deploy_loop_script_skips_what_it_cannot_judge(tmp_path):
    """tools/experiment_deploy_loop.sh names every run it skips and why (no policy is run here);
    without a grid it stops with a one-line error."""
    import subprocess
    out = _experiment(tmp_path)
    (out / "runs" / "ahrm-seed1" / "done.json").write_text("{}")
    (out / "robustness" / "ls-seed0").mkdir(parents=True)
    (out / "robustness" / "ls-seed0" / "robustness.json").write_text("{}")
    script = ROOT / "tools" / "experiment_deploy_loop.sh"
    done = subprocess.run(["bash", str(script), str(out)], capture_output=True, text=True,
                          env={"PYTHON": sys.executable, "PATH": "/usr/bin:/bin"}, check=True)
    assert done.stdout.splitlines() == ["ahrm-seed0: not finished, skipped",
                                        "ahrm-seed1: finished, but its final policy is lost, skipped",
                                        "ls-seed0: judged before, skipped", "ls-seed1: not finished, skipped"]
    failed = subprocess.run(["bash", str(script), str(tmp_path / "nothing")], capture_output=True, text=True)
    assert failed.returncode == 2 and failed.stderr.count("\n") == 1 and "grid.json not found" in failed.stderr


def test_time_and_wrong_lanes_on_paired_episodes(analysis, tmp_path):
    """Time on the episodes both runs of a seed won (by hand), against the scripted controller per
    run, and the sign test on wrong-lane episodes."""
    out = _experiment(tmp_path)
    # seed 0: ahrm wins all four in 2, 2, 4, 4 s; ls wins episode 0 only, in 5 s -> both won: episode 0,
    # difference 2 - 5 = -3. Seed 1: ahrm wins 0-2 in 3, 3, 3 s; ls wins 0-1 in 4, 6 s -> both won 0, 1:
    # 3 - 5 = -2. Mean -2.5, 1 df, se = sd(-3, -2) / sqrt 2 = 0.5
    _evaluation(out / "runs" / "ahrm-seed0" / "eval", [True] * 4, [False, False, False, True], [2, 2, 4, 4],
                ["True", "False", "True", "True"])
    _evaluation(out / "runs" / "ls-seed0" / "eval", [True, False, False, False], [True, True, False, True],
                [5, 0, 0, 0])
    _evaluation(out / "runs" / "ahrm-seed1" / "eval", [True, True, True, False], [False] * 4, [3, 3, 3, 0])
    _evaluation(out / "runs" / "ls-seed1" / "eval", [True, True, False, False], [True, False, False, False],
                [4, 6, 0, 0], ["False", "False", "", ""])
    _evaluation(out / "scripted", [True] * 4, [False] * 4, [1, 2, 3, 10])
    text = analysis.analyse(out)
    # against the scripted controller on the episodes both won: ahrm seed 0 all four (3 vs 16/4);
    # ahrm seed 1 episodes 0-2 (3 vs 2); ls seed 1 episodes 0, 1 (5 vs 1.5)
    assert "| ahrm-seed0 | 4/4 | 1 | 3.00 | 3.00 / 4.00 (4) | 3/4; 0 of 1 wrong-lane touching | changed |" in text
    assert "| ahrm-seed1 | 3/4 | 0 | 3.00 | 3.00 / 2.00 (3) | 3/3 | order never changed (FHRM) |" in text
    assert "| ls-seed1 | 2/4 | 1 | 5.00 | 5.00 / 1.50 (2) | 0/2; 1 of 2 wrong-lane touching | — |" in text
    # each run against the scripted controller: ls seed 1 lost episodes 2, 3 (0 / 2, p = 0.5), touched
    # in episode 0 (1 / 0), left episodes 0, 1 by a wrong lane (2 / 0, p = 0.5)
    assert "| ls-seed1 | 0 / 2, p = 0.5 | 1 / 0, p = 1 | 2 / 0, p = 0.5 |" in text
    half = 12.7062 * 0.5
    t = 2.5 / 0.5
    p = 2 * (0.5 - math.atan(t) / math.pi)  # two-sided, 1 df (Cauchy): closed form
    assert (f"| {-2.5:+.3f} [{-2.5 - half:+.3f}, {-2.5 + half:+.3f}], p = {p:.3g} "
            "(episodes both won, by seed: 0: 1, 1: 2) |") in text
    # wrong lane: ahrm seed 0 episode 1 (ls did not push it); ls seed 1 episodes 0 and 1 -> 1 / 2
    assert "| 1 only ahrm / 2 only ls, p = 1 |" in text


def test_the_goal_is_not_applicable_to_planner_assisted_runs(analysis, tmp_path):
    """The registered goal is for a policy without the planner: planner-assisted runs get no verdict."""
    for overrides, verdict in ((["profile=scratch"], "not applicable: the goal is for a policy without the planner"),
                               (["profile=scratch-own-lane"], "not met")):
        out = _experiment(tmp_path / overrides[0])
        grid = json.loads((out / "grid.json").read_text())
        (out / "grid.json").write_text(json.dumps({**grid, "train_overrides": overrides}))
        goal = analysis.analyse(out).split("## Goal")[1]
        assert goal.startswith(" (without the planner, ahrm pooled") and verdict in goal


def test_the_methods_are_ranked_with_seed_level_intervals(analysis, tmp_path):
    """Per method, the mean of its per-seed success shares with a t-interval over its seeds."""
    text = analysis.analyse(_experiment(tmp_path))
    # ahrm: seeds 4/4 and 3/4 -> mean 0.875, sd 0.1768, se 0.125, t(0.975, 1 df) 12.7062: the
    # interval [-71.3 %, 246.3 %] is clipped to the shares' range
    assert "| 1 | ahrm | 2 | 87.5% [0.0%, 100.0%]; seeds 75.0%–100.0% | " in text
    assert analysis.seed_level([0.8, 0.9, 0.85]) == "85.0% [72.6%, 97.4%]; seeds 80.0%–90.0%"  # 4.3027 x 0.05 / sqrt 3
    # ls: 1/4 and 2/4 -> 37.5 %, ranked second; touching 3/4 and 1/4 -> 50.0 %
    assert "| 2 | ls | 2 | 37.5% [" in text and "; seeds 25.0%–75.0% |" in text
    assert analysis.seed_level([0.5]) == "50.0% (one seed: no interval)"
