"""A deploy run beside the simulator's prediction: ``python -m ahrm_stack.deploy.replay RECORD``.

``RECORD`` is a run's telemetry (``.jsonl``) or its MCAP twin (``.mcap``; :mod:`.record`), from any
backend. The simulator (the sim backend, :class:`~ahrm_stack.sim_arm.SimArm`, with the task of
``--checkpoint`` or of ``configs/`` and the imperfections of ``--realism``, none by default) starts
from the run's first tick (the joint angles read, the cube and obstacles where they were perceived,
at rest) and is sent the run's commands open loop, each at the time it was sent (``sent_t``). At
every tick the predicted joint angles are set beside the recorded ones: per joint the RMS and
largest difference, printed, and with ``--out`` a figure (recorded against predicted, per joint,
over time).

What the difference shows: for a sim run without imperfections, the simulator's reproducibility
(~0); for a real arm, how far the training physics is from the arm under the same commands (lag,
latency, friction, a tool or payload the model lacks). Bad input is one line, exit 2.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from ahrm_stack.deploy.record import RunRecord, read_run


@dataclasses.dataclass
class Replay:
    """``times`` (s, the ticks' feedback stamps), ``recorded`` and ``predicted`` joint angles
    (ticks × joints, rad) of ``joint_names``, and the cube's recorded and predicted positions at
    the last tick (m)."""

    joint_names: tuple[str, ...]
    times: np.ndarray
    recorded: np.ndarray
    predicted: np.ndarray
    cube_recorded: np.ndarray
    cube_predicted: np.ndarray

    @property
    def rms(self) -> np.ndarray:
        return np.sqrt(np.mean((self.recorded - self.predicted) ** 2, axis=0))

    @property
    def largest(self) -> np.ndarray:
        return np.max(np.abs(self.recorded - self.predicted), axis=0)


def replay(record: RunRecord, task_config, realism=None) -> Replay:
    """The run ``record`` sent open loop to a simulated arm of ``task_config`` with ``realism``
    (a :class:`~ahrm_stack.realism.RealismConfig`; None: none); see the module docstring."""
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    ticks = record.ticks
    if not ticks:
        raise ValueError("the record has no tick: nothing to replay")
    if any(event.get("event") == "dry run" for event in record.events):
        raise ValueError("the record is of a dry run: its commands were never sent, so the arm did not "
                         "follow them; replay a live run")
    arm = SimArm(task_config, clock=FastClock(), realism=realism)
    arm.connect()
    first = ticks[0]
    arm.set_state(np.asarray(first["q"]), np.asarray(first["cube"]), np.asarray(first["obstacles"]))
    start = arm.clock.now() - float(first["feedback_t"])
    predicted, cube = [], np.asarray(first["cube"][:3], dtype=float)
    try:
        for tick in ticks:
            arm.clock.sleep_until(start + float(tick["feedback_t"]))
            predicted.append(arm.refresh_feedback().position)
            cube = arm.perception().cube_position
            arm.clock.sleep_until(start + float(tick["sent_t"]))
            arm.send_joint_speeds(np.asarray(tick["u"], dtype=float))
    finally:
        arm.disconnect()
    return Replay(joint_names=tuple(arm.joint_names), times=np.array([float(t["feedback_t"]) for t in ticks]),
                  recorded=np.array([t["q"] for t in ticks], dtype=float), predicted=np.array(predicted),
                  cube_recorded=np.asarray(ticks[-1]["cube"][:3], dtype=float), cube_predicted=cube)


def plot(result: Replay, out: Path) -> None:
    """Recorded against predicted joint angles over time, one panel per joint, into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = result.recorded.shape[1]
    fig, grid = plt.subplots(n, 1, figsize=(7, 1.6 * n), sharex=True, squeeze=False)
    axes = list(grid[:, 0])
    for i, ax in enumerate(axes):
        ax.plot(result.times, np.degrees(result.recorded[:, i]), label="recorded")
        ax.plot(result.times, np.degrees(result.predicted[:, i]), "--", label="simulator")
        ax.set_ylabel(f"{result.joint_names[i]}\n(deg)", fontsize=8)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("time since the run's start (s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    from ahrm_stack.cli import Parser, add_verbose_flag, quiet

    parser = Parser(prog="python -m ahrm_stack.deploy.replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("record", type=Path, help="a run's telemetry (.jsonl) or its MCAP twin (.mcap)")
    parser.add_argument("--checkpoint", type=Path, default=None,
                        help="the run whose task the arm ran (default: configs/)")
    parser.add_argument("--realism", default="ideal",
                        help="the simulator's imperfections: a set of configs/realism.yaml (default ideal)")
    parser.add_argument("--out", type=Path, default=None, help="a figure (PNG) of the comparison")
    add_verbose_flag(parser)
    args = parser.parse_args(argv)
    quiet(args.verbose)
    from ahrm_stack.config import ConfigError
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.realism import realism_profiles

    try:
        record = read_run(args.record)
        profiles = realism_profiles()
        if args.realism not in profiles:
            raise ValueError(f"--realism {args.realism!r}: choose one of {sorted(profiles)} (configs/realism.yaml)")
        config, _ = load_controller_config(args.checkpoint)
        result = replay(record, config.task, profiles[args.realism])
    except (ValueError, ConfigError, OSError, KeyError) as error:
        print(f"error: {(str(error).splitlines() or [''])[0]}", file=sys.stderr)
        return 2
    names = result.joint_names
    print(f"replay of {args.record} ({len(record.ticks)} ticks, {result.times[-1]:.2f} s) in the simulator "
          f"(realism {args.realism}): joint angle, recorded - predicted")
    for i, name in enumerate(names):
        print(f"  {name:>12}: RMS {np.degrees(result.rms[i]):7.3f} deg, "
              f"largest {np.degrees(result.largest[i]):7.3f} deg")
    off = np.linalg.norm(result.cube_recorded - result.cube_predicted)
    print(f"  cube at the last tick: perceived {np.round(result.cube_recorded, 3).tolist()} m, predicted "
          f"{np.round(result.cube_predicted, 3).tolist()} m ({off * 1e3:.1f} mm apart)")
    if args.out is not None:
        plot(result, args.out)
        print(f"figure: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
