"""Rules ``IzCheck`` (decoded I_z equals the SH sidecar's within the storage tolerance) and
``EncodingError`` (hemispherical RMSE of the decode).
"""

from __future__ import annotations

import math

import numpy as np

from usdahd import models
from usdahd.numerics import sh as shm
from usdahd.validate.findings import Finding, _Rule
from usdahd.validate.loading import Bake, load_for
from usdahd.validate.options import IRRADZ, MODEL_RMSE_NOTE, OPTIONS
from usdahd.validate.texel_values import _texel

# ---------------------------------------------------------------------------- rule 4: IzCheck


#: Slack on the derived tolerance: the first-order bound ignores products of two code errors
#: (the 8-bit sh_l1 L1 = ratio x L0, at most 1/127 of the bound) and float32 evaluation.
TOLERANCE_SLACK = 0.02


def _step(codes: np.ndarray, up: bool) -> np.ndarray:
    """Each stored code moved by one code step: the next float16, or the 8-bit code +-1."""
    if codes.dtype == np.float16:
        toward = np.float16(np.inf if up else -np.inf)
        out = np.nextafter(codes, toward)
        return np.where(np.isfinite(out), out, codes).astype(np.float16)
    c = codes.astype(np.int16) + (1 if up else -1)
    return np.clip(c, 0, 255).astype(codes.dtype)


def _at_z(bake: Bake, channels: dict) -> np.ndarray:
    """Decoded I(n = z) (n, 3) float64 of stored channels (as an engine computes it)."""
    params = bake.mod.decode(channels, ratio=bake.results.ratio, factors=bake.factors)
    z = np.zeros((len(bake.xy), 3))
    z[:, 2] = 1.0
    return bake.mod.evaluate(params, z).astype(np.float64)


def quantization_tolerance(bake: Bake, got: np.ndarray | None = None) -> np.ndarray:
    """Per texel and colour, how far the decoded I(z) may lie from the unquantized fit: (n, 3).

    Derived from the storage, not guessed: every stored code c_j is the rounding of the exact
    value to the nearest code (half a code step away at most), so to first order
    ``|I(z) - I_exact(z)| <= sum_j 0.5 |I(z; c_j + 1 step) - I(z)|`` (the larger of the two
    one-sided differences). One step is the next float16 (an ULP, 2^-11 relative at most, times
    the decode scale) or one 8-bit code; every channel of every texture enters, so a model
    whose I(z) involves several coefficients or an 8-bit direction gets the sum of their
    quantization errors at z. Plus TOLERANCE_SLACK of that. docs/validate.md, IzCheck.
    """
    base = _at_z(bake, bake.channels) if got is None else got
    tol = np.zeros_like(base)
    for role, codes in bake.channels.items():
        lay = bake.layout[role]
        for j, code in enumerate(lay.codes):
            if code == "reserved":
                continue
            worst = np.zeros_like(base)
            for up in (True, False):
                moved = dict(bake.channels)
                c = codes.copy()
                c[:, j] = _step(codes[:, j], up)
                moved[role] = c
                with np.errstate(all="ignore"):
                    diff = np.abs(_at_z(bake, moved) - base)
                worst = np.maximum(worst, np.where(np.isfinite(diff), diff, 0.0))
            tol += 0.5 * worst
    return tol * (1.0 + TOLERANCE_SLACK)


