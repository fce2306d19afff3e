"""One deploy-session factory (issue 57, item 5): every deploy episode in the package, the studies and
the benchmarks is a DeploySession's loop, and a session runs episode after episode on one arm."""

from pathlib import Path

from ahrm_stack.config import load_config
from ahrm_stack.deploy import PolicyController, ScriptedController, load_controller_config, load_deploy_settings
from ahrm_stack.deploy.session import DeploySession
from ahrm_stack.hardware.protocol import FastClock
from ahrm_stack.sim_arm import SimArm

ROOT = Path(__file__).resolve().parents[1]


def test_no_one_else_builds_a_deploy_loop():
    sources = [p for folder in ("ahrm_stack", "benchmarks", "studies", "tools")
               for p in (ROOT / folder).rglob("*.py")]
    builders = [str(p.relative_to(ROOT)) for p in sources if "DeployLoop(" in p.read_text()]
    assert builders == ["ahrm_stack/deploy/session.py"], builders


def test_a_session_runs_episodes_one_after_another():
    config = load_config()
    settings = load_deploy_settings(realtime=False, telemetry="", duration=0.5)
    arm = SimArm(config.task, seed=0, clock=FastClock())
    session = DeploySession.open(arm, config, None, settings)
    assert isinstance(session.controller, ScriptedController)
    arm.connect()
    try:
        ticks = []
        for seed in (0, 1):
            arm.reset_scene(seed)
            loop = session.loop()
            ticks.append(loop.run(settings.duration).ticks)
        assert ticks[0] == ticks[1] > 0
    finally:
        arm.disconnect()
    policy_config, actor = load_controller_config(ROOT / "docs" / "policies" / "ahrm-default-seed0")
    assert isinstance(DeploySession.open(arm, policy_config, actor, settings).controller, PolicyController)
