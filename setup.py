"""Build hook: a wheel carries a copy of ``configs/`` as package data (``ahrm_stack/_data/configs``),
so that an installed package runs outside the checkout (``ahrm_stack/paths.py`` finds it there).
Everything else is in pyproject.toml. An editable install reads the checkout's ``configs/`` itself."""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildWithConfigs(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False) or self.dry_run:
            return
        target = Path(self.build_lib) / "ahrm_stack" / "_data" / "configs"
        shutil.copytree(Path(__file__).resolve().parent / "configs", target, dirs_exist_ok=True)


setup(cmdclass={"build_py": BuildWithConfigs})
