"""Fitting speed and error per model x solver (section 2) and the encodings side by side on baked
scenes after quantization (section 3, like Roughton et al. 2024, Figure 5).

Errors are relative hemispherical RMSE against the SH irradiance target (see common.py). Fit
speed is ``usdahd.fit`` end to end (validation, normalisation, solve, float32 outputs) on a
tiled sky+sun set, median of repeats after a warm-up call (numba kernels compiled/cached).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from common import (
    PLOTS,
    bytes_per_texel,
    hemi_errors,
    log,
    md_table,
    median,
    pyplot,
    relative_rmse,
    roundtrip,
    save_figure,
    texels_of,
    timed,
    variants,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import make_sample_sh as envs  # noqa: E402

from usdahd import models  # noqa: E402
from usdahd.numerics import sh as shm  # noqa: E402


def fit_cases() -> list[tuple[str, str, str]]:
    """Every (model, solver) of the registry with the model's default (first) ratio."""
    return [
        (name, models.get(name).RATIOS[0], solver)
        for name in models.names()
        for solver in models.get(name).SOLVERS
    ]


def synthetic_families(texels: int) -> dict:
    """benchmarks/make_sample_sh.py's environment families, ``texels`` each."""
    return {name: fn(texels) for name, fn in envs.FAMILIES.items()}


#: Target seconds per speed measurement: slow solvers are timed on fewer texels.
SPEED_SECONDS = 2.0
#: Never time fewer texels than this (per-call overheads would dominate).
SPEED_MIN_TEXELS = 5000


def fit_speed(model, ratio, solver, data, repeats) -> tuple[float, int]:
    """(texels/s, texels timed) of usdahd.fit: median of ``repeats`` after a warm-up call;
    slow solvers are timed on fewer texels (about SPEED_SECONDS per call)."""
    _, t = timed(models.fit, data[:2000], model, ratio=ratio, solver=solver)  # warm-up, probe
    n = int(np.clip(2000 / max(t, 1e-9) * SPEED_SECONDS, SPEED_MIN_TEXELS, len(data)))
    x = data[:n]
    secs = [timed(models.fit, x, model, ratio=ratio, solver=solver)[1] for _ in range(repeats)]
    return n / median(secs), n


def fit_table(families: dict, *, speed_texels: int, repeats: int, cases=None) -> dict:
    """Section 2: per model x solver, texels/s and mean per-texel relative hemispherical RMSE
    on each family (the ``black`` family reports max |output| instead: it must be 0).

    families : name -> (n, 3, 9) SH (synthetic families plus e.g. "baked samples").
    returns : dict(families [names], rows [dict(model, ratio, solver, texels_per_s, errors)]).
    """
    base = families.get("sky+sun")
    if base is None:
        base = next(iter(families.values()))
    speed_data = np.tile(base, (speed_texels // len(base) + 1, 1, 1))[:speed_texels]
    rows = []
    for model, ratio, solver in cases or fit_cases():
        rate, timed_texels = float("nan"), 0
        if repeats:
            rate, timed_texels = fit_speed(model, ratio, solver, speed_data, repeats)
        errors = {}
        for name, data in families.items():
            p = models.fit(data, model, ratio=ratio, solver=solver).params
            if name == "black":
                z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(data), 3))
                errors[name] = float(np.abs(models.get(model).evaluate(p, z)).max())
                continue
            err, energy = hemi_errors(model, p, data)
            errors[name] = relative_rmse(err, energy)[1]
        rows.append(
            {
                "model": model,
                "ratio": ratio,
                "solver": solver,
                "texels_per_s": rate,
                "timed_texels": timed_texels,
                "errors": errors,
            }
        )
        log(f"fit {model:12} {solver:12} {rate / 1e6:7.2f} Mtexel/s")
    return {"families": list(families), "rows": rows}


def fit_markdown(result: dict) -> str:
    fams = result["families"]
    heads = ["model", "solver", "Mtexel/s", "timed on"] + [
        "black: max abs" if f == "black" else f for f in fams
    ]
    rows = [
        [r["model"], r["solver"], r["texels_per_s"] / 1e6, r["timed_texels"]]
        + [r["errors"][f] for f in fams]
        for r in result["rows"]
    ]
    return md_table(heads, rows)


# ---------------------------------------------------------------------------------- encodings