def check_iz(prim) -> list[Finding]:
    """Rule IzCheck (see RULES)."""
    r = _Rule("IzCheck", prim)
    bake = load_for(r, prim, sidecar=" (see SchemaValues)")
    if bake is None:
        return r.out
    res = bake.results
    z = np.array([0.0, 0.0, 1.0])
    with np.errstate(all="ignore"):
        got = _at_z(bake, bake.channels)
        if res.model in IRRADZ:
            ref = np.maximum(shm.iz(bake.sh), 0.0)  # the fit stores max(I_z, 0) (SH ringing)
            what = "I_z"
        else:
            fitted = models.fit(bake.sh, res.model, ratio=res.ratio, solver=res.solver or None)
            params = models.representable(fitted, bake.mod)
            zz = np.broadcast_to(z, bake.sh.shape[:-2] + (3,))
            ref = bake.mod.evaluate(params, zz).astype(np.float64)
            what = f"{res.model} irradiance at n = z"
        allowed = quantization_tolerance(bake, got)
    if OPTIONS.iz_tolerance is not None:  # --tolerance: a plain relative tolerance instead
        allowed = np.broadcast_to(
            float(OPTIONS.iz_tolerance) * np.abs(ref).max(axis=1, keepdims=True), ref.shape
        )
    # Texels TexelValues rejects (non-finite values, d_z below the floor) are its findings.
    ok = bake.valid & np.isfinite(got).all(axis=1) & np.isfinite(ref).all(axis=1)
    n_skip = int((~ok).sum())
    if not ok.any():
        r.skipped("no texel decodes to finite values (TexelValues)")
        return r.out
    err = np.where(ok[:, None], np.abs(got - ref), 0.0)
    # Relative figures against the texel's brightest channel (a black channel next to a bright
    # one is judged relative to the bright one).
    denom = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1e-30)
    relerr = err / denom
    lit = ok & (denom[:, 0] > 1e-6 * denom[ok].max())  # texels bright enough for a ratio
    reltol = np.where(lit[:, None], allowed / denom, 0.0)
    fail = ok & (err > allowed).any(axis=1)
    ratio = np.where(
        allowed > 0, err / np.where(allowed > 0, allowed, 1.0), np.where(err > 0, np.inf, 0.0)
    )
    worst = int(np.argmax(ratio.max(axis=1))) if fail.any() else int(np.argmax(relerr.max(axis=1)))
    x, y = _texel(bake, worst)
    stats = dict(
        texels=int(ok.sum()),
        failing=int(fail.sum()),
        max_relative=float(relerr.max()),
        mean_relative=float(relerr[ok].mean()),
        worst_texel=(x, y),
        tolerance=float(reltol[lit].max()) if lit.any() else 0.0,
        tolerance_median=float(np.median(reltol[lit].max(axis=1))) if lit.any() else 0.0,
        worst_error_over_tolerance=float(ratio[ok].max()),
        skipped_nonfinite=n_skip,
    )
    summary = (
        f"{what} vs the SH sidecar over {stats['texels']} covered texels: max relative error "
        f"{stats['max_relative']:.3g}, mean {stats['mean_relative']:.3g}, worst at texel "
        f"({x}, {y}); tolerance from the quantization up to {stats['tolerance']:.3g} relative "
        f"(median {stats['tolerance_median']:.3g}), worst error "
        f"{stats['worst_error_over_tolerance']:.3g} of it"
    )
    if fail.any():
        r.error(
            "IzMismatch",
            f"{stats['failing']} texel(s) exceed the tolerance: {summary}",
            "re-bake the prim; a texture was edited, corrupted or written with another "
            "quantization than the schema declares",
            **stats,
        )
    else:
        r.info("IzOk", summary, **stats)
    return r.out


# ---------------------------------------------------------------------- rule 5: EncodingError


def _relative_rmse(got: np.ndarray, ref: np.ndarray, scale: np.ndarray):
    """(per texel (n,), whole prim) RMSE of got - ref (n, d, 3) relative to ``scale`` (n,)."""
    sq = ((got - ref) ** 2).mean(axis=(1, 2))
    per_texel = np.sqrt(sq) / np.where(scale > 0, scale, np.inf)
    return per_texel, float(np.sqrt(sq.mean()) / max(float(scale.mean()), 1e-30))


