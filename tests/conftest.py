"""Shared fixtures and sample paths of the test suite (helpers: tests/stats.py for Monte Carlo
tolerances, tests/_hemi_brute.py for brute-force hemisphere integrals).

Importing :mod:`usdahd.usd` here registers usdahd's USD plugins before any test builds a stage
with pxr directly: USD reads schema plugins once, when its schema registry is first built, and
``import usdahd`` alone does not register them (it needs no pxr).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import usdahd.usd  # noqa: F401  (registers the plugins before any stage exists)

try:  # property tests are seeded and deterministic: the same examples on every machine and run
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile("usdahd", derandomize=True, database=None)
    _hypothesis_settings.load_profile("usdahd")
except ImportError:  # hypothesis is a test extra; the tests that need it import it themselves
    pass

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"


def sample_stages() -> list[str]:
    """File names of the sample stages in samples/, sorted. Bake outputs a user wrote there
    (README command 1 writes samples/cornell_box.lightmaps.usda) are not samples."""
    return sorted(p.name for p in SAMPLES.glob("*.usda") if ".lightmaps." not in p.name)


def copy_sample(folder: Path, name: str) -> Path:
    """Copy samples/<name> and samples/textures/ (which some samples reference) into
    ``folder``; returns the copied stage. A bake then writes next to the copy, never into
    samples/."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    dst = folder / name
    shutil.copy(SAMPLES / name, dst)
    if (SAMPLES / "textures").is_dir():
        shutil.copytree(SAMPLES / "textures", folder / "textures", dirs_exist_ok=True)
    return dst


@pytest.fixture
def samples_dir() -> Path:
    """The repository's samples/ folder (read only: copy before baking)."""
    return SAMPLES


@pytest.fixture
def sample_copy(tmp_path):
    """``sample_copy(name)``: samples/<name> (and its textures) copied into tmp_path."""
    return lambda name: copy_sample(tmp_path, name)


def baked_mean_iz(layer: Path) -> float:
    """Mean baked I_z (channel R) over the covered texels of the one baked prim of ``layer``,
    from its float SH sidecar (reloaded, so a re-bake in the same process is seen)."""
    import numpy as np
    from pxr import Sdf, Usd

    from usdahd.numerics import sh as shmod
    from usdahd.usd import schema

    Sdf.Layer.FindOrOpen(str(layer)).Reload(force=True)
    stage = Usd.Stage.Open(str(layer))
    (prim,) = schema.prims_with_api(stage)
    res = schema.read_results(prim)
    img = schema.read_record_pixels(res, schema.SIDECAR_ROLE, schema.SH_SIDECAR_CHANNELS)
    px = np.asarray(img, np.float64).reshape(-1, 28)
    covered = px[px[:, 27] > 0, :27].reshape(-1, 3, 9)
    return float(shmod.iz(covered)[:, 0].mean())
