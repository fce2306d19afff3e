"""Perception frames that put an obstacle exactly touching the arm never abort the deploy loop
(issue 17: python-fcl, used before, aborted the process with an uncaught C++ ``std::logic_error``
when a box face came within ~1e-10 m of the pusher's side).

Each run is the deploy command itself (:func:`ahrm_stack.deploy.main`, sim backend, fast clock)
in a child process, so that an abort shows as a signal in the return code instead of killing
the test. In the child the sim backend is :class:`TouchingSimArm`: its perception reports one
obstacle (``obstacle_0``) with a face exactly touching the pusher's side or a link capsule's side
(:data:`GAPS`: 0, +-1e-12, +-1e-10 m), on every call from :func:`first_touch` on (start-up for
runs 0 and 1, a later tick for the others), placed from the arm's current joint angles by the same
Pinocchio model and collision scene the safety filter uses. The part (the pusher in every other
frame from the first, else a link capsule drawn at random), the gap (cycled, starting at another
one in each run) and the direction (drawn, perpendicular to the part's axis) change from frame
to frame; even runs use the scripted controller, odd runs the committed policy
``docs/policies/ahrm-default-seed0``. The loop does not run on with an obstacle touching: the
filter reports the obstacle row violated within one or two touching frames and the loop e-stops,
so a run is fed a few touching frames, each one through the distance layer.

For each run: the return code is not a signal (and is 0 or 1, not a software fault), the
telemetry has a stop event and ends with the summary, the command the arm held when the loop let
go of it is zero, every command sent is finite and within the velocity limits, and the simulated
arm counted no limit violation. In CI two runs (one per controller) of a few ticks; the full
measurement is ``python tests/test_deploy_touching.py --runs 10`` (``--jobs 5``: five children
at once).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__":  # run as a script: this checkout's packages, not an installed copy
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

POLICY = ROOT / "docs" / "policies" / "ahrm-default-seed0"
GAPS = (0.0, 1e-12, -1e-12, 1e-10, -1e-10)  # m, face to side; negative: that deep inside
OBSTACLE = 0  # the obstacle whose reported pose is moved
RATE_HZ = 20.0
FIRST_TOUCH = 0  # the first perception call that touches (the child sets it from its run)
RUN = 0  # the child's run


def first_touch(run: int) -> int:
    """The first touching perception call of run ``run``: start-up for runs 0 and 1, then later
    and later ticks, so that the touch meets the arm in other poses and phases."""
    return 0 if run < 2 else 2 * run


def touching_arm_class():
    """A :class:`~ahrm_stack.sim_arm.SimArm` whose perception reports ``obstacle_0`` touching a moving
    robot part (imported lazily: the parent process needs none of it)."""
    import dataclasses

    import mujoco

    from ahrm_stack.kinematics.scene import signed_distance
    from ahrm_stack.sim_arm import SimArm

    class TouchingSimArm(SimArm):
        instance: "TouchingSimArm | None" = None

        def __init__(self, task_config, seed: int = 0, **kwargs) -> None:
            super().__init__(task_config, seed=seed, **kwargs)
            TouchingSimArm.instance = self
            self.rng = np.random.default_rng(1000 + seed)
            # The simulator's own task: its kinematics and collision scene are separate from the
            # deploy loop's (the world model's), built from the same description.
            self.scene = self.task.make_collision_scene(self.physics)
            self.parts = list(self.scene.moving_parts)
            self.box = self.scene.environment[f"obstacle_{OBSTACLE}"]
            self.frames: list[dict] = []  # one per touching frame reported
            self.held_at_release: list[float] | None = None
            self.calls = 0  # perception calls: 0 is the loop's start-up, then one per tick

        def perception(self):
            poses = super().perception()
            self.calls += 1
            if self.calls - 1 < FIRST_TOUCH:
                return poses
            q, _ = self.task.arm_state(self.physics)  # the joint angles of this tick's feedback
            self.scene.kinematics.update(q)
            self.scene.update_robot()
            k = len(self.frames)
            # the pusher (python-fcl's abort) in every other frame, from the first; else a link
            links = [name for name in self.parts if name != "pusher"]
            part = "pusher" if k % 2 == 0 else links[int(self.rng.integers(len(links)))]
            gap = GAPS[(RUN + k) % len(GAPS)]  # each run starts at another gap
            obj = self.scene.robot[part]
            center = np.asarray(obj.getTranslation(), dtype=float)
            axis = np.asarray(obj.getRotation(), dtype=float)[:, 2]  # cylinders, capsules: local z
            geometry = obj.collisionGeometry()
            # a random direction perpendicular to the axis: the box face's outward normal is -n
            n = np.cross(axis, self.rng.normal(size=3))
            n /= np.linalg.norm(n)
            rotation = np.column_stack([n, np.cross(axis, n), axis])  # x = n, z = the axis
            half = np.asarray(self.box.collisionGeometry().halfSide, dtype=float)
            position = center + (geometry.radius + half[0] + gap) * n  # face x = -hx on the side
            quaternion = np.empty(4)
            mujoco.mju_mat2Quat(quaternion, rotation.ravel())
            positions = poses.obstacle_positions.copy()
            quaternions = poses.obstacle_quaternions.copy()
            positions[OBSTACLE], quaternions[OBSTACLE] = position, quaternion
            # what the distance layer answers for the pose as reported (rotation from the quaternion)
            back = np.empty(9)
            mujoco.mju_quat2Mat(back, quaternion / np.linalg.norm(quaternion))
            self.box.setRotation(back.reshape(3, 3))
            self.box.setTranslation(position)
            d, *_, exact = signed_distance(obj, self.box)
            self.frames.append({"call": self.calls - 1, "part": part, "gap": gap,
                                "distance": float(d), "exact": bool(exact)})
            return dataclasses.replace(poses, obstacle_positions=positions,
                                       obstacle_quaternions=quaternions)

        def disconnect(self) -> None:
            if self.is_connected and self.held_at_release is None:
                self.held_at_release = self.command.tolist()  # before disconnect zeroes it
            super().disconnect()

    return TouchingSimArm


def child(run: int, duration: float, telemetry: str, result: str) -> int:
    """One deploy run with touching frames (this process); writes ``result`` (JSON), returns the
    deploy command's exit code."""
    import logging

    import ahrm_stack.sim_arm
    from ahrm_stack import deploy
    from ahrm_stack.kinematics import scene

    global FIRST_TOUCH, RUN
    FIRST_TOUCH, RUN = first_touch(run), run
    arm_class = touching_arm_class()
    ahrm_stack.sim_arm.SimArm = arm_class  # deploy_sim imports it from there at call time
    argv = ["--backend", "sim", "--fast", "--duration", str(duration), "--rate", str(RATE_HZ),
            "--seed", str(run), "--telemetry", telemetry]
    if run % 2:
        argv += ["--checkpoint", str(POLICY)]
    code = deploy.main(argv)
    logging.disable(logging.CRITICAL)
    arm = arm_class.instance
    Path(result).write_text(json.dumps({
        "code": code, "frames": arm.frames, "held_at_release": arm.held_at_release,
        "violations": arm.violations, "velocity_limit": arm.velocity_limit.tolist(),
        "guard_failures": scene.GUARD.failures, "guard_normals": scene.GUARD.normals,
        "guard_error": scene.GUARD.last_error}))
    return code


