"""CPU seconds per phase of one ``usdahd bake`` (issue 43: where a small bake's time goes).

    python benchmarks/bake_profile.py samples/exterior_sun_sky.usda --resolution 32 \
        --samples 256 [--flags=--no-denoise] [--top 30 [--sort tottime]] [--serial]

The bake runs in this process after one untimed 4-spp bake of the same stage (numba kernels
and caches loaded, as ``benchmarks/reference/warm.py`` times usdahd), under cProfile with the
process CPU time as its clock (every thread's CPU: the tracer's and OIDN's threads count),
so the shares hold on a loaded machine, where wall times do not. Prints the bake's CPU and
wall seconds, the report's ``seconds``, texels, rays, the pixels of each OIDN run (mosaic
images: chart canvases with their context) per covered texel and the 1-minute load, then the
cumulative CPU seconds and share of each phase (the functions of PHASES); ``--top N`` adds
cProfile's N largest cumulative entries. The stage's folder is copied to a temporary one
(the output goes there too).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import os
import pstats
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path

#: (label, function name, a part of its file's path) of the phases reported, in bake order.
PHASES = (
    ("scene load", "load_scene", "usd/reader"),
    ("plan (per prim)", "plan_job", "pipeline/plan"),
    ("rasterize texels", "rasterize", "bake/texels"),
    ("contacts pushed off", "push_off_contacts", "bake/texels"),
    ("trace, every prim (_trace_jobs)", "_trace_jobs", "pipeline/stages"),
    ("trace (bake_texels)", "bake_texels", "bake/integrate"),
    ("fill invalid", "fill_invalid", "bake/post"),
    ("denoise (denoise_records)", "denoise_records", "bake/denoise"),
    ("  of which OIDN execute", "execute", "pyoidn"),
    ("  of which noise kernel", "_tile_stats_numba", "numerics/noise"),
    ("seams: find", "find_seams", "bake/post"),
    ("seams: stitch", "stitch", "bake/post"),
    ("fit + encode + write pages", "write_pages", "pipeline/atlas"),
    ("commit textures", "commit_textures", "pipeline/outputs"),
    ("author layer", "author_layer", "pipeline/outputs"),
)


def profile(stage: Path, resolution: int, samples: int, flags: list[str]):
    """(cpu, wall, report, pstats.Stats, OIDN pixels per run) of one warm bake of ``stage``."""
    from usdahd.bake import denoise
    from usdahd.cli import main

    pixels = []
    run = denoise._Denoiser.run

    def counted(self, color, **kw):
        pixels.append(color.shape[0] * color.shape[1])
        return run(self, color, **kw)

    tmp = Path(tempfile.mkdtemp(prefix="usdahd-profile-"))
    try:
        shutil.copytree(stage.parent, tmp / "s")
        st = tmp / "s" / stage.name
        common = ["--resolution", str(resolution), "-q", *flags]
        with contextlib.redirect_stdout(io.StringIO()):
            main(["bake", str(st), "--samples", "4", "-o", str(tmp / "w" / "w.usda"), *common])
        pixels.clear()
        denoise._Denoiser.run = counted
        prof = cProfile.Profile(time.process_time)
        buf = io.StringIO()
        c0, w0 = time.process_time(), time.perf_counter()
        argv = ["bake", str(st), "--samples", str(samples), "--json"]
        argv += ["-o", str(tmp / "o" / "o.usda"), *common]
        with contextlib.redirect_stdout(buf):
            prof.runcall(main, argv)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        per_run = sum(pixels) / len(pixels) if pixels else 0
        return cpu, wall, json.loads(buf.getvalue()), pstats.Stats(prof), per_run
    finally:
        denoise._Denoiser.run = run
        shutil.rmtree(tmp, ignore_errors=True)


def phase_seconds(stats: pstats.Stats) -> dict[str, float]:
    """Cumulative CPU seconds of each PHASES entry found in ``stats``."""
    out: dict[str, float] = {}
    for (path, _, name), (_, _, _, cum, _) in stats.stats.items():
        for label, fn, where in PHASES:
            if name == fn and where in path.replace("\\", "/"):
                out[label] = out.get(label, 0.0) + cum
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", type=Path)
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--flags", default="", help="more bake flags, e.g. --flags=--no-denoise")
    ap.add_argument("--top", type=int, default=0, help="also cProfile's N largest entries")
    ap.add_argument("--sort", default="cumulative", help="--top's order (cumulative, tottime)")
    ap.add_argument(
        "--serial", action="store_true",
        help="the denoiser's chart work and the prims' tracing on the calling thread "
        "(denoise.CHART_THREADS = stages.JOB_THREADS = 1), so cProfile sees them (on other "
        "threads they show as a wait)",
    )  # fmt: skip
    a = ap.parse_args(argv)
    if not a.stage.is_file():
        print(f"error: {a.stage}: no such stage", file=sys.stderr)
        return 2
    from usdahd.bake import denoise
    from usdahd.pipeline import stages

    threads = denoise.CHART_THREADS, stages.JOB_THREADS
    if a.serial:
        denoise.CHART_THREADS = stages.JOB_THREADS = 1
    try:
        cpu, wall, rep, stats, px = profile(a.stage, a.resolution, a.samples, shlex.split(a.flags))
    finally:
        denoise.CHART_THREADS, stages.JOB_THREADS = threads
    rays = sum(p.get("rays", 0) for p in rep.get("prims", []))
    covered = sum(p.get("texels", 0) for p in rep.get("prims", []))
    print(
        f"# {a.stage.stem} {a.resolution}^2 {a.samples} spp {a.flags}: bake CPU {cpu:.2f} s, "
        f"wall {wall:.2f} s, report seconds {rep['seconds']:.2f}, texels "
        f"{rep.get('texels_total')} ({covered:,} covered), rays {rays:,}, OIDN pixels per run "
        f"{px:,.0f} ({px / max(covered, 1):.2f} per covered texel), load "
        f"{os.getloadavg()[0]:.1f}"
    )
    got = phase_seconds(stats)
    for label, _, _ in PHASES:
        if label in got:
            print(f"| {label} | {got[label]:.3f} | {100 * got[label] / cpu:.1f} % |")
    if a.top:
        stats.sort_stats(a.sort).print_stats(a.top)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
