"""Backfill the test ledger from the test-split outputs committed before it existed.

    python tools/backfill_test_ledger.py [--write]   # prints the reads; --write appends the missing

Each ``evaluation.json`` under docs/ with ``split: test`` is one past read. Its evaluation set is
the header's ``evaluation_set`` or, for outputs written before that field, the layout whose test
range starts at its ``seed_offset`` (``run`` when none); its policy is the ``policy.pt`` committed
in the nearest folder above the output (keyed by its hash), ``scripted controller``, or, where the
policy file was never committed, ``unknown:<the path it had>``; its time is the commit that added
the file. A read already in the ledger (same set, seeds, episodes and result) is not added twice.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ahrm_stack import test_ledger  # noqa: E402
from ahrm_stack.seeds import seed_table  # noqa: E402

RESULT_KEYS = ("successes", "touched_episodes", "episodes", "time_mean")


def signature(evaluation_set: str, seed_offset: int, result: dict) -> tuple:
    """What identifies one read's outputs: its set, first seed and result."""
    return (evaluation_set, int(seed_offset), *(result.get(k) for k in RESULT_KEYS))


def _set_of(header: dict) -> str:
    if header.get("evaluation_set"):
        return header["evaluation_set"]
    tests = {name: s.test.start for name, s in seed_table().evaluation.items()}
    layout = header.get("layout")
    if layout in tests and tests[layout] == header["seed_offset"]:
        return layout
    return "run"


def _policy_file(output: Path) -> Path | None:
    for folder in [output, *output.parents]:
        if folder == ROOT / "docs":
            return None
        if (folder / "policy.pt").is_file():
            return folder / "policy.pt"
    return None


def _added(path: Path) -> str:
    done = subprocess.run(["git", "log", "--diff-filter=A", "--format=%cI", "--", str(path.relative_to(ROOT))],
                          cwd=ROOT, capture_output=True, text=True, check=True)
    lines = done.stdout.split()
    return lines[-1] if lines else ""


def past_reads() -> list[test_ledger.Read]:
    found = []
    for path in sorted((ROOT / "docs").rglob("evaluation.json")):
        header = json.loads(path.read_text())
        if header.get("split") != "test":
            continue
        output = path.parent
        result = {k: header.get(k) for k in RESULT_KEYS}
        result["output"] = str(output.relative_to(ROOT))
        if header.get("policy") == test_ledger.SCRIPTED:
            key, policy = "scripted-unknown-config", test_ledger.SCRIPTED
        else:
            named = str(header.get("policy", ""))
            committed = _policy_file(output) if not named.endswith(".pt") or named.endswith("policy.pt") else None
            if committed is not None:
                key, policy = test_ledger.policy_key(committed), str(committed.relative_to(ROOT))
            else:
                key, policy = f"unknown:{named}", named
        found.append(test_ledger.Read(key, policy, _set_of(header), int(header["seed_offset"]),
                                      int(header["episodes"]), _added(path),
                                      f"backfilled from {path.relative_to(ROOT)}", "", "", result, True))
    return sorted(found, key=lambda r: (r.time, r.result["output"]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="append the reads not yet in the ledger")
    args = parser.parse_args(argv)
    have = {signature(r.evaluation_set, r.seed_offset, r.result) for r in test_ledger.reads()}
    new = [r for r in past_reads() if signature(r.evaluation_set, r.seed_offset, r.result) not in have]
    for read in new:
        print(f"{read.time} {read.policy} {read.evaluation_set} {read.episodes} {read.result['output']}")
        if args.write:
            test_ledger.record(read)
    print(f"{len(new)} reads {'appended to' if args.write else 'missing from'} {test_ledger.ledger_path()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
