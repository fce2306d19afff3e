"""The command line: ``python -m ahrm_stack.deploy --backend sim [...]`` (:func:`main`)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path
from typing import Sequence

from ahrm_stack.config import ConfigError
from ahrm_stack.deploy.loop import DeployFault, DeployLoop
from ahrm_stack.deploy.run import deploy_sim
from ahrm_stack.deploy.settings import (DEPLOY_CONFIG, DeployConfigError, DeploySettings,
                                        load_deploy_settings)

#: ``--backend`` choices; :func:`run_backend` runs each.
BACKENDS = ("sim",)


def run_backend(backend: str, settings: DeploySettings, checkpoint: Path | None,
                overrides: Sequence[str]) -> DeployLoop:
    """One deploy run on the arm adapter named ``backend`` (one of :data:`BACKENDS`): the one
    place the command line chooses a backend. Raises what :func:`~ahrm_stack.deploy.run.deploy_run`
    raises."""
    if backend == "sim":
        return deploy_sim(settings, checkpoint, overrides)
    raise DeployConfigError(f"--backend {backend!r} is not one of {list(BACKENDS)}")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = _Parser(prog="python -m ahrm_stack.deploy",
                     description="Run the deployment loop (policy or scripted controller → safety "
                                 "filter → arm adapter).")
    parser.add_argument("--backend", choices=list(BACKENDS), required=True,
                        help="arm adapter (the kortex backend has no perception module yet)")
    parser.add_argument("--checkpoint", type=Path, help="run folder with config.yaml and policy.pt "
                        "(default: the scripted controller)")
    parser.add_argument("--duration", type=float, help="s (default: deploy.yaml)")
    parser.add_argument("--rate", type=float, dest="rate_hz", help="loop rate, Hz (default: deploy.yaml)")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--realtime", dest="realtime", action="store_const", const=True,
                      help="pace to the wall clock")
    pace.add_argument("--fast", dest="realtime", action="store_const", const=False,
                      help="as fast as possible (sim only)")
    parser.add_argument("--seed", type=int, help="sim layout seed (default: deploy.yaml)")
    parser.add_argument("--telemetry", help="JSONL log path ('' for none; default: deploy.yaml)")
    parser.add_argument("--config", type=Path, default=DEPLOY_CONFIG, help="deploy settings YAML")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides without --checkpoint, e.g. task.robot=j2s6s200")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("ahrm_stack.env.runner").setLevel(logging.ERROR)  # the sim filters nothing:
    # by design, the deploy loop does
    try:
        settings = load_deploy_settings(args.config, rate_hz=args.rate_hz, duration=args.duration,
                                        realtime=args.realtime, seed=args.seed,
                                        telemetry=args.telemetry)
    except DeployConfigError as error:
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2

    def terminate(signum, frame):  # SIGTERM stops the arm like Ctrl-C
        raise KeyboardInterrupt

    from ahrm_stack.learning.checkpoint import CheckpointError

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        loop = run_backend(args.backend, settings, args.checkpoint, args.overrides)
    except (ConfigError, DeployConfigError, CheckpointError) as error:  # before anything moved
        print(f"python -m ahrm_stack.deploy: error: {error}", file=sys.stderr)
        return 2
    except DeployFault as error:  # the arm was stopped; the stop and the summary are recorded
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

