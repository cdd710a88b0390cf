"""Packaging shim: ships the repository's ``schema/`` and ``plugins/`` inside the wheel.

The USD plugin (``plugins/usdAhd``, the validators in ``plugins/usdAhdValidators``) and the
schema source (``schema/schema.usda``) live at the repository root, where USD's tools expect
them. A plain ``pip install`` must still carry them, so ``build_py`` copies both into
``usdahd/_resources/`` (declared as package data in pyproject.toml) and ``sdist`` includes them.
``usdahd.usd.plugin`` registers ``usdahd/_resources/plugins`` when it exists and falls back to the
repository's ``plugins/`` in a source checkout or an editable install.
Everything else is configured in pyproject.toml.
"""

from __future__ import annotations

import os
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

ROOT = Path(__file__).resolve().parent
#: Repository-root directories shipped as ``usdahd/_resources/<name>``.
RESOURCE_DIRS = ("schema", "plugins")
_SKIP = {"__pycache__", ".pytest_cache"}


def _resource_files():
    """(source path, path relative to the repository root) of every shipped resource file."""
    for name in RESOURCE_DIRS:
        top = ROOT / name
        if not top.is_dir():
            continue
        for dirpath, dirnames, filenames in os.walk(top):
            dirnames[:] = sorted(d for d in dirnames if d not in _SKIP)
            for f in sorted(filenames):
                if f.endswith((".pyc", ".pyo")):
                    continue
                src = Path(dirpath) / f
                yield src, src.relative_to(ROOT)


class BuildPyWithResources(build_py):
    """build_py that also copies schema/ and plugins/ into usdahd/_resources/."""

    def run(self):
        super().run()
        if self.editable_mode:  # editable installs read the checkout's directories
            return
        target = Path(self.build_lib) / "usdahd" / "_resources"
        for src, rel in _resource_files():
            dst = target / rel
            self.mkpath(str(dst.parent))
            self.copy_file(str(src), str(dst))

    def get_outputs(self, include_bytecode=True):
        outputs = list(super().get_outputs(include_bytecode))
        if not self.editable_mode:
            target = Path(self.build_lib) / "usdahd" / "_resources"
            outputs += [str(target / rel) for _src, rel in _resource_files()]
        return outputs


class SdistWithResources(sdist):
    """sdist that includes schema/ and plugins/ so a wheel built from it still ships them."""

    def add_defaults(self):
        super().add_defaults()
        self.filelist.extend(str(rel) for _src, rel in _resource_files())


setup(cmdclass={"build_py": BuildPyWithResources, "sdist": SdistWithResources})
