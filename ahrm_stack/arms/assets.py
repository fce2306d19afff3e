"""Locate the robot files: those the ``example-robot-data`` package installs, and those vendored in
this package (``package://ahrm_stack/<path>``, e.g. ``ahrm_stack/arms/vendor/kinova_gen3/``).

Version 6 of the example-robot-data pip package is a cmeel wheel: the robots live under its cmeel
prefix (``cmeel.prefix/share/example-robot-data/robots/...``) and there is no Python module to
import. The files are found through the distribution's own file list (``importlib.metadata``), so
nothing depends on where site-packages is. Vendored files are package data of ``ahrm_stack``.
"""

from __future__ import annotations

import functools
import importlib.metadata
from pathlib import Path, PurePosixPath

DISTRIBUTION = "example-robot-data"
PACKAGE_URI = "package://example-robot-data/"
VENDORED_URI = "package://ahrm_stack/"  # a file of this package, path relative to its folder
_PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the ahrm_stack package folder
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


def vendored_file(relative: str) -> Path:
    """Absolute path of ``relative`` (e.g. ``arms/vendor/kinova_gen3/gen3.urdf``) in this package."""
    path = (_PACKAGE_ROOT / relative).resolve()
    if not path.is_relative_to(_PACKAGE_ROOT) or not path.is_file():
        raise RobotAssetError(f"{relative!r} is not a file of the ahrm_stack package ({_PACKAGE_ROOT})")
    return path


def resolve_uri(uri: str) -> Path:
    """The file of a URDF mesh reference ``package://example-robot-data/<relative>`` or
    ``package://ahrm_stack/<relative>`` (vendored)."""
    if uri.startswith(VENDORED_URI):
        return vendored_file(uri[len(VENDORED_URI):])
    if not uri.startswith(PACKAGE_URI):
        raise RobotAssetError(f"mesh {uri!r} is neither in {PACKAGE_URI} nor in {VENDORED_URI}")
    return robot_file(uri[len(PACKAGE_URI):])


def urdf_file(file: str) -> Path:
    """The URDF of an arm entry's ``urdf.file``: a path under example-robot-data's share folder, or
    a ``package://`` reference (a file vendored in this package)."""
    return resolve_uri(file) if file.startswith("package://") else robot_file(file)
