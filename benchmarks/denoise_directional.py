"""Error of every SH band of a denoised 32^2 bake, with the directional coefficients' ratios
averaged in the chart (``denoise.DIRECTIONAL_OIDN`` False, the default) or run through OIDN's
directional network (cropped tiles, ``denoise.DIRECTIONAL_CROP``, or whole canvases), against
usdahd's own converged bake (issue 43: a cheaper directional denoise must not cost
directional accuracy).

    python benchmarks/denoise_directional.py --stages exterior_sun_sky stretched_boxes \
        floor_lamp cornell_box --samples 16 64 256 --seeds 0 1 --truth-spp 4096 \
        [--pads 10 8 6] [--radii 1 2 3]

Every bake runs in this process (kernels loaded once, one untimed 4-spp bake first). Truth:
the mean of two ``--no-denoise`` bakes at ``--truth-spp`` (seeds 1000 and 1001), whose
difference gives its noise (taken out of each error in quadrature). Per band (``c00``; ``c10``,
i.e. I_z; ``l1``: c1-1 and c11; ``l2``: the five l=2 coefficients): RMS of the Rec. 709
luminance of the coefficients' error over the interior covered texels, relative to the RMS
luminance of the truth's c00, in %, mean over seeds; CPU: the bake call's process CPU seconds
(every thread), median over seeds. Variants: ``plain`` (--no-denoise), ``mean`` (the
default), ``mean estimated`` (``denoise.DIRECTIONAL_NOISE_ESTIMATE``: the directional blend
also asks the second-difference noise estimate), ``oidn`` (OIDN's cropped tiles and the
estimate: the default until 2026-12-06), ``oidn full`` (uncropped); with ``--pads`` ``oidn
pad N`` (cropped with ``mosaic.CROP_PAD`` N), with ``--radii`` ``mean r N``
(``denoise.DIRECTIONAL_RADIUS`` N). Prints one JSON row per stage, samples and variant.
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
BANDS = {"c00": [0], "c10": [2], "l1": [1, 3], "l2": [4, 5, 6, 7, 8]}


def bake(stage: Path, spp: int, seed: int, flags: list[str]) -> tuple[dict, float]:
    """({prim: (n, 9) luminance of each coefficient on interior texels}, CPU seconds)."""
    from usdahd import sidecar
    from usdahd.cli import main

    tmp = Path(tempfile.mkdtemp(prefix="usdahd-ddir-"))
    try:
        argv = ["bake", str(stage), "--resolution", "32", "--samples", str(spp)]
        argv += ["--seed", str(seed), "-q", "-o", str(tmp / "o.usda"), *flags]
        with contextlib.redirect_stdout(io.StringIO()):
            c0 = time.process_time()
            main(argv)
            cpu = time.process_time() - c0
        out = {}
        for path, r in C.usdahd_results(tmp / "o.usda").items():
            if r.get("sidecar"):
                px = np.asarray(sidecar.read_record(r["record"]), np.float64)
                sh, cov = sidecar.split(px)
                out[path] = np.einsum("nck,c->nk", sh[C.interior(cov)], LUMA)
        return out, cpu
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def errors(est: dict, a: dict, b: dict) -> dict:
    """Per band: net relative RMS error (%) of ``est`` against the mean of ``a`` and ``b``."""
    t = {p: 0.5 * (a[p] + b[p]) for p in a}
    scale = math.sqrt(float(np.mean(np.concatenate([t[p][:, 0] for p in t]) ** 2)))
    res = {}
    for name, ks in BANDS.items():
        x = np.concatenate([est[p][:, ks].ravel() for p in t])
        tt = np.concatenate([t[p][:, ks].ravel() for p in t])
        d = np.concatenate([(a[p] - b[p])[:, ks].ravel() for p in t])
        rel = math.sqrt(float(np.mean((x - tt) ** 2))) / scale
        noise = 0.5 * math.sqrt(float(np.mean(d**2))) / scale
        res[name] = round(100 * math.sqrt(max(rel**2 - noise**2, 0.0)), 3)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", nargs="+", default=["exterior_sun_sky", "floor_lamp"])
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--truth-spp", type=int, default=4096)
    ap.add_argument("--pads", type=int, nargs="+", help="OIDN variants at these CROP_PAD")
    ap.add_argument("--radii", type=int, nargs="+", help="mean variants at these radii")
    a = ap.parse_args(argv)
    from usdahd.bake import denoise, mosaic

    # (label, bake flags, {module attribute: value} set for the variant's bakes)
    variants = [("plain", ["--no-denoise"], {}), ("mean", [], {})]
    variants += [(f"mean r {r}", [], {"DIRECTIONAL_RADIUS": r}) for r in a.radii or []]
    variants += [("mean estimated", [], {"DIRECTIONAL_NOISE_ESTIMATE": True})]
    before = {"DIRECTIONAL_OIDN": True, "DIRECTIONAL_NOISE_ESTIMATE": True}  # until 8e47805
    variants += [("oidn", [], before), ("oidn full", [], before | {"DIRECTIONAL_CROP": False})]
    variants += [(f"oidn pad {p}", [], before | {"CROP_PAD": p}) for p in a.pads or []]
    names = ("DIRECTIONAL_OIDN", "DIRECTIONAL_CROP", "DIRECTIONAL_RADIUS",
             "DIRECTIONAL_NOISE_ESTIMATE", "CROP_PAD")  # fmt: skip

    def module(name):
        return mosaic if name == "CROP_PAD" else denoise

    saved = {n: getattr(module(n), n) for n in names}
    for name in a.stages:
        src = REPO / "samples" / f"{name}.usda"
        if not src.is_file():
            print(f"error: {src}: no such stage", file=sys.stderr)
            return 2
        tmp = Path(tempfile.mkdtemp(prefix="usdahd-ddir-stage-"))
        try:
            shutil.copy(src, tmp)
            stage = tmp / src.name
            bake(stage, 4, 0, [])  # kernels loaded, untimed
            ta, _ = bake(stage, a.truth_spp, 1000, ["--no-denoise"])
            tb, _ = bake(stage, a.truth_spp, 1001, ["--no-denoise"])
            for spp in a.samples:
                for label, flags, attrs in variants:
                    errs, cpus = [], []
                    for seed in a.seeds:
                        for n in names:
                            setattr(module(n), n, attrs.get(n, saved[n]))
                        est, cpu = bake(stage, spp, seed, flags)
                        errs.append(errors(est, ta, tb))
                        cpus.append(cpu)
                    row = {"stage": name, "spp": spp, "variant": label,
                           "cpu": round(float(np.median(cpus)), 3)}  # fmt: skip
                    row |= {k: round(float(np.mean([e[k] for e in errs])), 3) for k in BANDS}
                    print(json.dumps(row), flush=True)
        finally:
            for n in names:
                setattr(module(n), n, saved[n])
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