def check_encoding_error(prim) -> list[Finding]:
    """Rule EncodingError (see RULES and docs/validate.md).

    Three hemispherical RMSEs over OPTIONS.rmse_normals upper-hemisphere normals (spherical
    Fibonacci), each relative to the mean |SH irradiance| over those normals and texels:
    ``relative_rmse`` decoded textures vs the SH irradiance (what a renderer gets), ``model_rmse``
    the unquantized refit vs the SH irradiance (the model's own approximation error, a note:
    a model choice, not a defect), ``quantization_rmse`` decoded vs the unquantized refit (what
    the textures add). Warns when the quantization part exceeds OPTIONS.rmse_warning.
    """
    r = _Rule("EncodingError", prim)
    bake = load_for(r, prim, sidecar="")
    if bake is None:
        return r.out
    idx = np.nonzero(bake.valid & np.isfinite(bake.sh).all(axis=(1, 2)))[0]
    if idx.size == 0:
        r.skipped("no valid covered texel")
        return r.out
    if idx.size > OPTIONS.rmse_max_texels:
        idx = idx[np.linspace(0, idx.size - 1, OPTIONS.rmse_max_texels).astype(np.int64)]
    dirs = shm.fibonacci_sphere(OPTIONS.rmse_normals, hemisphere=True)
    sh = bake.sh[idx]
    params = {k: v[idx] for k, v in bake.params.items()}
    res = bake.results
    with np.errstate(all="ignore"):
        target = shm.irradiance(sh[:, None], dirs[None])  # (n, d, 3)
        normals = np.broadcast_to(dirs, (idx.size,) + dirs.shape)
        got = bake.mod.evaluate(params, normals).astype(np.float64)
        fitted = models.fit(sh, res.model, ratio=res.ratio, solver=res.solver or None)
        exact = bake.mod.evaluate(models.representable(fitted, bake.mod), normals)
        exact = exact.astype(np.float64)
    scale = np.abs(target).mean(axis=(1, 2))
    per_texel, total = _relative_rmse(got, target, scale)
    _, model_total = _relative_rmse(exact, target, scale)
    q_texel, q_total = _relative_rmse(got, exact, scale)
    worst = int(np.argmax(per_texel))
    x, y = int(bake.xy[idx[worst], 0]), int(bake.xy[idx[worst], 1])
    qw = int(np.argmax(np.where(np.isfinite(q_texel), q_texel, 0.0)))
    stats = dict(
        texels=int(idx.size),
        relative_rmse=total,
        model_rmse=model_total,
        quantization_rmse=q_total,
        texel_relative_rmse_mean=float(per_texel.mean()),
        texel_relative_rmse_max=float(per_texel.max()),
        texel_quantization_rmse_max=float(q_texel.max()),
        worst_texel=(x, y),
        threshold=OPTIONS.rmse_warning,
    )
    msg = (
        f"{res.model} ({res.ratio}) decoded vs SH irradiance over "
        f"{OPTIONS.rmse_normals} hemisphere normals and {idx.size} texels: relative RMSE "
        f"{total:.3g} (model fit {model_total:.3g}, quantization {q_total:.3g}); per texel mean "
        f"{stats['texel_relative_rmse_mean']:.3g}, max {stats['texel_relative_rmse_max']:.3g} "
        f"at texel ({x}, {y})"
    )
    if res.model in IRRADZ:
        # Texels lit from below their tangent plane: I_z <= 0 while the hemisphere is lit;
        # an IrradZ model stores max(I_z, 0) and decodes them black.
        below = (shm.iz(sh).max(axis=1) <= 0.0) & (scale > 0)
        stats["below_horizon_texels"] = int(below.sum())
    loose = (
        model_total > MODEL_RMSE_NOTE
        or total > OPTIONS.model_rmse_warning
        or float(np.mean(~(per_texel <= OPTIONS.model_rmse_warning))) > OPTIONS.model_texel_share
    )
    advice = _closer_models(sh, target, scale, res.model, model_total) if loose else ""
    if not math.isfinite(q_total) or q_total > OPTIONS.rmse_warning:
        qx, qy = int(bake.xy[idx[qw], 0]), int(bake.xy[idx[qw], 1])
        r.warning(
            "HighEncodingError",
            f"{msg}; the textures add {q_total:.3g} to the model's own fit (worst texel "
            f"({qx}, {qy})), above the {OPTIONS.rmse_warning:g} threshold",
            "check the textures decode as docs/schema.md says (channel order, biases, scale "
            "factors), or re-bake the prim",
            **stats,
        )
    over = float(np.mean(~(per_texel <= OPTIONS.model_rmse_warning)))  # NaN counts as over
    stats["texel_share_above_warning"] = over
    if (
        not math.isfinite(total)
        or total > OPTIONS.model_rmse_warning
        or over > OPTIONS.model_texel_share
    ):
        below = stats.get("below_horizon_texels", 0)
        why = (
            f"; {below} of {idx.size} texels receive their light from below their tangent "
            f"plane (I_z <= 0), which {res.model} stores as 0 and decodes black"
            if below
            else ""
        )
        r.warning(
            "HighModelError",
            f"{msg}: the decoded irradiance is off by more than its own mean (relative RMSE "
            f"above {OPTIONS.model_rmse_warning:g}) on the prim or on {100 * over:.3g}% of its "
            f"texels (more than {100 * OPTIONS.model_texel_share:g}%), so the shading a "
            f"renderer gets from this bake is wrong there{why}{advice}",
            "re-bake the prim with a model that fits its lighting"
            + (" (see above)" if advice else "")
            + "; if light reaches it from below its surface, check the mesh's normals and "
            "for light leaking through thin geometry",
            **stats,
        )
    elif math.isfinite(q_total) and q_total <= OPTIONS.rmse_warning:
        hint = ""
        if model_total > MODEL_RMSE_NOTE:
            hint = f"; the model fits this lighting loosely (above {MODEL_RMSE_NOTE:g})" + (
                advice or ""
            )
        r.info("EncodingError", msg + hint, **stats)
    return r.out


