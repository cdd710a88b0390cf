"""Shared fixtures of the test suite. The tests mirror the package (tests/bake/ tests
usdahd/bake/, ...; tests of top-level modules and of the repository as a whole are in tests/).
tests/ is a package, so helpers are imported by name from the repository root, which pytest puts
on sys.path: tests/scenes.py (the sample stages and the small-stage builders, one definition
each), tests/stats.py (Monte Carlo tolerances), tests/_hemi_brute.py (brute-force hemisphere
integrals).

Importing :mod:`usdahd.usd` here registers usdahd's USD plugins before any test builds a stage
with pxr directly: USD reads schema plugins once, when its schema registry is first built, and
``import usdahd`` alone does not register them (it needs no pxr).
"""

from __future__ import annotations

from pathlib import Path

import pytest

import usdahd.usd  # noqa: F401  (registers the plugins before any stage exists)
from tests.scenes import SAMPLES, copy_sample

try:  # property tests are seeded and deterministic: the same examples on every machine and run
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile("usdahd", derandomize=True, database=None)
    _hypothesis_settings.load_profile("usdahd")
except ImportError:  # hypothesis is a test extra; the tests that need it import it themselves
    pass


@pytest.fixture
def samples_dir() -> Path:
    """The repository's samples/ folder (read only: copy before baking)."""
    return SAMPLES


@pytest.fixture
def sample_copy(tmp_path):
    """``sample_copy(name)``: samples/<name> (and its textures) copied into tmp_path."""
    return lambda name: copy_sample(tmp_path, name)
