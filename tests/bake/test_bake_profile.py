"""benchmarks/bake_profile.py: the per-phase CPU report of one warm bake, and ``--serial``
(the denoiser's chart work on the calling thread, where cProfile sees it)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from benchmarks import bake_profile
from usdahd.bake import denoise

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _need_oidn():
    pytest.importorskip("pyoidn")


def _run(*flags: str) -> str:
    out = io.StringIO()
    argv = [str(REPO / "samples" / "floor_lamp.usda"), "--resolution", "16", "--samples", "4"]
    with contextlib.redirect_stdout(out):
        assert bake_profile.main([*argv, "--top", "400", "--sort", "tottime", *flags]) == 0
    return out.getvalue()


def test_serial_profile_sees_the_chart_work_and_restores_the_threads():
    from usdahd.pipeline import stages

    threads = denoise.CHART_THREADS, stages.JOB_THREADS
    text = _run("--serial")
    assert text.startswith("# floor_lamp 16^2 4 spp")
    assert "| denoise (denoise_records) |" in text and "| trace (bake_texels) |" in text
    assert "Ordered by: internal time" in text
    # on the calling thread: every chart's preparation and blend are in the profile (with
    # CHART_THREADS > 1 they run in pairs on the pool's threads, which cProfile does not see)
    assert "_prepare_chart" in text and "blend_chart" in text
    assert (denoise.CHART_THREADS, stages.JOB_THREADS) == threads
