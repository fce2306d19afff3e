"""Atomic, rotated checkpoints loaded with ``torch.load(weights_only=True)``.

A checkpoint is written to a temporary file in the same folder, flushed to disk and renamed into
place, so a run killed at any moment (SIGKILL included) leaves either the previous checkpoint or
the new one, never a torn file. Only the newest ``keep`` checkpoints are kept.
"""

from __future__ import annotations

import os
import pickle
import re
import sys
from pathlib import Path

import torch


class CheckpointError(ValueError):
    """A checkpoint or policy file cannot be loaded safely; a one-line message names the file."""


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
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self.directory / f"ckpt-{step:07d}.pt"
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as handle:
            torch.save(state, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        for old in self.paths()[:-self.keep]:
            old.unlink()
        return path

    def load_latest(self) -> dict | None:
        """The newest readable checkpoint (an unreadable one is reported and skipped)."""
        for path in reversed(self.paths()):
            try:
                return load(path)
            except Exception as error:  # noqa: BLE001 - a torn or foreign file: try the previous one
                print(f"warning: skipping unreadable checkpoint {path}: {error}", file=sys.stderr)
        return None


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
