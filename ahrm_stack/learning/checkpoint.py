"""Atomic, rotated checkpoints loaded with ``torch.load(weights_only=True)``.

A checkpoint is written to a temporary file in the same folder, flushed to disk and renamed into
place, so a run killed at any moment (SIGKILL included) leaves either the previous checkpoint or
the new one, never a torn file; its SHA-256 follows in ``ckpt-N.pt.sha256``. Only the newest
``keep`` checkpoints are kept.

A file torn, truncated or changed by other means (a full disk, a copy cut short, a flipped bit, a
foreign file) is detected when a run is resumed (zip structure, SHA-256, contents):
:meth:`CheckpointManager.restore` names it and returns the newest intact checkpoint
(:meth:`CheckpointManager.discard` then moves the bad one aside, ``ckpt-N.pt.corrupt``); when
every checkpoint is unreadable it raises :class:`CheckpointError` instead of starting over.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import os
import pickle
import re
import sys
from pathlib import Path

import torch

from ahrm_stack.atomic import write_atomically

STATE_KEYS = ("actor", "critic", "optimizer", "mechanism", "time_objective", "counters", "torch_rng",
              "env_rng")  # what Trainer.state_dict writes
COUNTERS = ("episodes", "frames", "batches")


@dataclasses.dataclass
class Restored:
    """What :meth:`CheckpointManager.restore` found."""

    state: dict | None  # the newest intact checkpoint's state (None: the folder holds none)
    path: Path | None  # its file
    skipped: list[tuple[Path, str]]  # newer files that could not be used, and why


def _step_of(path: Path) -> int:
    """The batch number in a ``ckpt-NNNNNNN.pt`` name (-1 when it is not one)."""
    digits = path.name[len("ckpt-"):-len(".pt")]
    return int(digits) if digits.isdigit() else -1


def check_state(state: object, path: Path) -> dict:
    """``state`` when it is a complete trainer checkpoint whose counters match its file name;
    otherwise raises ``ValueError`` saying what is wrong."""
    if not isinstance(state, dict):
        raise ValueError(f"holds a {type(state).__name__}, not a checkpoint dictionary")
    missing = [key for key in STATE_KEYS if key not in state]
    if missing:
        raise ValueError(f"is not a trainer checkpoint (missing {missing})")
    counters = state["counters"]
    if not isinstance(counters, dict) or not all(
            isinstance(counters.get(k), int) and counters[k] >= 0 for k in COUNTERS):
        raise ValueError(f"has bad counters {counters!r}")
    step = _step_of(Path(path))
    if step >= 0 and counters["batches"] != step:
        raise ValueError(f"holds batch {counters['batches']}, its name says batch {step}")
    return state


class CheckpointError(ValueError):
    """A checkpoint or policy file cannot be loaded safely, or no checkpoint of a run can be used; a
    one-line message names the file (the folder and the files)."""


class MissingCheckpointError(CheckpointError, FileNotFoundError):
    """The checkpoint or policy file does not exist."""


class CheckpointManager:
    def __init__(self, directory: Path, keep: int) -> None:
        self.directory = Path(directory)
        self.keep = keep

    def paths(self) -> list[Path]:
        """Checkpoints on disk, oldest first."""
        if not self.directory.exists():
            return []
        return sorted(self.directory.glob("ckpt-*.pt"))

    def save(self, state: dict, step: int) -> Path:
        """Write ``ckpt-<step>.pt`` atomically, then its SHA-256 (``ckpt-<step>.pt.sha256``);
        keep the newest ``keep``."""
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self.directory / f"ckpt-{step:07d}.pt"
        buffer = io.BytesIO()
        torch.save(state, buffer)
        payload = buffer.getvalue()
        _digest_path(path).unlink(missing_ok=True)  # never a digest of what this replaces
        _write_durably(path, payload)
        _write_durably(_digest_path(path), hashlib.sha256(payload).hexdigest().encode() + b"\n")
        _fsync_dir(self.directory)
        for old in self.paths()[:-self.keep]:
            old.unlink()
            _digest_path(old).unlink(missing_ok=True)
        return path

    def restore(self) -> Restored:
        """The newest intact checkpoint, and the newer ones that are not (it writes nothing:
        :meth:`discard` moves those aside once the caller has decided to go on).

        Returns ``Restored(None, None, [])`` when the folder holds no checkpoint at all (a run
        killed before its first one). Raises :class:`CheckpointError` when there are checkpoints
        but none can be read: a silent restart would throw the run's work away.
        """
        paths = self.paths()
        skipped: list[tuple[Path, str]] = []
        for path in reversed(paths):
            try:
                state = check_state(_load_verified(path), path)
            except Exception as error:  # noqa: BLE001 - torn, truncated or foreign: try the previous
                text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
                skipped.append((path, f"torn or truncated checkpoint {path} ({path.stat().st_size} "
                                      f"bytes): {text}"))
                continue
            return Restored(state, path, skipped)
        if paths:
            raise CheckpointError(f"none of the {len(paths)} checkpoints in {self.directory} can be "
                                  f"read ({skipped[0][1]}); not restarting from scratch: move the "
                                  "folder away to start the run over")
        return Restored(None, None, [])

    def discard(self, skipped: list[tuple[Path, str]]) -> None:
        """Move unusable checkpoints aside (``ckpt-N.pt.corrupt``: kept for inspection, never
        loaded or rotated) and delete temporary files of saves cut short."""
        for bad, _ in skipped:
            os.replace(bad, bad.with_name(bad.name + ".corrupt"))
            _digest_path(bad).unlink(missing_ok=True)
        for tmp in [*self.directory.glob(".ckpt-*.tmp"), *self.directory.glob("ckpt-*.tmp")]:
            tmp.unlink()

    def load_latest(self) -> dict | None:
        """The newest intact checkpoint's state, or None when there is none (unusable newer ones
        are reported on stderr); raises :class:`CheckpointError` when none is readable."""
        restored = self.restore()
        for _, reason in restored.skipped:
            print(f"warning: {reason}; skipped", file=sys.stderr)
        return restored.state


def _digest_path(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def _write_durably(path: Path, payload: bytes) -> None:
    """``path`` holds ``payload`` or is untouched, whenever the process dies (temp file, fsync,
    rename)."""
    write_atomically(path, payload)


def _load_verified(path: Path) -> dict:
    """Load a checkpoint, first checking its bytes against its ``.sha256`` when it has one (a
    kill between the two renames of :meth:`CheckpointManager.save` leaves none: the zip
    structure is then the only check)."""
    payload = Path(path).read_bytes()
    digest_file = _digest_path(Path(path))
    if digest_file.is_file():
        expected = digest_file.read_text().strip()
        actual = hashlib.sha256(payload).hexdigest()
        if actual != expected:
            raise ValueError(f"its SHA-256 {actual[:12]}... differs from {digest_file.name} "
                             f"({expected[:12]}...): the file changed after it was written")
    return torch.load(io.BytesIO(payload), map_location="cpu", weights_only=True)


def _fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (POSIX; a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def load(path: Path) -> dict:
    """Load a checkpoint or policy file safely (tensors and plain containers only).

    A file that holds any other Python object (a pickle that would run code when loaded) is
    refused with a one-line :class:`CheckpointError` naming the file and the object; so is a file
    that is not a PyTorch checkpoint at all. The refused object is never imported or called."""
    path = Path(path)
    if not path.is_file():
        raise MissingCheckpointError(f"no such checkpoint or policy file: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        found = re.search(r"GLOBAL ([\w.]+)", str(error))
        what = f"the Python object {found.group(1)}" if found else "a Python object"
        raise CheckpointError(
            f"{path}: refused to load: it holds {what}, and a weights_only load (tensors and plain "
            "containers only) never unpickles objects that could run code") from None
    except Exception as error:  # noqa: BLE001 - torch raises anything on a foreign file
        first_line = (str(error).splitlines() or [""])[0][:200]
        raise CheckpointError(f"{path}: not a readable PyTorch checkpoint "
                              f"({type(error).__name__}: {first_line})") from None