#: Models the EncodingError advice measures against the bake's model (never the model in use):
#: sh_l2 represents the sidecar's irradiance exactly (both are L2 SH), hhd is the default
#: directional model.
ADVICE_MODELS = ("sh_l2", "hhd")
#: Texels the advice refits (evenly spaced among the rule's texels): cheap next to the rule.
ADVICE_TEXELS = 512
#: A model is said to fit closer when its relative RMSE is below this fraction of the bake's.
ADVICE_FRACTION = 0.8


def _closer_models(sh, target, scale, model: str, model_rmse: float) -> str:
    """'; measured on N of these texels, M (x) fits closer' for every ADVICE_MODELS entry other
    than ``model`` whose unquantized fit has a relative RMSE below ADVICE_FRACTION of the
    bake's model on the same texels; '' when none does (no model is recommended unmeasured)."""
    n = len(sh)
    pick = np.linspace(0, n - 1, min(n, ADVICE_TEXELS)).astype(np.int64)
    sub, tgt, sc = sh[pick], target[pick], scale[pick]
    dirs = shm.fibonacci_sphere(OPTIONS.rmse_normals, hemisphere=True)
    normals = np.broadcast_to(dirs, (len(pick),) + dirs.shape)
    found = {}
    for name in (model, *ADVICE_MODELS):
        if name in found:
            continue
        try:
            mod = models.get(name)
            with np.errstate(all="ignore"):
                fitted = models.fit(sub, name)
                got = mod.evaluate(models.representable(fitted, mod), normals)
            found[name] = _relative_rmse(got.astype(np.float64), tgt, sc)[1]
        except Exception:  # a model that cannot be fitted here is not advised
            continue
    own = found.get(model, model_rmse)
    closer = [
        f"{m} ({v:.3g})"
        for m, v in found.items()
        if m != model and math.isfinite(v) and v < ADVICE_FRACTION * own
    ]
    if not closer:
        return ""
    return (
        f"; measured on {len(pick)} of these texels ({model} {own:.3g}): "
        f"{' and '.join(closer)} {'fits' if len(closer) == 1 else 'fit'} closer"
    )
