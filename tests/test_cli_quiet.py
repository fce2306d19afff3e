"""Quiet command lines (ahrm_stack/cli.py): no library noise before an entry point's first line.

Noise measured before: glfw's "X11: The DISPLAY environment variable is missing" (GLFWError, when
MUJOCO_GL is unset and dm_control is imported), torchrl's DeprecationWarnings at import ("Creating
VanillaWeightUpdater ...") and its INFO log ("[torchrl][INFO] Initialized LazyTensorStorage").
Each command runs in a subprocess without MUJOCO_GL and DISPLAY (where glfw complains); all of them
are started at once and collected by one fixture, so the file costs about as long as its slowest.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from ahrm_stack import cli

ROOT = Path(__file__).resolve().parents[1]
NOISE = ("DeprecationWarning", "GLFWError", "DISPLAY", "[INFO]", "absl")

# dm_control's composer (glfw.init without a display; it also turns every DeprecationWarning on),
# torchrl's collectors (deprecation warnings at import) and torchrl's INFO logger: the three
# sources, behind quiet_argv() as in an entry point.
LIBRARIES = ("from ahrm_stack import cli; cli.quiet_argv(); "
             "import dm_control.composer; import torchrl.collectors, logging; "
             "logging.getLogger('torchrl').info('torchrl INFO line'); print('first line')")
DEMO = ["-m", "ahrm_stack.demo", "--episodes", "1", "--layout", "fixed", "task.episode.duration=0.1"]
COMMANDS = {
    "libraries": ["-c", LIBRARIES],
    "libraries --verbose": ["-c", LIBRARIES, "--verbose"],
    "demo": DEMO,
    "demo --verbose": [*DEMO, "--verbose"],
    **{f"{name} --help": ["-m", f"ahrm_stack.{name}", "--help"]
       for name in ("train", "evaluate", "experiment", "demo")},
    "report": ["-m", "ahrm_stack.report", "--verbose"],  # the usage line, nothing else
}


@pytest.fixture(scope="module")
def runs() -> dict[str, subprocess.CompletedProcess]:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "RL_LOGGING_LEVEL")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    procs = {name: subprocess.Popen([sys.executable, *args], cwd=ROOT, env=env, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for name, args in COMMANDS.items()}
    out = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        out[name] = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
    return out


def _noise(text: str) -> list[str]:
    return [line for line in text.splitlines() if any(word in line for word in NOISE)]


def test_library_noise_is_hidden_by_default(runs):
    run = runs["libraries"]
    assert run.returncode == 0, run.stderr
    assert run.stdout == "first line\n"
    assert run.stderr == "", run.stderr


def test_verbose_shows_the_library_noise(runs):
    run = runs["libraries --verbose"]
    assert run.returncode == 0, run.stderr
    assert any("GLFWError" in line for line in run.stderr.splitlines()), run.stderr
    assert any("DeprecationWarning" in line for line in run.stderr.splitlines()), run.stderr
    assert "torchrl INFO line" in run.stdout + run.stderr  # torchrl logs to stdout


def test_demo_prints_its_own_lines_only(runs):
    quiet, verbose = runs["demo"], runs["demo --verbose"]
    assert quiet.returncode == 0 and verbose.returncode == 0, quiet.stderr + verbose.stderr
    assert quiet.stdout.startswith("== fixed layout")
    assert quiet.stderr == "", quiet.stderr
    assert _noise(verbose.stderr), verbose.stderr  # glfw's DISPLAY complaint, shown on request


@pytest.mark.parametrize("name", ["train", "evaluate", "experiment", "demo"])
def test_every_entry_point_offers_verbose_and_is_quiet(runs, name):
    run = runs[f"{name} --help"]
    assert run.returncode == 0, run.stderr
    assert "--verbose" in run.stdout
    assert _noise(run.stderr) == [], run.stderr


def test_report_takes_verbose_and_prints_its_usage_only(runs):
    run = runs["report"]
    assert run.returncode == 2
    assert run.stderr == "usage: python -m ahrm_stack.report [--verbose] OUT_DIR\n"


def test_quiet_keeps_the_projects_own_warnings(monkeypatch):
    """In-process: a warning raised from a library file is dropped, one from ours is shown."""
    shown: list = []
    monkeypatch.delenv("RL_LOGGING_LEVEL", raising=False)  # restored (removed) afterwards
    monkeypatch.setattr(cli, "_SHOW_ALL", lambda *args: shown.append(args[0]))
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    monkeypatch.setattr(logging.getLogger("torchrl"), "level", logging.getLogger("torchrl").level)
    cli.quiet(False)
    warnings.showwarning(UserWarning("library"), UserWarning, "/usr/lib/python3/site-packages/x.py", 1)
    warnings.showwarning(UserWarning("ours"), UserWarning, str(ROOT / "ahrm_stack" / "train.py"), 1)
    assert [str(w) for w in shown] == ["ours"]
    assert logging.getLogger("torchrl").level == logging.WARNING
    assert os.environ["RL_LOGGING_LEVEL"] == "WARNING"  # for a torchrl imported later
    assert cli.library_log_level() == logging.WARNING
    cli.quiet(True)
    assert warnings.showwarning is cli._SHOW_ALL
    assert "RL_LOGGING_LEVEL" not in os.environ
    assert cli.library_log_level() == logging.INFO


def test_quiet_argv_strips_the_flag(monkeypatch):
    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)
    assert cli.quiet_argv(["--backend", "sim", "--verbose"]) == ["--backend", "sim"]
    assert cli.library_log_level() == logging.INFO
