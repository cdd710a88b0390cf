"""Cold start (issue 43 item 6): a bake with an empty numba cache compiles the kernels its
stage and settings need, and nothing else: no fit kernel for a model that fits in numpy, no
noise statistics without denoising, no seam solver on a stage without seams. Checked from
numba's own compile events in a new process with its own empty ``NUMBA_CACHE_DIR`` (the first
bake after ``pip install``); no wall-clock assertion (the machine may be shared).

With ``USDAHD_COMPILE_JOBS=1`` the bake compiles everything itself; by default a second process
(``usdahd.bake.kernels.prefetch``) compiles the kernels of ``GROUPS`` the bake needs and the bake
loads them from the cache: then the bake itself compiles none of them, the second process
compiles exactly those groups (plus their callees), and the baked textures are bit-identical
to the one-process bake's."""

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
    import json, os, sys
    from pathlib import Path
    from usdahd.bake.kernels.prefetch import Prefetch
    from usdahd.numerics.numba_cache import CompiledKernels

    names = CompiledKernels().__enter__().names  # open for the life of this child
    from usdahd.cli import main

    stage, out = sys.argv[1], sys.argv[2]
    common = ["bake", stage, "-q", "--json", "--resolution", "8", "--samples", "8"]
    steps = {}
    for name, extra in (("sh_l2", ["--model", "sh_l2", "--no-denoise"]), ("default", [])):
        names.clear()
        Prefetch.last = None
        os.makedirs(f"{out}/{name}", exist_ok=True)
        rc = main([*common, *extra, "-o", f"{out}/{name}/{name}.lightmaps.usda", "--force"])
        pf = Prefetch.last
        steps[name] = {
            "rc": rc,
            "compiled": sorted(n for n in names if n.startswith("usdahd")),
            "second": None if pf is None else {
                "kernels": pf.names, "done": pf.done, "report": pf.report,
            },
            "cache": sorted(p.name for p in Path(os.environ["NUMBA_CACHE_DIR"]).rglob("*.nbi")),
        }
    from usdahd.bake.kernels import prefetch
    steps["signatures"] = {
        n: [str(s) for s in prefetch.dispatcher(n).signatures]
        for g in prefetch.GROUPS.values() for n in g
    }
    steps["manifest"] = {n: [str(s) for s in v] for n, v in prefetch.signatures().items()}
    print("STEPS" + json.dumps(steps))
    """
)


def _cold(tmp_path, jobs: int) -> tuple[dict, Path]:
    """Run CHILD (two bakes of the warm-up quad) in a new process with an empty numba cache."""
    stage = tmp_path / "quad.usda"
    stage.write_text(STAGE)  # one quad under a dome: no seam, one chart
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    env = dict(
        os.environ,
        NUMBA_CACHE_DIR=str(cache),
        USDAHD_COMPILE_JOBS=str(jobs),
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
    assert steps["sh_l2"]["rc"] == 0 and steps["default"]["rc"] == 0, steps
    return steps, cache


def _textures(folder: Path) -> dict[str, bytes]:
    """The baked files of one output folder except the layer (it names its folder)."""
    files = (p for p in folder.rglob("*") if p.is_file() and p.suffix != ".usda")
    return {p.name: p.read_bytes() for p in files}


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    """The cold bakes with USDAHD_COMPILE_JOBS=1 (everything compiled in the bake's process)."""
    tmp = tmp_path_factory.mktemp("jobs1")
    return (*_cold(tmp, 1), tmp)


@pytest.mark.slow
@pytest.mark.timeout(3600)  # a cold compile: ~1 min idle, 15+ min on a loaded 2-core machine
def test_a_cold_bake_compiles_only_the_kernels_its_stage_needs(one_process):
    steps, cache, _ = one_process
    first, second = steps["sh_l2"], steps["default"]
    assert first["second"] is None and second["second"] is None  # one process: none started
    a, b = set(first["compiled"]), set(second["compiled"])
    # the empty cache was really empty: the first bake compiled the tracing kernels itself
    assert TRACE <= a, TRACE - a
    # sh_l2 fits in numpy, --no-denoise runs no noise estimate, one quad has no seam
    assert FIT not in a and NOISE not in a, sorted(a)
    assert not any(n.startswith(SEAMS) for n in a | b), sorted(a | b)
    # the default bake (hhd, denoised) adds exactly what it needs: the fit and the noise
    # statistics (the tracing kernels are in memory already, nothing is compiled twice)
    assert {FIT, NOISE} <= b and not (b & TRACE), sorted(b)
    denoise_fit = (
        "usdahd.models.irradz.",
        "usdahd.numerics.noise.",
        "usdahd.numerics.windows.",
        "usdahd.bake.blend.",
    )
    assert all(n.startswith(denoise_fit) for n in b), b
    assert any(p.suffix == ".nbi" for p in cache.rglob("*"))  # and they went to this cache
    # the prefetch manifest is current: the kernels it names were compiled with its signatures
    assert steps["signatures"] == steps["manifest"], "python -m benchmarks.startup " + (
        "--write-signatures rewrites usdahd/bake/kernels/signatures.json"
    )


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_a_cold_bake_hands_kernels_to_a_second_process_and_bakes_the_same_bits(
    one_process, tmp_path
):
    from usdahd.bake.kernels.prefetch import GROUPS

    steps, cache = _cold(tmp_path, 2)
    first, second = steps["sh_l2"], steps["default"]
    a, b = set(first["compiled"]), set(second["compiled"])
    # sh_l2 without denoising: the second process gets the tracing group only
    assert first["second"]["kernels"] == list(GROUPS["trace"]), first["second"]
    assert first["second"]["done"] == {n: "done" for n in GROUPS["trace"]}, first["second"]
    got = set(first["second"]["report"]["compiled"])
    assert set(GROUPS["trace"]) <= got and not ({FIT, NOISE} & got), sorted(got)
    # the bake compiled the rest of the tracing kernels, and none of the second process's
    assert {"usdahd.bake.kernels.integrate.native_pass"} <= a, sorted(a)
    assert not (a & set(GROUPS["trace"])), sorted(a & set(GROUPS["trace"]))
    assert FIT not in a and NOISE not in a, sorted(a)
    assert not [n for n in first["cache"] if "_fit_kernel" in n or "_tile_stats" in n]
    # the default bake: the fit and the noise statistics come from the second process; the
    # bake compiles nothing (the tracing kernels are in memory, the rest loaded)
    assert second["second"]["kernels"] == [*GROUPS["noise"], *GROUPS["fit"]], second["second"]
    assert {FIT, NOISE} <= set(second["second"]["report"]["compiled"])
    assert not b, sorted(b)
    assert any("_fit_kernel" in n for n in second["cache"]), second["cache"]
    assert any("_tile_stats" in n for n in second["cache"]), second["cache"]
    # the bake loaded exactly the manifest's signatures (a stale one would have been compiled)
    assert steps["signatures"] == steps["manifest"]
    # and the textures equal the one-process bake's, bit for bit
    _, _, tmp1 = one_process
    for name in ("sh_l2", "default"):
        mine, theirs = _textures(tmp_path / name), _textures(tmp1 / name)
        assert mine and mine.keys() == theirs.keys(), (sorted(mine), sorted(theirs))
        assert all(mine[k] == theirs[k] for k in mine), name
