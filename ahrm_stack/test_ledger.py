"""The ledger of the sealed test split's reads: one JSON line per read, appended, never rewritten.

A read is one evaluation of one policy on one evaluation set's test seeds (``run``, or a family of
``configs/layouts.yaml``) by :mod:`ahrm_stack.evaluation`, the one module that may read the split
(:func:`ahrm_stack.seeds.evaluation_range`). A policy is keyed by the SHA-256 of its file, so a copy
or a renamed folder is the same policy. The first read of a (policy, set) pair is recorded; a
second is refused (:class:`RereadError`, before any episode runs) unless a reason is given, which
the ledger records beside it. The scripted controller is not trained or chosen on these seeds:
its reads are recorded (keyed by its config) and never refused.

The ledger is ``configs/seeds.yaml``'s ``test_ledger`` (a path in the repository, committed: the
record of which frozen policy saw the test split, when and by which command), or the file named by
the environment variable :data:`LEDGER_ENV` (the test suite's own ledger per test).

    python -m ahrm_stack.test_ledger [--policy FILE]   # the reads, or those of one policy file
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Iterator

from ahrm_stack.cli import Parser
from ahrm_stack.config import ConfigError
from ahrm_stack.paths import PROJECT_ROOT

LEDGER_ENV = "AHRM_TEST_LEDGER"  # a ledger file other than the committed one (the tests set it)
SCRIPTED = "scripted controller"  # the policy field of the scripted controller's reads


class RereadError(ConfigError):
    """A policy's second read of one evaluation set's test split, without a recorded reason."""


def ledger_path() -> Path:
    """The ledger file: :data:`LEDGER_ENV` when set, else ``configs/seeds.yaml``'s ``test_ledger``
    (relative to the project root: the repository, or for an installed wheel the working folder)."""
    override = os.environ.get(LEDGER_ENV)
    if override:
        return Path(override)
    from ahrm_stack.seeds import seed_table
    return PROJECT_ROOT / seed_table().test_ledger


def policy_key(policy_file: Path | None, config_text: str = "") -> str:
    """``sha256:<hex>`` of a policy file's bytes, or for the scripted controller (``None``) of the
    config it runs under."""
    if policy_file is None:
        return "scripted-sha256:" + hashlib.sha256(config_text.encode()).hexdigest()
    digest = hashlib.sha256()
    with open(policy_file, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return "sha256:" + digest.hexdigest()


@dataclasses.dataclass(frozen=True)
class Read:
    """One line of the ledger."""

    key: str  # policy_key: the policy file's hash (or the scripted controller's config's)
    policy: str  # the file as it was named (or SCRIPTED)
    evaluation_set: str  # run, or a family of configs/layouts.yaml
    seed_offset: int  # the first test seed
    episodes: int
    time: str  # UTC, ISO 8601, when the read was recorded
    command: str  # the command line that read it
    commit: str  # the checkout's git commit ("" outside a git checkout)
    reason: str = ""  # why a policy's re-read was allowed ("" on a first read)
    result: dict = dataclasses.field(default_factory=dict)  # successes, touched_episodes, ...
    backfilled: bool = False  # recorded from committed outputs, after the read (before the ledger)

    @property
    def scripted(self) -> bool:
        return self.policy == SCRIPTED


def reads(path: Path | None = None) -> list[Read]:
    """Every read in the ledger, oldest first ([] when it does not exist yet). A line that is not
    a read is a :class:`ConfigError` naming the file and the line."""
    path = ledger_path() if path is None else path
    if not path.is_file():
        return []
    out = []
    fields = {f.name for f in dataclasses.fields(Read)}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
            out.append(Read(**{k: v for k, v in entry.items() if k in fields}))
        except (json.JSONDecodeError, TypeError) as error:
            raise ConfigError(f"{path}:{number}: not a test-split read ({error})") from None
    return out


def check_read(key: str, evaluation_set: str, reason: str = "", scripted: bool = False) -> None:
    """Refuse (:class:`RereadError`) a policy's second read of ``evaluation_set``'s test split
    without a ``reason``. Called before any episode runs."""
    if scripted or reason.strip():
        return
    earlier = [r for r in reads() if r.key == key and r.evaluation_set == evaluation_set]
    if earlier:
        first = earlier[0]
        raise RereadError(f"the test split of '{evaluation_set}' was already read for this policy "
                          f"({first.policy}, {first.time}, by: {first.command}); a frozen policy is read "
                          f"once. Give --reason TEXT to read it again (recorded in {ledger_path()})")


def _commit() -> str:
    try:
        done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT, capture_output=True,
                              text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


def record(read: Read, path: Path | None = None) -> None:
    """Append one read (one line, flushed to disk)."""
    path = ledger_path() if path is None else path
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(dataclasses.asdict(read), sort_keys=True)
    with open(path, "a") as handle:
        handle.write(line + "\n")
        handle.flush()
        os.fsync(handle.fileno())


def new_read(key: str, policy: str, evaluation_set: str, seed_offset: int, episodes: int,
             reason: str, result: dict) -> Read:
    """A read made now by this process's command line."""
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    program = [f"-m {spec.name}"] if spec is not None else sys.argv[:1]
    command = " ".join(["python", *program, *sys.argv[1:]])
    return Read(key, policy, evaluation_set, int(seed_offset), int(episodes), now, command, _commit(),
                reason.strip(), result)


def _rows(entries: list[Read]) -> Iterator[str]:
    yield "| time (UTC) | policy | set | episodes | successes | touching | reason |"
    yield "|---|---|---|---|---|---|---|"
    for r in entries:
        note = r.reason or ("backfilled" if r.backfilled else "")
        yield (f"| {r.time} | {r.policy} | {r.evaluation_set} | {r.episodes} | "
               f"{r.result.get('successes', '')} | {r.result.get('touched_episodes', '')} | {note} |")


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="python -m ahrm_stack.test_ledger",
                                     description="The sealed test split's reads, as a table.")
    parser.add_argument("--policy", metavar="FILE", help="only the reads of this policy file (by its hash)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        entries = reads()
        if args.policy:
            if not Path(args.policy).is_file():
                raise ConfigError(f"--policy {args.policy} not found")
            key = policy_key(Path(args.policy))
            entries = [r for r in entries if r.key == key]
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{ledger_path()}: {len(entries)} reads")
    for row in _rows(entries):
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
