"""IrradZ model x solver benchmark: speed and hemispherical error on environment families.

    PYTHONPATH=. python benchmarks/fit.py [--texels 2000] [--speed-texels 200000] [--quick]

Errors (per texel, then the mean over texels of a family; relative so that HDR scales compare):

- ``sh``    SH-domain error, what the solvers minimise (2024 §4.1): sqrt((m - t)^T G (m - t))
            / sqrt(t^T G t) summed over RGB, m = the model's band-2 irradiance SH, t = the
            target's, G the hemispherical Gram matrix.
- ``eval``  the model as engines evaluate it (with its max()) against the SH irradiance target,
            L2 over the hemisphere by Gauss-Legendre quadrature, relative likewise.
- ``quant`` ``eval`` after encode -> decode (float16 I_z, 8-bit direction and ratio).

Black texels have no relative error: the table reports the max |output| instead (must be 0).
Speed: texels/s of ``usdahd.fit`` end to end (normalisation, solve, outputs) on a tiled sky+sun
set, median of 3 runs after a warm-up (numba compiled and cached), all cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import make_sample_sh as envs  # noqa: E402

from usdahd import models  # noqa: E402
from usdahd import sh as shm  # noqa: E402
from usdahd.models import _irradz  # noqa: E402

CASES = [
    ("ahd", "2018_sphere"),
    ("ahd", "2018_hemi"),
    ("ahd", "golden"),
    ("ahd", "golden_phi"),
    ("hhd", "2018_sphere"),
    ("hhd", "2018_hemi"),
    ("hhd", "golden"),
    ("hhd", "golden_phi"),
    ("hhd", "direct"),
    ("hlsh", "direct"),
]


def rel_sh_error(kind, sh, params):
    g = _irradz.gram_hemi()
    e = _irradz.sh_error(kind, sh, params).sum(-1)
    t = sh * shm.COSINE_FACTORS
    tt = np.einsum("nck,kl,ncl->n", t, g, t)
    return np.sqrt(e / np.where(tt > 0, tt, 1.0))


def rel_eval_error(kind, sh, params, quad=(12, 24)):
    d, w = shm.hemisphere_quadrature(*quad)
    target = shm.irradiance(sh[:, None], d[None])  # (n, m, 3)
    got = models.get(kind).evaluate(params, np.broadcast_to(d, (sh.shape[0],) + d.shape))
    e = np.einsum("nmc,m->n", (got - target) ** 2, w)
    t = np.einsum("nmc,m->n", target**2, w)
    return np.sqrt(e / np.where(t > 0, t, 1.0))


def roundtrip(kind, params, ratio):
    mod = models.get(kind)
    ch, factors = mod.encode(params, ratio=ratio)
    return mod.decode(ch, ratio=ratio, factors=factors)


def speed(kind, solver, ratio, data, repeats=3):
    models.fit(data[:1000], kind, ratio=ratio, solver=solver)  # warm-up / compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        models.fit(data, kind, ratio=ratio, solver=solver)
        times.append(time.perf_counter() - t0)
    return data.shape[0] / float(np.median(times))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--texels", type=int, default=2000, help="texels per family (default 2000)")
    ap.add_argument("--speed-texels", type=int, default=200_000)
    ap.add_argument("--ratio", default=None, choices=["luminance", "rgb"], help="default both")
    ap.add_argument("--quick", action="store_true", help="no speed measurement")
    args = ap.parse_args(argv)

    fams = {name: fn(args.texels) for name, fn in envs.FAMILIES.items()}
    speed_data = np.tile(fams["sky+sun"], (args.speed_texels // args.texels + 1, 1, 1))
    speed_data = speed_data[: args.speed_texels]
    ratios = [args.ratio] if args.ratio else ["luminance", "rgb"]
    sh_err = {}
    for ratio in ratios:
        print(
            f"\nratio={ratio}, {args.texels} texels per family; mean relative error sh/eval/quant"
        )
        head = f"{'model':5} {'solver':12} {'Mtexel/s':>9}  " + "  ".join(
            f"{n[:13]:>19}" for n in fams
        )
        print(head)
        for kind, solver in CASES:
            rate = 0.0 if args.quick else speed(kind, solver, ratio, speed_data) / 1e6
            cells = []
            for name, data in fams.items():
                p = models.fit(data, kind, ratio=ratio, solver=solver).params
                if name == "black":
                    m = float(np.abs(p["iz"]).max())
                    cells.append(f"{'max|out| ' + format(m, '.1g'):>19}")
                    continue
                es = rel_sh_error(kind, data, p)
                ee = rel_eval_error(kind, data, p)
                eq = rel_eval_error(kind, data, roundtrip(kind, p, ratio))
                sh_err[(ratio, kind, solver, name)] = es
                cells.append(f"{es.mean():.4f}/{ee.mean():.4f}/{eq.mean():.4f}")
            print(f"{kind:5} {solver:12} {rate:9.2f}  " + "  ".join(cells), flush=True)

    print("\nacceptance checks (SH-domain relative error, mean over texels):")
    for ratio in ratios:
        for kind in ("ahd", "hhd"):
            sph = sh_err[(ratio, kind, "2018_sphere", "sky+sun")].mean()
            gold = sh_err[(ratio, kind, "golden", "sky+sun")].mean()
            print(
                f"  {ratio:9} {kind}: 2018_sphere / golden on sky+sun = {sph / gold:.2f}x "
                "(want >= 2)"
            )
            gains = []
            for name in fams:
                if name == "black":
                    continue
                g = sh_err[(ratio, kind, "golden", name)].mean()
                gp = sh_err[(ratio, kind, "golden_phi", name)].mean()
                gains.append(1 - gp / g if g > 0 else 0.0)
            print(
                f"  {ratio:9} {kind}: golden_phi error reduction vs golden, mean over families "
                f"{100 * np.mean(gains):.2f}% (largest {100 * np.max(gains):.2f}%; want < 7%)"
            )
        for name in ("sky+sun", "hdr 1e-4..1e4"):
            dr = sh_err[(ratio, "hhd", "direct", name)].mean()
            gold = sh_err[(ratio, "hhd", "golden", name)].mean()
            print(f"  {ratio:9} hhd direct / golden on {name} = {dr / gold:.3f} (want <= ~1.10)")


if __name__ == "__main__":
    main()
