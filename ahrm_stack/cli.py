"""Quiet command lines (the libraries' warnings and INFO logs hidden unless ``--verbose``), and the
one argument parser of every entry point (:class:`Parser`: one-line errors).

Every entry point (``python -m ahrm_stack.<name>``, the benchmarks and studies) calls :func:`quiet`
first (the scripts before their heavy imports, through :func:`quiet_argv`), so that its first line
is its own. Hidden by default:

* Python warnings raised from library code (any file outside this checkout's ``ahrm_stack/``,
  ``hardware/``, ``benchmarks/``, ``studies/`` and ``tests/``): torchrl's DeprecationWarnings,
  glfw's ``GLFWError`` "DISPLAY environment variable is missing" (dm_control initialises glfw when
  ``MUJOCO_GL`` is unset), and the like. The
  hook is :data:`warnings.showwarning`, not a filter: dm_control's composer inserts
  ``simplefilter('always', DeprecationWarning)`` at import, which would override a filter.
  Warnings raised by this project's own code are still shown.
* INFO (and DEBUG) records of the libraries' loggers (:data:`LIBRARY_LOGGERS`: torchrl's
  "Initialized LazyTensorStorage", absl, ray, ...); this project's own loggers keep their levels
  (deploy's INFO events among them). torchrl sets its logger's level from ``RL_LOGGING_LEVEL`` when
  it is imported, so that variable is set too (when unset) for a later import; Ray's
  ``ray.init(logging_level=...)`` takes :func:`library_log_level`.

``MUJOCO_GL`` is left alone: evaluation videos choose it themselves when it is unset (EGL, then
OSMesa; :mod:`ahrm_stack.env.video`), which setting it here would pre-empt.
``--verbose`` (``quiet(True)``) shows everything, and undoes an earlier ``quiet()``.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

VERBOSE_FLAG = "--verbose"

LIBRARY_LOGGERS = ("absl", "ray", "torchrl", "tensordict", "torch", "matplotlib", "PIL", "glfw", "OpenGL",
                   "jax", "urllib3", "filelock", "asyncio", "imageio", "imageio_ffmpeg", "numexpr")
"""Loggers held at WARNING unless verbose."""

_ROOT = Path(__file__).resolve().parent.parent
_OURS = tuple(str(_ROOT / name) + os.sep for name in ("ahrm_stack", "benchmarks", "studies", "tests"))
_SHOW_ALL = warnings.showwarning  # the interpreter's (or pytest's) hook when this module is imported
_TORCHRL_LEVEL, _QUIET_TORCHRL = "RL_LOGGING_LEVEL", "WARNING"
_LEVEL = logging.INFO


def _is_ours(filename: str) -> bool:
    return os.path.abspath(filename).startswith(_OURS)


def _show_ours(message, category, filename, lineno, file=None, line=None) -> None:  # type: ignore[no-untyped-def]
    """warnings.showwarning that drops the warnings raised from library files."""
    if _is_ours(str(filename)):
        _SHOW_ALL(message, category, filename, lineno, file, line)


def quiet(verbose: bool = False) -> None:
    """Hide the libraries' warnings and INFO logs (``verbose=False``) or show them (``True``).

    Idempotent; call it first in a ``main``. Affects only this process (Ray workers start their
    own and log through Ray's own settings).
    """
    global _LEVEL
    if verbose:
        if warnings.showwarning is _show_ours:
            warnings.showwarning = _SHOW_ALL
        if os.environ.get(_TORCHRL_LEVEL) == _QUIET_TORCHRL:
            del os.environ[_TORCHRL_LEVEL]
        _LEVEL = logging.INFO
        for name in LIBRARY_LOGGERS:
            logging.getLogger(name).setLevel(logging.NOTSET)
        return
    warnings.showwarning = _show_ours
    os.environ.setdefault(_TORCHRL_LEVEL, _QUIET_TORCHRL)
    _LEVEL = logging.WARNING
    for name in LIBRARY_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)


def library_log_level() -> int:
    """The level the libraries log at now: WARNING after ``quiet()``, else INFO (for ``ray.init``)."""
    return _LEVEL


class Parser(argparse.ArgumentParser):
    """Every entry point's argument parser: a bad argument is one line on stderr naming it (exit
    status 2), not argparse's usage block."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def add_verbose_flag(parser: argparse.ArgumentParser) -> None:
    """Add ``--verbose`` (show the libraries' warnings and INFO logs) to an entry point's parser."""
    parser.add_argument(VERBOSE_FLAG, action="store_true",
                        help="show the libraries' warnings and INFO logs (hidden by default)")


def quiet_argv(argv: Sequence[str] | None = None) -> list[str]:
    """:func:`quiet` from the command line itself (``--verbose`` present or not), for a ``main``
    whose parser does not know the flag; returns the arguments without it (``argv`` None: sys.argv[1:])."""
    args = list(sys.argv[1:] if argv is None else argv)
    quiet(VERBOSE_FLAG in args)
    return [a for a in args if a != VERBOSE_FLAG]


def named_folders(items: Sequence[str]) -> dict[str, Path]:
    """``NAME=FOLDER`` arguments (the studies' ``summarise``) as a mapping; a ``SystemExit(2)`` with
    a one-line error naming the first item that is not one with an existing folder."""
    named: dict[str, Path] = {}
    for item in items:
        name, _, path = item.partition("=")
        if not name or not path or not Path(path).is_dir():
            print(f"error: {item!r} is not NAME=RUN_DIR with an existing folder", file=sys.stderr)
            raise SystemExit(2)
        named[name] = Path(path)
    return named
