"""Does denoising pay in time? Error and CPU seconds of ``usdahd bake`` with and without
``--denoise`` at equal samples, against usdahd's own converged bake (issue 43).

    python benchmarks/denoise_cost.py --resolution 32 --samples 16 64 256 --seeds 0 1 \
        --truth-spp 4096 samples/exterior_sun_sky.usda samples/floor_lamp.usda ...

Every bake runs in this process (kernels loaded once). Truth: the mean of two
``--no-denoise`` bakes at ``--truth-spp`` (seeds 1000 and 1001; cached in --cache), whose
difference gives its noise (rms / 2, taken out of each error in quadrature). The integrator
is unbiased against Cycles (issue 17, benchmarks/reference/README.md), so what this judges is
the denoiser; it needs no Cycles and runs in minutes. Error: relRMSE of Rec. 709 luminance of
I_z over the interior covered texels (``benchmarks.reference.compare.interior``) of every
baked mesh, net of the truth's noise, mean over seeds. CPU: the bake call's process CPU
seconds (every thread), median over seeds. Prints one JSON row per stage, samples and
variant (``plain``: --no-denoise, ``default``), then a markdown table with the CPU seconds
``--no-denoise`` needs to reach the default's error at each sample count (its error taken
to fall as 1/sqrt(samples) from its largest count, its CPU linear in the samples between
its two largest counts).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks.reference import compare as C  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])
VARIANTS = {"plain": ["--no-denoise"], "default": []}


def bake(stage: Path, resolution: int, spp: int, seed: int, flags: list[str]):
    """({prim: (luminance I_z (h, w), interior mask)}, CPU seconds) of one bake."""
    from usdahd.cli import main

    tmp = Path(tempfile.mkdtemp(prefix="usdahd-dcost-"))
    try:
        argv = ["bake", str(stage), "--resolution", str(resolution), "--samples", str(spp)]
        argv += ["--seed", str(seed), "-q", "-o", str(tmp / "o.usda"), *flags]
        with contextlib.redirect_stdout(io.StringIO()):
            c0 = time.process_time()
            main(argv)
            cpu = time.process_time() - c0
        out = {}
        for path, r in C.usdahd_results(tmp / "o.usda").items():
            if r.get("sidecar"):
                iz, cov = C.usdahd_iz(r["record"])
                out[path] = (iz @ LUMA, C.interior(cov))
        return out, cpu
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def truth(stage: Path, resolution: int, spp: int, cache: Path) -> dict:
    """{prim: (mean luminance I_z, interior mask, difference of the two seeds)}."""
    f = cache / f"{stage.stem}-{resolution}-{spp}.npz"
    if f.exists():
        return np.load(f, allow_pickle=True)["d"].item()
    a, _ = bake(stage, resolution, spp, 1000, ["--no-denoise"])
    b, _ = bake(stage, resolution, spp, 1001, ["--no-denoise"])
    d = {p: (0.5 * (a[p][0] + b[p][0]), a[p][1], a[p][0] - b[p][0]) for p in a}
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(f, d=np.array(d, dtype=object))
    return d


def net_error(est: dict, tr: dict) -> float:
    """relRMSE of ``est`` against ``tr`` over every mesh's interior texels, net of the truth's
    noise (rms(A - B) / 2 of its two seeds, relative)."""
    xs, ts, ds = [], [], []
    for p, (t, m, diff) in tr.items():
        if p in est:
            xs.append(est[p][0][m])
            ts.append(t[m])
            ds.append(diff[m])
    x, t, d = (np.concatenate(v) for v in (xs, ts, ds))
    scale = float(np.mean(t))
    rel = float(np.sqrt(np.mean((x - t) ** 2))) / scale
    noise = 0.5 * float(np.sqrt(np.mean(d**2))) / scale
    return math.sqrt(max(rel**2 - noise**2, 0.0))


def table(rows: list[dict]) -> str:
    lines = [
        "| stage | size | spp | --no-denoise: net relRMSE / CPU s | default: net relRMSE / "
        "CPU s | error ratio | --no-denoise CPU s to the default's error |",
        "|---|---|---|---|---|---|---|",
    ]
    for stage, res in dict.fromkeys((r["stage"], r["resolution"]) for r in rows):
        got = {(r["variant"], r["spp"]): r for r in rows if (r["stage"], r["resolution"]) ==
               (stage, res)}  # fmt: skip
        spps = sorted({k[1] for k in got})
        if len(spps) < 2:
            continue
        lo, hi = got[("plain", spps[-2])], got[("plain", spps[-1])]
        slope = (hi["cpu"] - lo["cpu"]) / (spps[-1] - spps[-2])
        for n in spps:
            p, d = got[("plain", n)], got[("default", n)]
            need = spps[-1] * (hi["net_rel"] / d["net_rel"]) ** 2
            cpu = hi["cpu"] + slope * (need - spps[-1])
            lines.append(
                f"| {stage} | {res}² | {n} | {100 * p['net_rel']:.2f} % / {p['cpu']:.2f} | "
                f"{100 * d['net_rel']:.2f} % / {d['cpu']:.2f} | "
                f"{d['net_rel'] / p['net_rel']:.2f} | {cpu:.2f} ({need:.0f} spp) |"
            )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stages", nargs="+", type=Path)
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--truth-spp", type=int, default=4096)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "usdahd-dcost")
    a = ap.parse_args(argv)
    missing = [str(s) for s in a.stages if not s.is_file()]
    if missing:
        print(f"error: no such stage: {', '.join(missing)}", file=sys.stderr)
        return 2
    rows = []
    for stage in a.stages:
        tr = truth(stage, a.resolution, a.truth_spp, a.cache)
        for spp in a.samples:
            for name, flags in VARIANTS.items():
                errs, cpus = [], []
                for seed in a.seeds:
                    est, cpu = bake(stage, a.resolution, spp, seed, flags)
                    errs.append(net_error(est, tr))
                    cpus.append(cpu)
                rows.append({"stage": stage.stem, "resolution": a.resolution, "spp": spp,
                             "variant": name, "net_rel": float(np.mean(errs)),
                             "cpu": float(np.median(cpus))})  # fmt: skip
                print(json.dumps(rows[-1]), flush=True)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
