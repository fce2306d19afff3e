"""One atomic write (ahrm_stack/atomic.py): old or new file, never torn, and the same bytes from the
same data (torch.save names its archive after the file it writes)."""

from __future__ import annotations

import zipfile

import pytest
import torch

from ahrm_stack.atomic import replacing, write_atomically


def test_the_same_policy_gives_the_same_bytes(tmp_path):
    payloads = []
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        with replacing(tmp_path / folder / "policy.pt") as tmp:
            torch.save({"actor": {"w": torch.arange(4.0)}}, tmp)
        payloads.append((tmp_path / folder / "policy.pt").read_bytes())
    assert payloads[0] == payloads[1]
    assert zipfile.ZipFile(tmp_path / "a" / "policy.pt").namelist()[0].startswith(".policy.pt/")


def test_an_error_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "config.yaml"
    write_atomically(path, "old\n")
    with pytest.raises(RuntimeError):
        with replacing(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["config.yaml"]
    write_atomically(path, b"new\r\n")
    assert path.read_bytes() == b"new\r\n"
