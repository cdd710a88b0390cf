"""usdahd.numerics.numba_cache: numba's on-disk cache keeps a kernel compiled against an old
value of a constant imported from another module; track() makes it recompile."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

KERNEL = """
from numba import njit

from cachepkg import consts
from cachepkg.consts import K


@njit(cache=True)
def f():
    return K

{track}

print(f())
"""


def _run(root: Path) -> str:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(root / "cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(REPO), env.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", "import cachepkg.kern"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    return out.stdout.strip()


def _setup(root: Path, tracked: bool) -> None:
    pkg = root / "cachepkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "consts.py").write_text("K = 1.0\n")
    track = (
        "from usdahd.numerics import numba_cache\nnumba_cache.track(globals(), consts)"
        if tracked
        else "consts  # untracked"
    )
    (pkg / "kern.py").write_text(textwrap.dedent(KERNEL).format(track=track))


@pytest.mark.parametrize("tracked", [False, True])
def test_constant_from_another_module(tmp_path, tracked):
    _setup(tmp_path, tracked)
    assert _run(tmp_path) == "1.0"
    (tmp_path / "cachepkg" / "consts.py").write_text("K = 2.0  # edited\n")
    # Without tracking numba serves the stale kernel (the pitfall); with it, it recompiles.
    assert _run(tmp_path) == ("2.0" if tracked else "1.0")
