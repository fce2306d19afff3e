"""The policy's forward pass per call: TorchRL's module stack against the lean plain-torch path.

Same weights (the committed policy in docs/policies/, or a fresh actor of the configured size),
single observations as in collection, evaluation and deploy:

* TorchRL actor, deterministic: ``ProbabilisticActor`` on a TensorDict under
  ``ExplorationType.DETERMINISTIC`` (evaluation and deploy before the lean path);
* TorchRL actor, random: the same under ``ExplorationType.RANDOM`` (what the Collector runs per
  collected frame: the action is sampled and its log-probability computed);
* lean, TensorDict: :class:`~ahrm_stack.learning.ppo.LeanActor` called with a TensorDict (what
  ``load_policy`` / ``run_episodes`` now use);
* lean, tensor: ``LeanActor.act`` on the observation tensor (no TensorDict at all);
* deploy: :class:`~ahrm_stack.deploy.policy.NumpyPolicy` on the float64 observation array (what the
  deploy loop's policy controller runs: frozen float32 weights, preallocated buffers, no torch).

Then collection as training runs it: a TorchRL ``Collector`` over the environment with the TorchRL
actor against one with :class:`~ahrm_stack.learning.ppo.LeanCollectionActor` (same keys, same
sampled actions for the same seed), frames per second, interleaved batches.

Prints per-call median (us), the ratios to the deterministic TorchRL actor, and the largest action
difference between the lean and the TorchRL deterministic action (goal: <= 1e-6) and between
NumpyPolicy and the lean action (goal: <= 1e-5, float32 rounding in another summation order).
Usage: python benchmarks/bench_policy.py [--calls N] [--checkpoint RUN [--policy-file PT]] [--quick]
"""

from __future__ import annotations

import time
from pathlib import Path

from ahrm_stack import cli

cli.quiet_argv()  # before the heavy imports: the libraries' warnings and INFO logs unless --verbose

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torchrl.envs.utils import ExplorationType, set_exploration_type  # noqa: E402

from _scripted import quick_parser  # noqa: E402
from ahrm_stack.config import load_config  # noqa: E402
from ahrm_stack.deploy.policy import NumpyPolicy  # noqa: E402
from ahrm_stack.learning.ppo import lean_actor, lean_collection_actor, make_modules  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CHECKPOINT = ROOT / "docs" / "policies" / "ahrm-default-seed0"


def collection_rates(config, actor, frames: int, batches: int) -> tuple[float, float]:
    """Frames/s of a Collector with the TorchRL actor and with its lean collection actor."""
    import logging

    from torchrl.collectors import Collector

    from ahrm_stack.env.torchrl_env import PushOffEnv

    logging.getLogger("ahrm_stack").setLevel(logging.ERROR)
    rates = {}
    iterators = {}
    for name, policy in (("torchrl", actor), ("lean", lean_collection_actor(actor))):
        env = PushOffEnv(config.task, config.safety, seed=1)
        collector = Collector(env, policy, frames_per_batch=frames, total_frames=-1,
                              exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False)
        iterators[name] = (collector, iter(collector))
        next(iterators[name][1])  # warm-up
        rates[name] = 0.0
    for _ in range(batches):
        for name, (_, it) in iterators.items():
            start = time.perf_counter()
            next(it)
            rates[name] += time.perf_counter() - start
    for collector, _ in iterators.values():
        collector.shutdown()
    return frames * batches / rates["torchrl"], frames * batches / rates["lean"]


def load_actor(checkpoint: Path | None, policy_file: Path | None = None):
    """(actor, observation dim, where from, config): the checkpoint's TorchRL actor (its
    ``policy.pt`` or ``policy_file``; in its lane frame if it has one), or a fresh one."""
    policy_file = policy_file or (None if checkpoint is None else checkpoint / "policy.pt")
    if checkpoint is not None and policy_file is not None and policy_file.exists():
        from ahrm_stack.learning.checkpoint import load
        from ahrm_stack.learning.lane_frame import lane_mirror_for
        from ahrm_stack.run_config import load_run_config

        config = load_run_config(checkpoint)
        saved = load(policy_file)
        dims = saved["observation_dim"], saved["action_dim"]
        modules = make_modules(config.ppo, *dims, lane_mirror_for(config, *dims))
        modules.actor.load_state_dict(saved["actor"])
        frame = "" if config.ppo.lane_frame == "none" else f", lane frame {config.ppo.lane_frame}"
        return modules.actor.eval(), dims[0], f"{policy_file.resolve().relative_to(ROOT)}{frame}", config
    config = load_config()
    from ahrm_stack.env.torchrl_env import PushOffEnv

    obs_dim = PushOffEnv(config.task, config.safety).observation_spec["observation"].shape[-1]
    modules = make_modules(config.ppo, obs_dim, 3 if config.task.action.mode == "cartesian" else 5)
    modules.normalizer.update(torch.randn(256, obs_dim))
    return modules.actor.eval(), obs_dim, "a fresh actor of the configured size", config


