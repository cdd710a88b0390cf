"""Cold start (issue 43 item 6): a bake with an empty numba cache compiles the kernels its
stage and settings need, and nothing else: no fit kernel for a model that fits in numpy, no
noise statistics without denoising, no seam solver on a stage without seams. Checked from
numba's own compile events in a new process with its own empty ``NUMBA_CACHE_DIR`` (the first
bake after ``pip install``); no wall-clock assertion (the machine may be shared)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from usdahd.commands.warmup import STAGE

REPO = Path(__file__).resolve().parents[2]

#: The kernels tracing needs on any lit stage (rasteriser, Embree queries, integrator).
TRACE = {
    "usdahd.numerics.raster._get_kernel.<locals>.kernel",
    "usdahd.bake.kernels.embree.intersect_rays",
    "usdahd.bake.kernels.integrate.native_pass",
    "usdahd.bake.kernels.integrate.native_result",
}
FIT = "usdahd.models.irradz.kernel._fit_kernel"
NOISE = "usdahd.numerics.noise._tile_stats_numba"
SEAMS = "usdahd.numerics.cholesky"

CHILD = textwrap.dedent(
    """
    import json, sys
    from numba.core import event as ev

    names = set()

    class L(ev.Listener):
        def on_start(self, e):
            pass

        def on_end(self, e):
            f = e.data["dispatcher"].py_func
            names.add(f"{f.__module__}.{f.__qualname__}")

    ev.register("numba:compile", L())
    from usdahd.cli import main

    stage, out = sys.argv[1], sys.argv[2]
    common = ["bake", stage, "-q", "--json", "--resolution", "8", "--samples", "8"]
    steps = {}
    for name, extra in (("sh_l2", ["--model", "sh_l2", "--no-denoise"]), ("default", [])):
        names.clear()
        rc = main([*common, *extra, "-o", f"{out}/{name}.lightmaps.usda", "--force"])
        steps[name] = {"rc": rc, "compiled": sorted(n for n in names if n.startswith("usdahd"))}
    print("STEPS" + json.dumps(steps))
    """
)


@pytest.mark.slow
@pytest.mark.timeout(3600)  # a cold compile: ~1 min idle, 15+ min on a loaded 2-core machine
def test_a_cold_bake_compiles_only_the_kernels_its_stage_needs(tmp_path):
    stage = tmp_path / "quad.usda"
    stage.write_text(STAGE)  # one quad under a dome: no seam, one chart
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = dict(
        os.environ,
        NUMBA_CACHE_DIR=str(cache),
        PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    )
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(stage), str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
        timeout=3500,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    line = next(x for x in run.stdout.splitlines() if x.startswith("STEPS"))
    steps = json.loads(line[len("STEPS") :])
    first, second = steps["sh_l2"], steps["default"]
    assert first["rc"] == 0 and second["rc"] == 0, steps
    a, b = set(first["compiled"]), set(second["compiled"])
    # the empty cache was really empty: the first bake compiled the tracing kernels itself
    assert TRACE <= a, TRACE - a
    # sh_l2 fits in numpy, --no-denoise runs no noise estimate, one quad has no seam
    assert FIT not in a and NOISE not in a, sorted(a)
    assert not any(n.startswith(SEAMS) for n in a | b), sorted(a | b)
    # the default bake (hhd, denoised) adds exactly what it needs: the fit and the noise
    # statistics (the tracing kernels are in memory already, nothing is compiled twice)
    assert {FIT, NOISE} <= b and not (b & TRACE), sorted(b)
    assert all(n.startswith(("usdahd.models.irradz.", "usdahd.numerics.noise.")) for n in b), b
    assert any(p.suffix == ".nbi" for p in cache.rglob("*"))  # and they went to this cache
