"""Can a joint-torque threshold tell contact from motion? The feedback torques of sim deploy runs.

    MUJOCO_GL=egl python studies/contact_torques.py [RUN_DIR] [--realism NAME] [--episodes N]

Runs the policy of ``RUN_DIR`` (default: the committed ``docs/policies/ahrm-default-seed0``; ``scripted``:
the scripted controller) through the deploy loop on the sim backend, unpaced, on episodes of the
``robustness`` seed family, and prints per episode and joint: the largest torque magnitude the
feedback reported (N·m; the sim's velocity actuators' forces) and the largest change of a torque from
the mean of the 5 ticks before the last (the model-free contact detector's statistic, at 20 Hz).
Issue 58 item 4 asks for a contact stop; this measures whether one without a dynamics model could
work: if normal pushing moves the statistic as far as a contact would, it cannot.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python studies/contact_torques.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", nargs="?", default=str(ROOT / "docs" / "policies" / "ahrm-default-seed0"))
    parser.add_argument("--realism", default="ideal")
    parser.add_argument("--episodes", type=int, default=4)
    args = parser.parse_args(argv)
    from ahrm_stack.deploy.run import load_controller_config
    from ahrm_stack.deploy.session import DeploySession
    from ahrm_stack.deploy.settings import load_deploy_settings
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm
    from ahrm_stack.hardware.wrapper import ArmWrapper
    from ahrm_stack.realism import realism_profiles
    from ahrm_stack.seeds import seed_table

    logging.disable(logging.WARNING)

    class Recording(ArmWrapper):
        def __init__(self, arm):
            super().__init__(arm)
            self.torques: list[np.ndarray] = []

        def refresh_feedback(self):
            frame = self.arm.refresh_feedback()
            self.torques.append(np.array(frame.torque))
            return frame

    checkpoint = None if args.run == "scripted" else Path(args.run)
    config, actor = load_controller_config(checkpoint)
    settings = load_deploy_settings(realtime=False, telemetry="", duration=15.0)
    seeds = [seed_table()["robustness"].seed(i) for i in range(args.episodes)]
    sim = SimArm(config.task, seed=seeds[0], clock=FastClock(), realism=realism_profiles()[args.realism])
    arm = Recording(sim)
    session = DeploySession.open(arm, config, actor, settings, world_seed=0)
    for seed in seeds:
        session.reset_sim(seed, sim)
        arm.torques = []
        session.run(settings.duration)
        torque = np.array(arm.torques)
        change = np.array([torque[t] - torque[max(0, t - 6):t - 1].mean(axis=0) for t in range(2, len(torque))])
        print(json.dumps({"seed": seed, "success": bool(sim.truth.success), "touched": bool(sim.truth.touched),
                          "ticks": len(torque), "largest_torque": np.abs(torque).max(axis=0).round(2).tolist(),
                          "largest_change": np.abs(change).max(axis=0).round(2).tolist()}))
    arm.disconnect()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
