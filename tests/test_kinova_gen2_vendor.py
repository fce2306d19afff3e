"""Kinova's own Gen2 SDK binary (ahrm_stack/hardware/vendor/kinova_gen2/x86_64-linux-gnu, from kinova-ros),
without an arm, always in a child process so that a crash shows as a return code, never takes
pytest down: the codes it returns (fake_kinova_sdk/no_arm.py, which the fake matches), the calls
that crash it, and the documented set-up end to end: without the loader path, one line saying what
to set (exit 2); with it, ``connect()`` (and ``--check``) ends in the one-line "no arm found" error
(exit 3), on every failure path reachable without an arm, never a signal."""

from __future__ import annotations

import ctypes.util
import os
import platform
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ahrm_stack.hardware.kinova_gen2.loader import VENDOR_DIR, VENDOR_LIBRARY
from conftest import touched_off

from fake_kinova_sdk import no_arm  # noqa: E402  (tests/ is on sys.path)

ROOT = Path(__file__).resolve().parents[1]
SERIAL = "PJ00900006151300001"
TIMEOUT = 120  # s per child: a loaded 2-core machine imports dm_control slowly

pytestmark = [
    pytest.mark.skipif(not (sys.platform.startswith("linux") and platform.machine() == "x86_64"),
                       reason="Kinova's vendored Gen2 SDK is the x86_64 Linux build"),
    # the SDK takes Kinova's machine-wide lock (/dev/shm/sem.KinovaMutex): one worker runs these
    pytest.mark.xdist_group("kinova_vendor_sdk"),
]


@pytest.fixture(scope="module")
def libusb() -> None:
    if ctypes.util.find_library("usb-1.0") is None:
        pytest.skip("libusb-1.0 is not installed, so Kinova's USB layer cannot load: `make setup` "
                    "installs it (Debian/Ubuntu package libusb-1.0-0)")


def _env(loader_path: str | None) -> dict[str, str]:
    """This environment with LD_LIBRARY_PATH exactly ``loader_path`` (None: unset), the
    repository and tests/ first on PYTHONPATH."""
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    if loader_path is not None:
        env["LD_LIBRARY_PATH"] = loader_path
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "tests"), env.get("PYTHONPATH", "")])
    env.setdefault("MUJOCO_GL", "egl")
    return env


def _run(args: list[str], loader_path: str | None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], env=_env(loader_path), cwd=ROOT,
                          capture_output=True, text=True, timeout=TIMEOUT)


def _loader_path(comm: bool) -> str | None:
    return str(VENDOR_DIR) if comm else None


def test_the_vendor_files_are_there():
    for name in ("USBCommandLayerUbuntu.so", "USBCommLayerUbuntu.so"):
        assert (VENDOR_DIR / name).is_file(), name
    assert "Redistribution and use in source and binary forms" in (
        VENDOR_DIR.parent / "LICENSE").read_text()


# ------------------------------------------------------------------ the binary, call by call


@pytest.mark.parametrize("name", sorted(no_arm.SEQUENCES))
def test_real_sdk_codes_without_an_arm(libusb, name):
    comm, calls = no_arm.SEQUENCES[name]
    done = _run(["-m", "fake_kinova_sdk.no_arm", str(VENDOR_LIBRARY), *[c for c, _ in calls]],
                _loader_path(comm))
    assert done.returncode == 0, done.stderr[-2000:]
    got = no_arm.parse(done.stdout)
    assert no_arm.matches(got, calls), [(g, c) for g, c in zip(got, calls) if g != c]


@pytest.mark.parametrize("name", sorted(no_arm.CRASHES))
def test_real_sdk_crashes_where_the_table_says(libusb, name):
    """Why the adapter never calls these there (the fake counts them: test_kinova_gen2.py)."""
    comm, calls = no_arm.CRASHES[name]
    done = _run(["-m", "fake_kinova_sdk.no_arm", str(VENDOR_LIBRARY), *calls], _loader_path(comm))
    assert done.returncode == -signal.SIGSEGV, (done.returncode, done.stdout, done.stderr[-500:])
    assert [c for c, _ in no_arm.parse(done.stdout)] == calls[:-1]


# ------------------------------------------------------------------ the documented set-up


def _config(tmp_path: Path) -> Path:
    data = yaml.safe_load((ROOT / "configs" / "deploy.yaml").read_text())
    data["kinova_gen2"].update(library=str(VENDOR_LIBRARY), serial=SERIAL,
                               scene=str(ROOT / "configs" / "scenes" / "default.yaml"))
    touched_off(data, tmp_path)
    path = tmp_path / "deploy.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _error_line(done: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("python -m ahrm_stack.deploy")]
    assert len(lines) == 1, done.stderr[-3000:]
    return lines[0]


def test_deploy_without_the_loader_path_says_what_to_set(libusb, tmp_path):
    done = _run(["-m", "ahrm_stack.deploy", "--backend", "kinova-gen2", "--config",
                 str(_config(tmp_path)), "--telemetry", ""], None)
    line = _error_line(done)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "deploy.kinova_gen2.library" in line and "USBCommLayerUbuntu.so" in line
    assert f"export LD_LIBRARY_PATH={VENDOR_DIR}" in line and "docs/hardware.md" in line


