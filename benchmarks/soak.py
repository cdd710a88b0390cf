"""Soak: many random and adversarial radiance SH texels through every model (fit -> encode ->
decode -> evaluate), counting non-finite values (must be 0) and the worst I_z error.

Texel categories (equal shares, deterministic in ``seed``):

- ``physical``: 1-4 delta lights above the horizon (random RGB power 0..10) plus a uniform sky
  0..1, i.e. non-negative hemispherical radiance at unit scale;
- ``scale 1e-30..1e30``: ``physical`` times 10^U(-30, 30) per texel (float32-representable);
- ``beyond float32``: ``physical`` times 10^±U(39, 300) (finite float64, outputs overflow or
  underflow float32: only finiteness is checked);
- ``horizon``: one delta light 1e-7..1e-2 rad above the tangent horizon;
- ``float16 input``: ``physical`` times 10^U(-3, 3) stored as float16;
- ``negative lobes``: ``physical`` plus a delta of negative power (ringing, leaks);
- ``random SH``: N(0, 1) coefficients (lower-hemisphere content, negative radiance);
- ``black / denormal``: zeros, -0.0 and 1e-310 entries;
- ``NaN/Inf``: ``physical`` with 1-3 coefficients set to NaN, +Inf or -Inf.

A texel counts as *non-finite* when any fitted parameter, decoded parameter or evaluated
irradiance (at z, at a normal 1e-6 above the horizon and at a random upper-hemisphere normal)
is NaN or Inf. The I_z error is |I(z) - I_z| / max_c |I_z| per texel (I_z = ``sh.iz`` of the
input); "unquantized" is the fitted model over the non-negative, float32-representable
categories (physical, scale, horizon, float16), "quantized" is after encode -> decode on
``physical`` only (decode factors such as izScale are per texture, i.e. per chunk here, so
mixed-scale chunks would measure float16 range, not the model).
"""

from __future__ import annotations

import time

import numpy as np
from common import log, md_table, variants

from usdahd import models
from usdahd.numerics import sh as shm

CATEGORIES = (
    "physical",
    "scale 1e-30..1e30",
    "beyond float32",
    "horizon",
    "float16 input",
    "negative lobes",
    "random SH",
    "black / denormal",
    "NaN/Inf",
)
#: Categories whose I_z error is measured before quantization (non-negative, representable).
IZ_EXACT_CATEGORIES = ("physical", "scale 1e-30..1e30", "horizon", "float16 input")
#: Largest chunk pushed through a model at once (memory: ~100 MB per chunk).
CHUNK = 125_000
_Z = np.array([0.0, 0.0, 1.0])


def _uniform_sky_sh() -> np.ndarray:
    """SH (9,) of radiance 1 over the upper hemisphere, 0 below (exact quadrature)."""
    d, w = shm.hemisphere_quadrature(8)
    return np.einsum("nk,n->k", shm.basis(d), w)


def _upper_dirs(rng, n, zmin=0.0):
    z = rng.uniform(zmin, 1.0, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(ph), s * np.sin(ph), z], -1)


def physical(rng, n) -> np.ndarray:
    """Delta lights + uniform sky: (n, 3, 9) float64, non-negative hemispherical radiance."""
    out = rng.uniform(0, 1, (n, 3, 1)) * _uniform_sky_sh()
    count = rng.integers(1, 5, n)
    for j in range(4):
        power = rng.uniform(0, 10, (n, 3)) * (j < count)[:, None]
        out += power[:, :, None] * shm.basis(_upper_dirs(rng, n))[:, None, :]
    return out


def texels(category: str, n: int, seed: int = 0) -> np.ndarray:
    """``n`` texels of one category: (n, 3, 9), float64 (float16 for ``float16 input``)."""
    rng = np.random.default_rng([seed, CATEGORIES.index(category)])
    if category == "physical":
        return physical(rng, n)
    if category == "scale 1e-30..1e30":
        return physical(rng, n) * 10.0 ** rng.uniform(-30, 30, (n, 1, 1))
    if category == "beyond float32":
        exp = rng.uniform(39, 300, (n, 1, 1)) * rng.choice([-1.0, 1.0], (n, 1, 1))
        return physical(rng, n) * 10.0**exp
    if category == "horizon":
        el = 10.0 ** rng.uniform(-7, -2, n)
        az = rng.uniform(0, 2 * np.pi, n)
        s = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
        return rng.uniform(0.1, 10, (n, 3, 1)) * shm.basis(s)[:, None, :]
    if category == "float16 input":
        return (physical(rng, n) * 10.0 ** rng.uniform(-3, 3, (n, 1, 1))).astype(np.float16)
    if category == "negative lobes":
        x = physical(rng, n)
        power = -rng.uniform(0, 20, (n, 3))
        return x + power[:, :, None] * shm.basis(_upper_dirs(rng, n))[:, None, :]
    if category == "random SH":
        return rng.normal(size=(n, 3, 9))
    if category == "black / denormal":
        x = np.zeros((n, 3, 9))
        kind = rng.integers(0, 3, n)
        x[kind == 1] = -0.0
        x[kind == 2] = 1e-310 * rng.uniform(0, 1, (int((kind == 2).sum()), 3, 9))
        return x
    if category == "NaN/Inf":
        x = physical(rng, n).reshape(n, 27)
        bad = np.array([np.nan, np.inf, -np.inf])
        for _ in range(3):
            rows = np.flatnonzero(rng.uniform(size=n) < 0.6)
            x[rows, rng.integers(0, 27, rows.size)] = bad[rng.integers(0, 3, rows.size)]
        return x.reshape(n, 3, 9)
    raise ValueError(category)


