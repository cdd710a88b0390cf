"""``usdahd warmup``: compile (or load from numba's cache) every kernel a bake needs, once.

numba compiles the bake's kernels on their first use and caches them on disk; the first bake
after installing usdahd spends a minute or two compiling before its first texel (issue 16,
``benchmarks/startup.py``). ``usdahd warmup`` does that work up front: it bakes a small built-in
stage (one quad under a dome light, written to a temporary folder and removed) with the default
settings, which compiles the tracing, rasterising and encoding kernels, then fits a few SH with
every registered model, ratio and solver. It prints how many kernels it compiled and how many
numba's cache already had; run a second time it compiles nothing. Kernels are cached where
numba caches them (``NUMBA_CACHE_DIR``, else ``__pycache__`` next to the installed sources).
"""

from __future__ import annotations

import contextlib
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from usdahd.numerics.numba_cache import CompiledKernels

#: The warm-up stage: a 1 x 1 quad (y = 0, facing +y, UVs primvars:st) under a uniform dome.
STAGE = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{
    def Mesh "Quad"
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        normal3f[] normals = [(0, 1, 0), (0, 1, 0), (0, 1, 0), (0, 1, 0)] (
            interpolation = "vertex"
        )
        point3f[] points = [(-0.5, 0, 0.5), (0.5, 0, 0.5), (0.5, 0, -0.5), (-0.5, 0, -0.5)]
        texCoord2f[] primvars:st = [(0.05, 0.05), (0.95, 0.05), (0.95, 0.95), (0.05, 0.95)] (
            interpolation = "vertex"
        )
        uniform token subdivisionScheme = "none"
    }

    def DomeLight "Sky"
    {
        float inputs:intensity = 1
    }
}
"""

#: Bake settings of the warm-up (small: the point is compiling, not the picture).
RESOLUTION = 8
SAMPLES = 8


def add_parser(sub):
    p = sub.add_parser(
        "warmup",
        help="compile every bake kernel now (the first bake after installing then starts fast)",
        description=(
            "Compile, or load from numba's on-disk cache, every numba kernel a bake uses: bakes "
            "a small built-in stage in a temporary folder and fits every model. Run once after "
            "installing usdahd; the first real bake then shows its first texel within seconds. "
            "Prints how many kernels were compiled and how many came from the cache."
        ),
    )
    p.add_argument(
        "--jobs",
        type=int,
        choices=(1, 2),
        default=2,
        help="2 (default): compile the fit and noise kernels and fit every model in a second "
        "process while the first bakes the warm-up stage; 1: one process",
    )
    p.set_defaults(func=run)
    return p


def _kernels() -> set[str]:
    """Names of the usdahd numba dispatchers that have at least one compiled or loaded version."""
    import sys

    from numba.core.dispatcher import Dispatcher

    out = set()
    for mod in list(sys.modules.values()):
        if not getattr(mod, "__name__", "").startswith("usdahd"):
            continue
        for value in list(vars(mod).values()):
            if isinstance(value, Dispatcher) and value.signatures:
                f = value.py_func
                out.add(f"{f.__module__}.{f.__qualname__}")
    return out


def _fit_every_model() -> list[str]:
    """Fit a few fixed SH (float32, as a bake passes them) with every model/ratio/solver."""
    from usdahd import models

    rng = np.random.default_rng(0)
    sh = rng.normal(0.0, 0.1, size=(16, 3, 9)).astype(np.float32)
    sh[:, :, 0] = 1.0  # a bright, mostly uniform sky with some directional structure
    sh[:, :, 2] += 0.4
    done = []
    for name in models.names():
        mod = models.get(name)
        for ratio in mod.RATIOS:
            for solver in mod.SOLVERS:
                models.fit(sh, name, ratio=ratio, solver=solver)
                done.append(f"{name}/{ratio}/{solver}")
    return done


def _solve_seams() -> None:
    """Compile the seam solver (usdahd.numerics.cholesky): the warm-up quad has no seam."""
    from usdahd.numerics import cholesky

    indptr = np.array([0, 2, 4])
    f = cholesky.factor(indptr, np.array([0, 1, 0, 1]), np.array([2.0, -1.0, -1.0, 2.0]), [1, 0])
    f.solve(np.ones((2, 27)))


def _noise_stats() -> None:
    """Compile the denoiser's noise statistics, window means and blend (usdahd.numerics.noise,
    usdahd.numerics.windows, usdahd.bake.blend) on a small chart."""
    from usdahd.bake import blend
    from usdahd.numerics import noise, windows

    rng = np.random.default_rng(0)
    img = rng.normal(size=(12, 12, 27))
    mask = np.ones((12, 12), bool)
    ly, lx = np.nonzero(mask)
    mean, _, cnt, fmean, _, _ = noise.tile_stats(img, mask, 6)
    windows.neighbour_mean(mean, cnt > 0, fmean)
    windows.box_mean_texels(img[ly, lx], ly, lx, mask.shape, 2)
    noise.bends(img[ly, lx, :6], np.abs(img[ly, lx, 6:12]), ly, lx, mask.shape, 24.0)
    sh = img[ly, lx].reshape(-1, 3, 9)
    blend.blend_chart(sh, sh, np.abs(sh), ly, lx, mask, gain=1.5, edges=True)


def _second_worker() -> tuple[list[str], list[str]]:
    """The rest of ``--jobs 2``'s second process (after the fit and noise kernels): fit every
    model and compile the seam solver; returns (fits, the kernels ready there). The seam
    solver is here, not after the first process's bake, because that bake (the tracing
    kernels) is the longer of the two: 14.2 s against 10.7 s on an idle 2-core machine."""
    fits = _fit_every_model()
    _noise_stats()
    _solve_seams()
    return fits, sorted(_kernels())


def warmup(*, quiet: bool = False, jobs: int = 2) -> dict:
    """Compile or load every bake kernel; returns the report (kernels compiled / loaded).

    jobs : 2 compiles the kernels a bake runs after tracing (fit, noise statistics) in a
        second process (:class:`usdahd.bake.kernels.prefetch.Prefetch`), which then fits every
        model and compiles the seam solver, while this one bakes the warm-up stage and compiles
        the tracing kernels; the bake waits for the second process's kernels and loads them
        from numba's cache instead of compiling them too. 1 does everything here, one after
        the other.
    """
    from usdahd.bake.kernels.prefetch import Prefetch
    from usdahd.pipeline.run import bake
    from usdahd.pipeline.settings import BakeOptions

    t0, c0 = time.perf_counter(), time.process_time()
    child_compiled, child_ready, t_child, fits = set(), set(), None, None
    # --jobs 2: the second process compiles the fit and noise kernels first (the bake here
    # waits for them instead of compiling them too), then fits every model and compiles the
    # seam solver; this one bakes
    then = "usdahd.commands.warmup:_second_worker"
    second = Prefetch(["noise", "fit"], then=then) if jobs > 1 else None
    with second or contextlib.nullcontext():
        with CompiledKernels() as c:
            with tempfile.TemporaryDirectory(prefix="usdahd-warmup-") as tmp:
                stage = Path(tmp) / "warmup.usda"
                stage.write_text(STAGE)
                opts = BakeOptions(resolution=RESOLUTION, samples=SAMPLES, quiet=quiet)
                result = bake(stage, opts)
                if result.get("exit_code", 0) != 0:
                    from usdahd.errors import BakeError

                    raise BakeError(f"warm-up bake failed: {json.dumps(result)[:400]}")
            t_bake = (time.perf_counter() - t0, time.process_time() - c0)
            if second is not None:
                second.wait()
                rep = second.report
                if rep is not None and rep["result"] is not None:
                    fits, child_ready = rep["result"]
                    child_compiled, child_ready = set(rep["compiled"]), set(child_ready)
                    t_child = (rep["seconds"], rep["cpu_seconds"])
            if fits is None:  # --jobs 1, USDAHD_COMPILE_JOBS=1, or the second process failed
                fits = _fit_every_model()
                _noise_stats()
                _solve_seams()
    compiled = {k for k in c.names | child_compiled if k.startswith("usdahd")}
    ready = _kernels() | child_ready
    return {
        "command": "warmup",
        "exit_code": 0,
        "seconds": round(time.perf_counter() - t0, 2),
        "jobs": jobs,
        "bake_seconds": round(t_bake[0], 2),
        "bake_cpu_seconds": round(t_bake[1], 2),
        "second_process_seconds": None if t_child is None else round(t_child[0], 2),
        "second_process_cpu_seconds": None if t_child is None else round(t_child[1], 2),
        # the second process's exit status (None: none started; nonzero: this one did its work)
        "second_process_exit": None
        if second is None or second.proc is None
        else second.proc.returncode,
        "compiled": sorted(compiled),
        "loaded": sorted(ready - compiled),
        "fits": fits,
    }


def run(args) -> int:
    quiet = bool(getattr(args, "quiet", 0))
    report = warmup(quiet=quiet, jobs=getattr(args, "jobs", 2))
    if getattr(args, "json", False):
        print(json.dumps(report, indent=2))
        return 0
    n_c, n_l = len(report["compiled"]), len(report["loaded"])
    if n_c:
        msg = (
            f"usdahd warmup: compiled {n_c} kernels ({n_l} more from the cache) in "
            f"{report['seconds']:.1f}s; they are cached: bakes now start without compiling"
        )
    else:
        msg = (
            f"usdahd warmup: all {n_l} kernels loaded from numba's cache in "
            f"{report['seconds']:.1f}s: nothing to compile"
        )
    print(msg)
    if not quiet:
        for name in report["compiled"]:
            print(f"  compiled {name}")
    return 0