def per_call(fn, observations: torch.Tensor) -> np.ndarray:
    times = np.empty(len(observations))
    for i, obs in enumerate(observations):
        start = time.perf_counter()
        fn(obs)
        times[i] = time.perf_counter() - start
    return times


def main() -> None:
    parser = quick_parser(__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="calls per variant (default 2000)")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--policy-file", type=Path, default=None,
                        help="a policy of the checkpoint run other than its policy.pt")
    parser.add_argument("--frames", type=int, default=200, help="frames per collected batch (default 200)")
    parser.add_argument("--batches", type=int, default=3, help="batches per collector (default 3)")
    args = parser.parse_args()
    if args.quick:
        args.calls, args.frames, args.batches = 50, 20, 1
    torch.set_num_threads(1)
    actor, obs_dim, source, config = load_actor(args.checkpoint, args.policy_file)
    lean = lean_actor(actor)
    observations = torch.randn(args.calls, obs_dim) * 2.0

    def torchrl(mode):
        def call(obs):
            with torch.no_grad(), set_exploration_type(mode):
                return actor(TensorDict({"observation": obs}, batch_size=[]))["action"]
        return call

    numpy_policy = NumpyPolicy.from_actor(actor)
    arrays = observations.double().numpy()  # what deploy's world model gives (float64)
    variants = {
        "TorchRL actor, deterministic": (torchrl(ExplorationType.DETERMINISTIC), observations),
        "TorchRL actor, random (Collector)": (torchrl(ExplorationType.RANDOM), observations),
        "lean, TensorDict": (lambda obs: lean(TensorDict({"observation": obs}, batch_size=[]))["action"],
                             observations),
        "lean, tensor (.act)": (lean.act, observations),
        "deploy, NumpyPolicy (numpy array)": (numpy_policy, arrays),
    }
    for fn, inputs in variants.values():  # warm-up
        per_call(fn, inputs[:20])
    medians = {}
    for _ in range(3):  # interleaved rounds: machine noise hits all alike
        for name, (fn, inputs) in variants.items():
            t = np.median(per_call(fn, inputs)) * 1e6
            medians[name] = min(medians.get(name, np.inf), t)
    base = medians["TorchRL actor, deterministic"]
    print(f"policy forward pass per call, {source}, {args.calls} single observations, 1 thread")
    for name, t in medians.items():
        print(f"  {name:34s}: {t:8.1f} us   ratio to the TorchRL deterministic actor {base / t:5.1f}x")
    batch = lean.act(observations)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        ref = actor(TensorDict({"observation": observations}, batch_size=[len(observations)]))["action"]
    diff = float((batch - ref).abs().max())
    print(f"  max |lean - TorchRL deterministic action| over {len(observations)} observations: {diff:.2g} "
          f"(goal <= 1e-6: {'met' if diff <= 1e-6 else 'NOT met'})")
    if diff > 1e-6:
        raise SystemExit("the lean path's action differs")
    numpy_diff = max(float(np.abs(numpy_policy(row) - lean.act(torch.as_tensor(row, dtype=torch.float32))
                                  .numpy()).max()) for row in arrays)
    print(f"  max |NumpyPolicy - lean action| (single observations): {numpy_diff:.2g} (goal <= 1e-5, "
          f"float32 rounding: {'met' if numpy_diff <= 1e-5 else 'NOT met'})")
    if numpy_diff > 1e-5:
        raise SystemExit("deploy's NumPy policy's action differs")
    slow, fast = collection_rates(config, actor, args.frames, args.batches)
    print(f"collection (Collector, {args.batches} x {args.frames} frames): TorchRL actor {slow:6.0f} frames/s "
          f"({1e6 / slow:6.0f} us/frame), lean collection actor {fast:6.0f} frames/s ({1e6 / fast:6.0f} us/frame); "
          f"ratio lean/TorchRL {fast / slow:.2f}")


if __name__ == "__main__":
    main()
