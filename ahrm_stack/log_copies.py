"""Committed copies of a run's logs: a CSV log read from the run folder or from its gzipped copy,
and logs gzipped without a time stamp, so that the same data always gives the same bytes (the
studies' and tools' summarisers copy run logs under ``docs/``)."""

from __future__ import annotations

import csv
import gzip
import io
import shutil
from pathlib import Path


def csv_rows(folder: Path, name: str) -> list[dict[str, str]]:
    """The rows of ``folder/name``, or of its gzipped copy ``folder/name.gz``; [] when neither exists."""
    if (folder / name).is_file():
        text = (folder / name).read_text()
    elif (folder / f"{name}.gz").is_file():
        with gzip.open(folder / f"{name}.gz", "rt") as handle:
            text = handle.read()
    else:
        return []
    return list(csv.DictReader(io.StringIO(text)))


def gzip_copy(source: Path, target: Path) -> None:
    """Write ``source`` gzipped to ``target``, with no time stamp in the header."""
    with open(source, "rb") as plain, open(target, "wb") as raw:
        with gzip.GzipFile(filename=source.name, fileobj=raw, mode="wb", mtime=0) as packed:
            shutil.copyfileobj(plain, packed)
