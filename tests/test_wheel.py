"""The package installs (issue 57, item 6): a wheel built from the checkout, installed into a fresh
virtual environment and run from a folder outside the checkout, finds its packaged configs, the
vendored SDK files and the vendored Gen3 model, and its console scripts evaluate the scripted
controller and drive a committed policy through the deploy loop on the sim backend.

The fresh environment borrows this environment's installed dependencies (its site folder and its
.pth hooks, all but this checkout's editable hook), so the test needs no network; the project itself
comes only from the wheel."""

import subprocess
import sys
import sysconfig
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(args, cwd, timeout=300, codes=(0,)):
    done = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode in codes, (args, done.stdout[-1500:], done.stderr[-1500:])
    return done.stdout


def test_the_built_wheel_runs_outside_the_checkout(tmp_path):
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(wheels),
          str(ROOT)], tmp_path)
    [wheel] = wheels.glob("ahrm_stack-*.whl")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path)
    python = venv / "bin" / "python"
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = Path(_run([str(python), "-c", purelib], tmp_path).strip())
    ours = Path(sysconfig.get_paths()["purelib"])
    hooks = [line for pth in sorted(ours.glob("*.pth")) if "editable" not in pth.name
             for line in pth.read_text().splitlines() if line.startswith("import ")]
    (site / "ahrm-deps.pth").write_text("\n".join([str(ours), *hooks]) + "\n")
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps", str(wheel)], tmp_path)

    work = tmp_path / "work"  # outside the checkout: no configs/ beside it
    work.mkdir()
    where = _run([str(python), "-c", "import ahrm_stack.paths as p, ahrm_stack.hardware.kinova_gen2.loader as g; "
                  "print(p.__file__); print(p.CONFIG_DIR); print(p.IN_CHECKOUT); print(g.VENDOR_DIR.is_dir())"], work)
    module, configs, in_checkout, vendor = where.split()
    assert module.startswith(str(venv)) and configs.startswith(str(venv)), where  # the wheel's, not the checkout's
    assert (in_checkout, vendor) == ("False", "True")
    gen3 = _run([str(python), "-c", "from ahrm_stack.robot import describe, make_arm; "
                 "print(describe('gen3', make_arm('gen3')).urdf)"], work).strip()  # its vendored URDF and meshes
    assert gen3.startswith(str(venv)) and gen3.endswith("vendor/kinova_gen3/gen3.urdf"), gen3
    bin_ = venv / "bin"
    out = _run([str(bin_ / "ahrm-evaluate"), "--policy", "scripted", "--episodes", "1", "--layout", "default"], work)
    assert "successes 1" in out and (work / "runs" / "scripted-eval" / "evaluation.json").is_file()
    out = _run([str(bin_ / "ahrm-deploy"), "--backend", "sim", "--checkpoint",
                str(ROOT / "docs" / "policies" / "ahrm-default-seed0"), "--duration", "1", "--fast"], work,
               codes=(0, 1))  # 1: the episode was not won in its one second (the summary says why)
    assert "deploy summary" in out and "deadline misses 0" in out
    for script in ("ahrm-train", "ahrm-robustness", "ahrm-experiment", "ahrm-demo", "ahrm-test-ledger",
                   "ahrm-calibrate"):
        assert "usage:" in _run([str(bin_ / script), "--help"], work)
