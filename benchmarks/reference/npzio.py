"""The harness's one atomic ``.npz`` writer (numpy + the standard library only, so the bpy
interpreter running ``cycles_bake.py`` imports it too: the script's folder is on its path)."""

from __future__ import annotations

import os
import tempfile

import numpy as np


def save_npz(path, arrays: dict, prefix: str = ".npz.", compress: bool = False) -> None:
    """Write ``arrays`` ({name: array}) to ``path`` through a temporary file in the same folder
    and an atomic rename: a reader never sees a partial file, a failure leaves none behind.
    ``compress``: ``np.savez_compressed`` (zip deflate) instead of ``np.savez``."""
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".npz", dir=d)
    os.close(fd)
    try:
        (np.savez_compressed if compress else np.savez)(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