def _nonfinite_rows(*arrays_by_texel) -> np.ndarray:
    """(n,) bool: any non-finite value in any of the arrays (leading axis = texel)."""
    bad = None
    for a in arrays_by_texel:
        a = np.asarray(a)
        row = ~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
        bad = row if bad is None else bad | row
    return bad


def run_variant(model: str, ratio: str, data: dict) -> dict:
    """One (model, ratio) with its default solver over every category's texels."""
    mod = models.get(model)
    warm = data[next(iter(data))][:100]  # numba kernels load/compile outside the timing
    ch, fac = mod.encode(models.fit(warm, model, ratio=ratio).params, ratio=ratio)
    mod.decode(ch, ratio=ratio, factors=fac)
    t0 = time.perf_counter()
    nonfinite, where = {}, {}
    worst_exact, worst_quant = 0.0, 0.0
    total = 0
    for cat, x in data.items():
        bad_count = 0
        stages = {}
        for a in range(0, len(x), CHUNK):
            xc = x[a : a + CHUNK]
            n = len(xc)
            total += n
            params = models.fit(xc, model, ratio=ratio).params
            channels, factors = mod.encode(params, ratio=ratio)
            dec = mod.decode(channels, ratio=ratio, factors=factors)
            z = np.broadcast_to(_Z, (n, 3))
            rng = np.random.default_rng(a)
            normals = np.stack(
                [
                    np.broadcast_to(_Z, (n, 3)),
                    np.broadcast_to(np.array([np.sqrt(1 - 1e-12), 0.0, 1e-6]), (n, 3)),
                    _upper_dirs(rng, n),
                ],
                axis=1,
            )
            out_dec = mod.evaluate(dec, normals)
            out_raw = mod.evaluate(params, z)
            bad_fit = _nonfinite_rows(*params.values())
            bad_dec = _nonfinite_rows(*dec.values()) & ~bad_fit
            bad_eval = _nonfinite_rows(out_dec, out_raw) & ~(bad_fit | bad_dec)
            for stage, bad in (("fit", bad_fit), ("decode", bad_dec), ("evaluate", bad_eval)):
                stages[stage] = stages.get(stage, 0) + int(bad.sum())
                bad_count += int(bad.sum())
            if cat in IZ_EXACT_CATEGORIES or cat == "physical":
                want = shm.iz(xc.astype(np.float64))
                scale = np.maximum(np.abs(want).max(-1), 1e-300)
                if cat in IZ_EXACT_CATEGORIES:
                    e = np.abs(np.asarray(out_raw, np.float64) - want).max(-1) / scale
                    worst_exact = max(worst_exact, float(np.nanmax(e)))
                if cat == "physical":
                    e = np.abs(np.asarray(out_dec[:, 0], np.float64) - want).max(-1) / scale
                    worst_quant = max(worst_quant, float(np.nanmax(e)))
        nonfinite[cat] = bad_count
        if bad_count:
            where[cat] = {k: v for k, v in stages.items() if v}
    seconds = time.perf_counter() - t0
    return {
        "model": model,
        "ratio": ratio,
        "solver": mod.DEFAULT_SOLVER,
        "texels": total,
        "nonfinite": nonfinite,
        "nonfinite_total": int(sum(nonfinite.values())),
        "nonfinite_where": where,
        "iz_worst_exact": worst_exact,
        "iz_worst_quantized": worst_quant,
        "seconds": seconds,
    }


def soak(n_texels: int, *, seed: int = 0, variant_list=None) -> dict:
    """Push at least ``n_texels`` (split evenly over CATEGORIES) through every (model, ratio).

    returns : dict(texels, categories, rows [run_variant() results]).
    """
    per = max(1, -(-n_texels // len(CATEGORIES)))  # at least n_texels in all
    data = {cat: texels(cat, per, seed) for cat in CATEGORIES}
    rows = []
    for model, ratio in variant_list or variants():
        rows.append(run_variant(model, ratio, data))
        r = rows[-1]
        log(
            f"soak {model:12} {ratio:9} non-finite {r['nonfinite_total']} "
            f"I_z worst {r['iz_worst_exact']:.2e}/{r['iz_worst_quantized']:.2e} "
            f"{r['seconds']:.1f}s"
        )
    return {"texels": per * len(CATEGORIES), "categories": list(CATEGORIES), "rows": rows}


def soak_markdown(result: dict) -> str:
    rows = []
    for r in result["rows"]:
        where = (
            "; ".join(
                f"{c}: " + ", ".join(f"{k} in {stage}" for stage, k in st.items())
                for c, st in r["nonfinite_where"].items()
            )
            or "-"
        )
        rows.append(
            [
                r["model"],
                r["ratio"],
                r["solver"],
                r["texels"],
                r["nonfinite_total"],
                where,
                r["iz_worst_exact"],
                r["iz_worst_quantized"],
                r["texels"] / r["seconds"] / 1e6,
            ]
        )
    return md_table(
        [
            "model",
            "ratio",
            "solver",
            "texels",
            "non-finite",
            "in",
            "worst I_z error (fit)",
            "worst I_z error (quantized)",
            "Mtexel/s (fit+codec+eval)",
        ],
        rows,
    )
