"""The command line: ``python -m ahrm_stack.deploy --backend sim|kinova-gen2|kortex [...]``
(:func:`main`)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path
from typing import Sequence

from ahrm_stack.cli import Parser
from ahrm_stack.config import ConfigError
from ahrm_stack.deploy.loop import DeployFault, DeployLoop
from ahrm_stack.deploy.run import deploy
from ahrm_stack.deploy.settings import (DEPLOY_CONFIG, DeployConfigError, DeploySettings,
                                        load_deploy_settings)
from ahrm_stack.deploy.bring_up import check_link, home_arm
from ahrm_stack.deploy.start_check import StartPostureError
from ahrm_stack.deploy.backends import BACKENDS


def run_backend(backend: str, settings: DeploySettings, checkpoint: Path | None,
                overrides: Sequence[str], scene: str = "sim",
                layout_file: Path | None = None, policy_file: Path | None = None,
                dry_run: bool = False) -> DeployLoop:
    """One deploy run on the arm adapter named ``backend`` (one of
    :data:`ahrm_stack.deploy.backends.BACKENDS`) with object poses from ``scene``: the one place the
    command line chooses them. Raises what :func:`~ahrm_stack.deploy.run.deploy` raises."""
    return deploy(settings, checkpoint, overrides, backend=backend, scene=scene,
                  layout_file=layout_file, policy_file=policy_file, dry_run=dry_run)


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = Parser(prog="python -m ahrm_stack.deploy",
                     description="Run the deployment loop (policy or scripted controller → safety "
                                 "filter → arm adapter).")
    parser.add_argument("--backend", choices=list(BACKENDS), required=True,
                        help="arm adapter: " + "; ".join(f"{b.name}: {b.help}"
                                                         for b in BACKENDS.values()))
    parser.add_argument("--checkpoint", type=Path, help="run folder with config.yaml and policy.pt "
                        "(default: the scripted controller)")
    parser.add_argument("--policy-file", type=Path, metavar="PT", help="with --checkpoint: another "
                        "policy of that run, e.g. RUN/policies/episode-N.pt (default: RUN/policy.pt)")
    parser.add_argument("--duration", type=float, help="s (default: deploy.yaml)")
    parser.add_argument("--rate", type=float, dest="rate_hz", help="loop rate, Hz (default: deploy.yaml)")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--realtime", dest="realtime", action="store_const", const=True,
                      help="pace to the wall clock")
    pace.add_argument("--fast", dest="realtime", action="store_const", const=False,
                      help="as fast as possible (sim only)")
    parser.add_argument("--seed", type=int, help="sim layout seed (default: deploy.yaml)")
    parser.add_argument("--realism", metavar="NAME", help="sim backend: the arm's and camera's "
                        "imperfections, a set of configs/realism.yaml (ideal, jaco2; default: deploy.yaml)")
    parser.add_argument("--telemetry", help="JSONL log path ('' for none; default: deploy.yaml)")
    parser.add_argument("--config", type=Path, default=DEPLOY_CONFIG, help="deploy settings YAML")
    parser.add_argument("--scene", choices=["sim", "camera"], default="sim",
                        help="object poses: the simulator's (sim) or the AprilTag camera's for the "
                             "cube and a measured layout file for the obstacles (camera; "
                             "configs/perception.yaml: source.kind sim renders the simulator, "
                             "video/uvc/realsense a real frame source, any backend)")
    parser.add_argument("--layout-file", type=Path, help="with --scene camera: the measured obstacle "
                        "layout (default: perception.layout_file, else surveyed from the sim)")
    parser.add_argument("--check", action="store_true",
                        help="measure the link to the arm and say whether its budget fits at the "
                             "configured rates, with the arm held still, then exit (kinova-gen2: each "
                             "SDK call's USB latency; kortex: the per-tick RPCs against the send "
                             "deadline, the arm's model, soft limits and protection zones; exit 0 fits, "
                             "1 does not, 3 no arm)")
    parser.add_argument("--home", action="store_true",
                        help="kinova-gen2, kortex: move the arm to the posture the policy was trained "
                             "from (kinova-gen2: MoveHome, then a slow joint move, kinova_gen2.home; "
                             "kortex: one slow ReachJointAngles action, kortex.home), after a "
                             "confirmation, then exit (0 there, 1 not confirmed, 2 bad input, "
                             "3 stopped, 130 Ctrl-C)")
    parser.add_argument("--touch-off", action="store_true",
                        help="kinova-gen2: jog the pusher tip onto three table points "
                             "(kinova_gen2.touch_off) and compare forward kinematics with the model's "
                             "table, writing the record a deploy run checks (0 passed, 1 failed or not "
                             "confirmed, 2 bad input, 3 stopped, 130 Ctrl-C)")
    parser.add_argument("--dry-run", action="store_true",
                        help="the arm's real feedback and scene, every command computed, filtered and "
                             "logged, none sent (stops still are): the arm never moves")
    parser.add_argument("--yes", action="store_true",
                        help="with --home: confirm without asking (scripted use)")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides without --checkpoint, e.g. task.robot=j2s6s200")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    from ahrm_stack.cli import quiet_argv

    args = _parse(quiet_argv(argv))  # --verbose: the libraries' warnings and INFO logs too
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("ahrm_stack.env.runner").setLevel(logging.ERROR)  # the sim filters nothing:
    # by design, the deploy loop does
    try:
        settings = load_deploy_settings(args.config, rate_hz=args.rate_hz, duration=args.duration,
                                        realtime=args.realtime, seed=args.seed,
                                        telemetry=args.telemetry, realism=args.realism)
    except DeployConfigError as error:
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2

    def terminate(signum, frame):  # SIGTERM stops the arm like Ctrl-C
        raise KeyboardInterrupt

    if args.dry_run and (args.check or args.home or args.touch_off):
        print("python -m ahrm_stack.deploy: error: --dry-run runs the loop; --check, --home and --touch-off "
              "are separate steps", file=sys.stderr)
        return 2
    if args.check + args.home + args.touch_off > 1:
        print("python -m ahrm_stack.deploy: error: --check, --home and --touch-off are separate steps; give one",
              file=sys.stderr)
        return 2
    if args.yes and not args.home:
        print("python -m ahrm_stack.deploy: error: --yes confirms --home; give --home too",
              file=sys.stderr)
        return 2
    if args.home or args.touch_off:
        previous = signal.signal(signal.SIGTERM, terminate)
        try:
            return home_arm(args.backend, settings, args.checkpoint, args.overrides,
                            args.policy_file, args.yes, touch_off=args.touch_off)
        finally:
            signal.signal(signal.SIGTERM, previous)

    if args.check:
        previous = signal.signal(signal.SIGTERM, terminate)
        try:
            return check_link(args.backend, settings, args.checkpoint, args.overrides, args.policy_file)
        finally:
            signal.signal(signal.SIGTERM, previous)

    from ahrm_stack.learning.checkpoint import CheckpointError

    if args.scene == "camera":  # offscreen rendering: MUJOCO_GL must be chosen before mujoco loads
        from ahrm_stack.config import VideoConfig, load_extra
        from ahrm_stack.env.video import RenderError, select_gl_backend
        from ahrm_stack.perception.settings import load_perception_settings

        try:
            if load_perception_settings().source.kind == "sim":
                select_gl_backend(load_extra(VideoConfig, "video").gl_backends)
        except (RenderError, ConfigError) as error:
            print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
            return 2
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        loop = run_backend(args.backend, settings, args.checkpoint, args.overrides, args.scene,
                           args.layout_file, args.policy_file, args.dry_run)
    except (ConfigError, DeployConfigError, CheckpointError) as error:  # before anything moved
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2
    except DeployFault as error:  # the arm was stopped; the stop and the summary are recorded
        if isinstance(error.__cause__, StartPostureError):  # refused before any command
            print(f"python -m ahrm_stack.deploy: error: {error.__cause__}", file=sys.stderr)
            return 2
        print(error.summary)
        print(f"python -m ahrm_stack.deploy: error: the arm was stopped on a fault: {error}",
              file=sys.stderr)
        return 3
    except KeyboardInterrupt:  # during set-up, before the arm moved
        print("interrupted before the loop started", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    summary = loop.summary()
    print(summary)
    if loop.interrupted:
        return 130
    return 0 if summary.success else 1

