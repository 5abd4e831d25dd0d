"""Installs ``laplab-gymnasium.pth`` into site-packages, beside the package, for regular and editable
installs alike, so that ``gym.make("laplab/TimeTrial-v0")`` works without importing laplab (see
laplab_gymnasium_hook.py). Everything else is in pyproject.toml.

A regular wheel gets the file from ``build_py`` (at the wheel's top, which is site-packages). An
editable wheel holds only setuptools' package finder and what is copied into the unpacked wheel, so
the hook is copied there too (setuptools skips data files in editable wheels). tests/env checks both
installs in a fresh interpreter, so a setuptools change that drops the file fails a test.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.editable_wheel import editable_wheel

HOOK = Path(__file__).resolve().parent / "laplab-gymnasium.pth"


class BuildPyWithHook(build_py):
    def run(self):
        super().run()
        if not self.editable_mode:
            self.copy_file(str(HOOK), str(Path(self.build_lib) / HOOK.name))

    def get_outputs(self, include_bytecode=True):
        extra = [] if self.editable_mode else [str(Path(self.build_lib) / HOOK.name)]
        return super().get_outputs(include_bytecode) + extra


class EditableWheelWithHook(editable_wheel):
    def _install_namespaces(self, installation_dir, pth_prefix):
        super()._install_namespaces(installation_dir, pth_prefix)
        shutil.copy(HOOK, Path(installation_dir) / HOOK.name)


setup(cmdclass={"build_py": BuildPyWithHook, "editable_wheel": EditableWheelWithHook})
