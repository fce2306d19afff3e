"""One way to replace a file so that a kill at any moment leaves the old file or the new one.

    write_atomically(path, text_or_bytes)
    with replacing(path) as tmp:      # for writers that want a path (torch.save, ...)
        torch.save(obj, tmp)

The data goes to a hidden sibling (``.NAME.tmp``, same folder, so the rename is atomic; one writer
per file), is fsynced, and is renamed over ``path``; on an error the sibling is removed and ``path`` is left as
it was. Used by every file the project rewrites in place: run configs, run-folder logs,
checkpoints, policies, the experiment grid's records.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def replacing(path: Path | str) -> Iterator[Path]:
    """A temporary sibling of ``path`` to write; on leaving the block without an error it is
    fsynced and renamed over ``path``."""
    path = Path(path)
    # no process id in the name: torch.save names its archive after the file it writes, and a
    # policy must come out byte for byte the same from the same training
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        yield tmp
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_atomically(path: Path | str, data: str | bytes) -> None:
    """Replace ``path`` by ``data`` (text is written as UTF-8, newlines as they are)."""
    with replacing(path) as tmp:
        tmp.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)


__all__ = ["replacing", "write_atomically"]
