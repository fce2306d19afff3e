"""Where the project's files are: the config folder and the project root, in a checkout or installed.

In a checkout (an editable install, or ``PYTHONPATH`` on a worktree) the configs are the
repository's ``configs/`` beside the package and the project root is the repository. An installed
wheel carries a copy of ``configs/`` as package data (``ahrm_stack/_data/configs``, copied by
``setup.py`` at build time) and its project root is the working folder (run folders under
``runs/``, the test ledger's file). ``AHRM_CONFIG_DIR`` names another config folder (a copy to
edit, say) in either case. This module imports nothing of the package, so every layer may use it.
"""

from __future__ import annotations

import os
from pathlib import Path

CONFIG_ENV = "AHRM_CONFIG_DIR"  # a config folder other than the checkout's or the packaged one
_CHECKOUT_CONFIGS = Path(__file__).resolve().parents[1] / "configs"
PACKAGED_CONFIGS = Path(__file__).resolve().parent / "_data" / "configs"


IN_CHECKOUT = _CHECKOUT_CONFIGS.is_dir()  # the package runs from a repository checkout


def config_dir() -> Path:
    """The config folder: ``$AHRM_CONFIG_DIR``, else the checkout's ``configs/``, else the
    packaged copy."""
    override = os.environ.get(CONFIG_ENV)
    if override:
        return Path(override).resolve()
    return _CHECKOUT_CONFIGS if IN_CHECKOUT else PACKAGED_CONFIGS


CONFIG_DIR = config_dir()
PROJECT_ROOT = _CHECKOUT_CONFIGS.parent if IN_CHECKOUT else Path.cwd()  # relative paths of configs resolve here
