"""The cost of running ``kortex_api`` in its own process: one ``RefreshFeedback`` (the plain-valued
frame of a 6-joint arm) and one ``SendJointSpeedsCommand`` through the child-process link
(ahrm_stack/hardware/kortex/child_link.py: a JSON line each way over a pipe) against the same call on the same
vendor code in this process (ahrm_stack/hardware/kortex/vendor_link.py), both on the fake ``kortex_api``
(tests/fake_kortex_api; its simulated arm answers at once, so the figures are the link's own
overhead, without the network's round trip to a real arm).

Prints per-call medians and 99th percentiles, and the ratio child/direct of the medians; the
difference is what the pipe adds to each call of the 20 Hz control loop (50 ms per period).
Usage: python benchmarks/bench_kortex_link.py [--calls N] [--quick]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from fake_kortex_api.rig import HERE, fake_api  # noqa: E402
from ahrm_stack.hardware.kortex import ChildLink, VendorLink, joint_speeds_message  # noqa: E402

JOINTS = 6
SPEC = ('{"positions_deg": [0, 180, 180, 0, 0, 0], "continuous": [true, false, false, true, true, '
        'true]}')


def _open(link) -> None:
    link.call("open", address="192.0.2.200", port=10000, username="admin", password="pw",
              session_inactivity_timeout_ms=60000, connection_inactivity_timeout_ms=2000,
              timeout_ms=3000)


def _times(link, method: str, calls: int, **args) -> list[float]:
    out = []
    for _ in range(calls):
        start = time.perf_counter()
        link.call(method, timeout_ms=1000, **args)
        out.append(time.perf_counter() - start)
    return out


def _p99(values: list[float]) -> float:
    return float(np.percentile(values, 99))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--quick", action="store_true", help="300 calls")
    args = parser.parse_args()
    calls = 300 if args.quick else args.calls
    os.environ["FAKE_KORTEX_ARM"] = SPEC  # the fake arm, in this process and in the child
    direct = VendorLink(fake_api())
    child = ChildLink(None, path=[HERE])
    speeds = joint_speeds_message(np.zeros(JOINTS))
    try:
        for link in (direct, child):
            _open(link)
            _times(link, "feedback", 50)  # warm-up
        rows = {}
        for name, link in (("direct", direct), ("child", child)):
            rows[name] = (_times(link, "feedback", calls),
                          _times(link, "joint_speeds", calls, speeds=speeds))
    finally:
        for link in (direct, child):
            link.call("close", timeout_ms=1000)
        child.shutdown()
    print(f"{calls} calls each; fake kortex_api (no network); python {sys.version.split()[0]}")
    for name, (feedback, command) in rows.items():
        print(f"{name:>6}: RefreshFeedback median {statistics.median(feedback) * 1e6:8.1f} us "
              f"p99 {_p99(feedback) * 1e6:8.1f} us | SendJointSpeedsCommand median "
              f"{statistics.median(command) * 1e6:8.1f} us p99 {_p99(command) * 1e6:8.1f} us")
    for i, what in enumerate(("RefreshFeedback", "SendJointSpeedsCommand")):
        ratio = statistics.median(rows["child"][i]) / statistics.median(rows["direct"][i])
        added = (statistics.median(rows["child"][i]) - statistics.median(rows["direct"][i])) * 1e3
        print(f"ratio child/direct {what}: {ratio:.1f} (+{added:.3f} ms per call, "
              f"{added / 50 * 100:.2f} % of a 50 ms period)")


if __name__ == "__main__":
    main()
