"""Locate the files that the ``example-robot-data`` package installs.

Version 6 of the pip package is a cmeel wheel: the robots live under its cmeel prefix
(``cmeel.prefix/share/example-robot-data/robots/...``) and there is no Python module to import.
The files are found through the distribution's own file list (``importlib.metadata``), so nothing
depends on where site-packages is.
"""

from __future__ import annotations

import functools
import importlib.metadata
from pathlib import Path, PurePosixPath

DISTRIBUTION = "example-robot-data"
PACKAGE_URI = "package://example-robot-data/"
_SHARE = PurePosixPath("share/example-robot-data")


class RobotAssetError(FileNotFoundError):
    """A robot file is missing; the message names the file and the package."""


@functools.lru_cache(maxsize=1)
def _installed_files() -> dict[PurePosixPath, Path]:
    """Every file of the installed distribution under its ``share/example-robot-data`` folder,
    keyed by the path relative to that folder."""
    try:
        dist = importlib.metadata.distribution(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise RobotAssetError(f"the {DISTRIBUTION!r} package is not installed "
                              f"(pip install {DISTRIBUTION}==6.0.0)") from None
    found = {}
    for entry in dist.files or ():
        parts = PurePosixPath(str(entry)).parts
        for i in range(len(parts) - 1):
            if PurePosixPath(*parts[i:i + 2]) == _SHARE:
                found[PurePosixPath(*parts[i + 2:])] = Path(str(dist.locate_file(entry)))
                break
    if not found:
        raise RobotAssetError(f"the installed {DISTRIBUTION!r} lists no files under {_SHARE}/")
    return found


def robot_file(relative: str) -> Path:
    """Absolute path of ``relative`` (e.g. ``robots/kinova_description/robots/kinova.urdf``) under
    the package's ``share/example-robot-data`` folder."""
    files = _installed_files()
    path = files.get(PurePosixPath(relative))
    if path is None or not path.is_file():
        raise RobotAssetError(f"{relative!r} is not a file of the installed {DISTRIBUTION!r} "
                              f"package ({len(files)} files there)")
    return path


def resolve_uri(uri: str) -> Path:
    """The file of a URDF mesh reference ``package://example-robot-data/<relative>``."""
    if not uri.startswith(PACKAGE_URI):
        raise RobotAssetError(f"mesh {uri!r} is not in {PACKAGE_URI}")
    return robot_file(uri[len(PACKAGE_URI):])