def encodings_table(baked_scenes: dict, variant_list=None) -> dict:
    """Section 3: per (model, ratio), bytes/texel and relative hemispherical RMSE per scene,
    before and after quantization; fit with the model's default solver, one prim at a time
    (decode factors are per texture, as in a bake).

    baked_scenes : scene -> {prim: (sh (h,w,3,9), covered (h,w))} (common.read_baked_sh).
    returns : dict(scenes, rows [dict(model, ratio, bytes, exact {scene: rmse},
    quantized {scene: rmse}, iz_max {scene: max rel I_z error after quantization})],
    maps {(model, ratio): {scene: {prim: (h,w) per-texel relative RMSE after quantization}}}).
    """
    rows, maps = [], {}
    for model, ratio in variant_list or variants():
        mod = models.get(model)
        row = {
            "model": model,
            "ratio": ratio,
            "bytes": bytes_per_texel(model, ratio),
            "exact": {},
            "quantized": {},
            "iz_max": {},
        }
        maps[(model, ratio)] = {}
        for scene, baked in baked_scenes.items():
            e_ex, e_q, en, iz_err = [], [], [], []
            maps[(model, ratio)][scene] = {}
            for prim, (img, mask) in baked.items():
                sh = img[mask].astype(np.float64)
                p = models.fit(sh, model, ratio=ratio).params
                dec = roundtrip(model, p, ratio)
                a, energy = hemi_errors(model, p, sh)
                b, _ = hemi_errors(model, dec, sh)
                e_ex.append(a)
                e_q.append(b)
                en.append(energy)
                z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(sh), 3))
                want = shm.iz(sh)
                got = np.asarray(mod.evaluate(dec, z), np.float64)
                scale = np.maximum(np.abs(want).max(-1), 1e-30)
                iz_err.append(np.abs(got - want).max(-1) / scale)
                m = np.full(mask.shape, np.nan)
                m[mask] = np.sqrt(b / np.where(energy > 0, energy, 1.0))
                maps[(model, ratio)][scene][prim] = m
            en = np.concatenate(en)
            row["exact"][scene] = relative_rmse(np.concatenate(e_ex), en)[0]
            row["quantized"][scene] = relative_rmse(np.concatenate(e_q), en)[0]
            row["iz_max"][scene] = float(np.concatenate(iz_err).max())
        rows.append(row)
        log(f"encoding {model:12} {ratio:9} done")
    return {"scenes": list(baked_scenes), "rows": rows, "maps": maps}


def encodings_markdown(result: dict) -> str:
    scenes = result["scenes"]
    heads = (
        ["model", "ratio", "bytes/texel"]
        + [f"{s} (quantized)" for s in scenes]
        + ["mean, unquantized", "mean, quantized", "max I_z error after quantization"]
    )
    rows = []
    for r in result["rows"]:
        rows.append(
            [r["model"], r["ratio"], r["bytes"]]
            + [r["quantized"][s] for s in scenes]
            + [
                float(np.mean(list(r["exact"].values()))),
                float(np.mean(list(r["quantized"].values()))),
                max(r["iz_max"].values()),
            ]
        )
    return md_table(heads, rows)


def error_maps_plot(result, scene, prim, reference_iz, name="encoding_errors.png", plots_dir=PLOTS):
    """False-colour per-texel relative error (after quantization) of every encoding for one
    prim of one scene, next to the reference I_z; shared log colour scale."""
    plt = pyplot()
    from matplotlib.colors import LogNorm

    keys = [k for k in result["maps"] if k[1] in ("luminance", "none", "linear")]
    n = len(keys) + 1
    cols = 5
    nrows = (n + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(2.3 * cols, 2.45 * nrows), squeeze=False)
    ax0 = axes.flat[0]
    im0 = ax0.imshow(reference_iz, cmap="gray", interpolation="nearest")
    ax0.set_title("reference I_z (lum.)", fontsize=8)
    fig.colorbar(im0, ax=ax0, fraction=0.046, pad=0.04).ax.tick_params(labelsize=6)
    norm = LogNorm(vmin=1e-4, vmax=1.0)
    im = None
    for ax, key in zip(list(axes.flat)[1:], keys):
        m = result["maps"][key][scene][prim]
        im = ax.imshow(np.clip(m, 1e-4, 1.0), cmap="inferno", norm=norm, interpolation="nearest")
        mean = np.nanmean(m)
        ax.set_title(f"{key[0]}  (mean {mean:.3f})", fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    if im is not None:
        fig.colorbar(im, ax=list(axes.flat), fraction=0.02, pad=0.01, label="relative RMSE")
    fig.suptitle(f"{scene} {prim}: per-texel hemispherical error after quantization", fontsize=10)
    return save_figure(fig, name, plots_dir)


def encodings_plot(result: dict, name: str = "encodings.png", plots_dir=PLOTS):
    """Mean quantized error per (model, ratio), sorted, with its bytes per texel."""
    plt = pyplot()
    rows = sorted(result["rows"], key=lambda r: -float(np.mean(list(r["quantized"].values()))))
    fig, ax = plt.subplots(figsize=(6.4, 0.28 * len(rows) + 1.0))
    ys = np.arange(len(rows))
    vals = [max(float(np.mean(list(r["quantized"].values()))), 1e-7) for r in rows]
    ax.barh(ys, vals, color="tab:blue", alpha=0.8)
    ax.set_yticks(ys, [f"{r['model']} {r['ratio']} ({r['bytes']} B)" for r in rows], fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("relative hemispherical RMSE after quantization (mean over the samples)")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    ax.set_title("Encodings on the baked samples (bytes per texel in brackets)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, name, plots_dir)


def baked_family(baked_scenes: dict, texels: int, seed: int = 0) -> np.ndarray:
    """Up to ``texels`` real baked texels drawn from every scene (fixed seed)."""
    data = np.concatenate([texels_of(b) for b in baked_scenes.values()]).astype(np.float64)
    if len(data) > texels:
        data = data[np.random.default_rng(seed).choice(len(data), texels, replace=False)]
    return data