def test_deploy_without_an_arm_ends_in_one_line(libusb, tmp_path):
    telemetry = tmp_path / "telemetry.jsonl"
    done = _run(["-m", "ahrm_stack.deploy", "--backend", "kinova-gen2", "--config",
                 str(_config(tmp_path)), "--telemetry", str(telemetry)], str(VENDOR_DIR))
    line = _error_line(done)
    assert done.returncode == 3, (done.returncode, done.stderr[-3000:])  # a start-up fault, no signal
    assert "no Kinova arm found on USB" in line and "ERROR_NO_DEVICE_FOUND (1015)" in line
    assert '"summary"' in telemetry.read_text().splitlines()[-1]


def test_check_without_an_arm_ends_in_one_line(libusb, tmp_path):
    """`--check` (the USB budget) on Kinova's binary without an arm: the same one line, exit 3."""
    done = _run(["-m", "ahrm_stack.deploy", "--backend", "kinova-gen2", "--config",
                 str(_config(tmp_path)), "--check"], str(VENDOR_DIR))
    line = _error_line(done)
    assert done.returncode == 3, (done.returncode, done.stderr[-3000:])
    assert "no Kinova arm found on USB" in line and "ERROR_NO_DEVICE_FOUND (1015)" in line


CONNECT = """
import dataclasses, sys
import ahrm_stack.hardware.kinova_gen2 as gen2
import ahrm_stack.hardware.kinova_gen2.sdk as gen2_sdk
import ahrm_stack.hardware.kinova_gen2.settings as gen2_settings
from ahrm_stack.hardware.protocol import HardwareError
from ahrm_stack.deploy import load_deploy_settings
from ahrm_stack.robot import describe, make_arm
from ahrm_stack.hardware.kinova_gen2.loader import VENDOR_LIBRARY
if sys.argv[1] == "bypass-check":  # reach InitAPI's own failure (2002), as an unchecked caller would
    gen2_settings.check_sdk_path = gen2_sdk.check_sdk_path = lambda library: {}
settings = dataclasses.replace(load_deploy_settings().kinova_gen2, library=str(VENDOR_LIBRARY),
                               serial="%s")
arm = gen2.KinovaGen2Arm(describe("jaco", make_arm("jaco")), settings, 0.1)
for attempt in range(2):
    try:
        arm.connect()
    except HardwareError as error:
        print("connect failed:", error, flush=True)
    print("connected:", arm.is_connected, flush=True)
arm.disconnect()
print("done", flush=True)
""" % SERIAL


@pytest.mark.parametrize("case", ["no arm", "communication layer not loaded"])
def test_connect_failure_paths_never_crash(libusb, case):
    """Every failure of connect() reachable without an arm, twice in one process (a second InitAPI
    would "succeed" if the first had not been closed): one line each, then a clean exit."""
    bypass = case != "no arm"
    done = _run(["-c", CONNECT, "bypass-check" if bypass else "checked"],
                None if bypass else str(VENDOR_DIR))
    assert done.returncode == 0, (done.returncode, done.stdout, done.stderr[-3000:])
    lines = done.stdout.splitlines()
    assert lines[-1] == "done" and lines.count("connected: False") == 2, done.stdout
    failures = [line for line in lines if line.startswith("connect failed:")]
    assert len(failures) == 2
    expected = ("Kinova's communication layer did not load (InitAPI failed: ERROR_LOAD_COMM_DLL "
                "(2002))" if bypass else
                "no Kinova arm found on USB (InitAPI failed: ERROR_NO_DEVICE_FOUND (1015))")
    assert all(expected in line for line in failures), failures


def test_a_comm_layer_that_cannot_load_names_what_is_missing(libusb, tmp_path):
    """The loader finds USBCommLayerUbuntu.so but not a library it needs (as without libusb): the
    check says so in one line (a stand-in comm layer linked against a library then removed)."""
    cc = shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler to build the stand-in communication layer")
    stub, layer = tmp_path / "stub.c", tmp_path / "layer.c"
    stub.write_text("int kinova_test_usb(void) { return 1; }\n")
    layer.write_text("int kinova_test_usb(void);\nint use(void) { return kinova_test_usb(); }\n")
    for args in (["-o", str(tmp_path / "libusb-kinova-test.so"), str(stub)],
                 ["-o", str(tmp_path / "USBCommLayerUbuntu.so"), str(layer), f"-L{tmp_path}",
                  "-lusb-kinova-test"]):
        subprocess.run([cc, "-shared", "-fPIC", *args], check=True, capture_output=True)
    (tmp_path / "libusb-kinova-test.so").unlink()
    code = ("from pathlib import Path\nfrom ahrm_stack.hardware.kinova_gen2 import Gen2ConfigError, check_sdk_path\n"
            f"try:\n    check_sdk_path(Path({str(VENDOR_LIBRARY)!r}))\n"
            "except Gen2ConfigError as error:\n    print(error)\n")
    done = _run(["-c", code], str(tmp_path))
    assert done.returncode == 0, done.stderr[-2000:]
    line = done.stdout.strip()
    assert "\n" not in line and "communication layer USBCommLayerUbuntu.so does not load" in line
    assert "libusb-kinova-test.so" in line and "sudo apt-get install libusb-1.0-0" in line
