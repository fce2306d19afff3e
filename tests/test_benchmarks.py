"""Every benchmark (benchmarks/bench_*.py) runs to the end in its brief mode (``--quick``).

``make bench`` runs them at full size; this keeps a broken benchmark from going unnoticed until
then. Each prints its figures as a ratio of two things measured in one run; here only that it
finishes (exit status 0) and prints its ratio line is checked, not the figures (~30 s in all).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((ROOT / "benchmarks").glob("bench_*.py"))
RATIO_LINE = {  # a line each benchmark prints when it got to its figures
    "bench_camera_scene.py": "ratio camera/true successes",
    "bench_camera_thread.py": "ratio thread/none tick p99",
    "bench_collection.py": "ratio lean/TorchRL",
    "bench_concurrent_training.py": "parallel speed-up of runs",
    "bench_cores.py": "parallel speed-up",
    "bench_config.py": "ratio config/plain attribute access",
    "bench_deploy.py": "share of the summed tick time",
    "bench_distance_rows.py": "ratio reference/fast",
    "bench_env_step.py": "ratio full/bare",
    "bench_gen2_budget.py": "ratio arm points per policy tick",
    "bench_gen2_estop.py": "ratio false e-stops per tick",
    "bench_kinova_gen2.py": "ratio sends per policy tick",
    "bench_kortex_link.py": "ratio child/direct",
    "bench_loss.py": "ratio ClipPPOLoss/lean",
    "bench_phases.py": "ratio reference/fast",
    "bench_physics.py": "ratio configured/noslip 0",
    "bench_policy.py": "ratio to the TorchRL deterministic actor",
    "bench_safety.py": "ratios osqp / daqp",
    "bench_throughput.py": "ratio fast/reference frames/s",
    "bench_training.py": "ratio training/replay",
}


def test_every_benchmark_is_covered():
    assert {b.name for b in BENCHMARKS} == set(RATIO_LINE), "add the new benchmark's ratio line here"


@pytest.mark.parametrize("script", BENCHMARKS, ids=[b.name for b in BENCHMARKS])
def test_benchmark_runs_briefly(script: Path):
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, str(script), "--quick"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{script.name} --quick failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}"
    assert RATIO_LINE[script.name] in done.stdout, done.stdout[-2000:]