def deploy_touching(run: int, duration: float, folder: Path, timeout: float = 1200.0) -> dict:
    """Run one touching deploy in a child process; the checks' inputs, as a dict."""
    telemetry, result = folder / f"touching{run}.jsonl", folder / f"touching{run}.json"
    try:
        process = subprocess.run(
            [sys.executable, str(Path(__file__).resolve()), "--child", "--run", str(run),
             "--duration", str(duration), "--telemetry", str(telemetry), "--result", str(result)],
            cwd=ROOT, capture_output=True, text=True, timeout=timeout,
            env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
        returncode, stderr = process.returncode, process.stderr[-2000:]
    except subprocess.TimeoutExpired:  # killed: a hang, or a machine too loaded to finish
        returncode, stderr = None, f"no exit within {timeout:g} s"
    outcome = {"run": run, "controller": "policy" if run % 2 else "scripted",
               "returncode": returncode, "stderr": stderr}
    if result.is_file():
        outcome.update(json.loads(result.read_text()))
    lines = ([json.loads(line) for line in telemetry.read_text().splitlines()]
             if telemetry.is_file() else [])
    ticks = [line for line in lines if "latency_ms" in line]
    stops = [line for line in lines if line.get("event") in ("stop", "emergency stop")]
    outcome["ticks"] = len(ticks)
    outcome["stop_reason"] = stops[-1]["reason"] if stops else None
    outcome["stop_event"] = bool(stops)
    outcome["summary"] = bool(lines) and "summary" in lines[-1]
    limit = np.asarray(outcome.get("velocity_limit", [np.inf]))
    outcome["out_of_limits"] = sum(
        1 for t in ticks if not (np.isfinite(t["u"]).all() and (np.abs(t["u"]) <= limit).all()))
    outcome["obstacle_rows_active"] = sum(
        1 for t in ticks if any(name.startswith("obstacle:") and name.endswith(f"obstacle_{OBSTACLE}")
                                for name in t["active"]))
    return outcome


def check(outcome: dict) -> list[str]:
    """The failed checks of one run (empty: all passed)."""
    code = outcome["returncode"]
    failed = []
    if code is None:
        failed.append("the child did not exit in time")
    elif code < 0:
        failed.append(f"killed by signal {signal.Signals(-code).name}")
    elif code not in (0, 1):
        failed.append(f"exit code {code} (3: a software fault)")
    if not outcome.get("frames"):
        failed.append("no touching frame was fed")
    if not outcome["stop_event"]:
        failed.append("no stop event in the telemetry")
    if not outcome["summary"]:
        failed.append("the telemetry does not end with the summary")
    held = outcome.get("held_at_release")
    if held is None or any(v != 0.0 for v in held):
        failed.append(f"the arm held {held} when the loop let go")
    if outcome["out_of_limits"] or outcome.get("violations", 1):
        failed.append(f"{outcome['out_of_limits']} commands outside the limits, "
                      f"{outcome.get('violations')} sim violations")
    return failed


def test_touching_perception_frames_end_in_a_recorded_stop(tmp_path):
    for run in (0, 1):  # the scripted controller, then the committed policy
        outcome = deploy_touching(run, duration=0.25, folder=tmp_path)
        assert not check(outcome), (check(outcome), outcome)
        touching = [f for f in outcome["frames"] if abs(f["distance"] - f["gap"]) <= 1e-6]
        assert len(touching) == len(outcome["frames"])  # the distance layer saw each touch


def test_an_abort_fails_the_check():
    """The harness sees what it is for: a child killed by SIGABRT (python-fcl's uncaught C++
    exception) fails, and so does one that left no stop or summary."""
    healthy = {"returncode": 1, "frames": [{}], "stop_event": True, "summary": True,
               "held_at_release": [0.0] * 6, "out_of_limits": 0, "violations": 0}
    assert check(healthy) == []
    aborted = {"returncode": -signal.SIGABRT, "stop_event": False, "summary": False,
               "out_of_limits": 0}
    assert "killed by signal SIGABRT" in check(aborted)
    assert len(check(aborted)) == 6  # and no frames, stop, summary, held command, violation count


def _measure(runs: int, duration: float, jobs: int) -> int:
    import tempfile

    from concurrent.futures import ThreadPoolExecutor

    total_frames, failures, aborts = 0, 0, 0
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(jobs) as pool:
        outcomes = pool.map(lambda run: deploy_touching(run, duration, Path(tmp)), range(runs))
        for run, o in enumerate(outcomes):
            failed = check(o)
            failures += bool(failed)
            aborts += o["returncode"] is not None and o["returncode"] < 0
            frames = o.get("frames", [])
            total_frames += len(frames)
            gaps = [f["distance"] for f in frames]
            parts = sorted({f["part"] for f in frames})
            start_up = sum(1 for f in frames if f["call"] == 0)
            print(f"run {run} ({o['controller']}): rc {o['returncode']}, {len(frames)} touching "
                  f"frames ({start_up} at start-up) from call {first_touch(run)} on {parts}, "
                  f"{o['ticks']} ticks, "
                  f"obstacle row active in {o['obstacle_rows_active']}, coal distance "
                  f"{min(gaps, default=np.nan):.2e}..{max(gaps, default=np.nan):.2e} m, guard "
                  f"{o.get('guard_failures')} failures / {o.get('guard_normals')} normals; stop: "
                  f"{o['stop_reason']}; held at release {o.get('held_at_release')}; "
                  f"{'OK' if not failed else 'FAILED: ' + '; '.join(failed)}")
            if failed:
                print(o["stderr"], file=sys.stderr)
    print(f"{runs} deploy runs fed {total_frames} touching perception frames (gaps {GAPS} m): "
          f"process aborts (signal return codes) {aborts}/{runs}; {runs - failures}/{runs} "
          "passed every check")
    return 1 if failures else 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="deploy runs (seeds 0..)")
    parser.add_argument("--duration", type=float, default=1.5, help="s per run (fast clock)")
    parser.add_argument("--jobs", type=int, default=1, help="child processes at once")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--run", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--telemetry", help=argparse.SUPPRESS)
    parser.add_argument("--result", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        sys.exit(child(args.run, args.duration, args.telemetry, args.result))
    sys.exit(_measure(args.runs, args.duration, args.jobs))
