"""Rules ``IzCheck`` (decoded I_z equals the SH sidecar's within the storage tolerance) and
``EncodingError`` (hemispherical RMSE of the decode).
"""

from __future__ import annotations

import math

import numpy as np

from usdahd import models
from usdahd.numerics import sh as shm
from usdahd.numerics.stats import pooled_rmse_over_mean_abs, rmse_over_mean_abs
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import Bake, load_for
from usdahd.validate.options import IRRADZ, MODEL_RMSE_NOTE, OPTIONS
from usdahd.validate.texel_values import texel_xy

__all__ = [
    "TOLERANCE_SLACK",
    "check_encoding_error",
    "check_iz",
    "code_step",
    "decoded_iz",
    "fit_chunked",
    "quantization_tolerance",
]

# ---------------------------------------------------------------------------- rule 4: IzCheck


#: Slack on the derived tolerance: the first-order bound ignores products of two code errors
#: (the 8-bit sh_l1 L1 = ratio x L0, at most 1/127 of the bound) and float32 evaluation.
TOLERANCE_SLACK = 0.02


def code_step(codes: np.ndarray, up: bool) -> np.ndarray:
    """Each stored code moved by one code step: the next float16, or the 8-bit code +-1."""
    if np.issubdtype(codes.dtype, np.floating):
        toward = codes.dtype.type(np.inf if up else -np.inf)
        out = np.nextafter(codes, toward)
        return np.where(np.isfinite(out), out, codes).astype(codes.dtype)
    info = np.iinfo(codes.dtype)
    c = codes.astype(np.int32) + (1 if up else -1)
    return np.clip(c, info.min, info.max).astype(codes.dtype)


def check_normals() -> np.ndarray:
    """(1, 3) tangent-space normals IzCheck compares the decode at: z only, where the
    first-order quantization bound holds (measured: 0.90-0.98 of it on fresh default bakes of
    every model). Off z the bound is not rigorous (the clamp of max(0, n . d) and C_d =
    I_z (1 - w_a) / d_z are far from linear in the 8-bit direction codes: at 50 and 80 degrees
    fresh ahd and hhd bakes measured up to 1.37 of it), so the codes that I(z) does not see
    (IrradZ direction and ratio, ...) are checked by re-encoding instead (:func:`code_check`).
    """
    return np.array([[0.0, 0.0, 1.0]])


#: Relative noise added to the sidecar SH to find codes that sit on a rounding boundary (a
#: float32-level difference of the fit, e.g. another CPU's FMA, may round them either way):
#: 16x float32's epsilon.
AMBIGUITY_NOISE = 1e-6


def code_check(bake: Bake) -> tuple[dict, bool]:
    """Stored codes against the codes the model's encoder gives the sidecar SH (refit with the
    bake's ratio and solver, then ``encode``, as the baker does): role -> (n, c) bool mask of
    codes that differ and are not on a rounding boundary; and whether the check ran.

    The refit is of the float32 SH, as the baker fits it (and stores it in the sidecar), so a
    fresh bake re-encodes to the same codes bit for bit. A code on a rounding boundary (its
    re-encode changes when the SH moves by AMBIGUITY_NOISE: a scale and two seeded random
    directions, each both ways; another CPU's float rounding of the fit) may be either
    neighbour. The check needs the encoder that wrote the bake: a bake by another usdahd
    version (Staleness warns ``OtherGenerator``) is not checked this way (returns ({}, False)).
    """
    memo = bake.__dict__.get("_code_check")
    if memo is not None:
        return memo
    memo = bake.__dict__["_code_check"] = _code_check(bake)
    return memo


def refit(bake: Bake, sel=slice(None)):
    """The model refitted to the sidecar's float32 SH (what the baker fits; same ratio and
    solver), computed once per bake and shared by IzCheck and EncodingError; the texels
    ``sel`` (a slice or an index array) of it."""
    fitted = bake.__dict__.get("_refit")
    if fitted is None:
        fitted = bake.__dict__["_refit"] = fit_chunked(bake.results, bake.sh)
    if isinstance(sel, slice) and sel == slice(None):
        return fitted
    return models.Fit(
        model=fitted.model,
        ratio=fitted.ratio,
        solver=fitted.solver,
        params={k: np.asarray(v)[sel] for k, v in fitted.params.items()},
    )


def fit_chunked(res, sh: np.ndarray):
    """models.fit of the float32 SH ``sh`` (n, 3, 9) with the record's model, ratio and solver,
    CHUNK texels at a time (the fit is per texel, so the result is the same; memory stays
    O(chunk): the fit widens its input to float64)."""
    parts = []
    for a in range(0, max(len(sh), 1), CHUNK):
        with np.errstate(all="ignore"):
            parts.append(
                models.fit(
                    sh[a : a + CHUNK].astype(np.float32),
                    res.model,
                    ratio=res.ratio,
                    solver=res.solver or None,
                )
            )
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    return models.Fit(
        model=first.model,
        ratio=first.ratio,
        solver=first.solver,
        params={k: np.concatenate([p.params[k] for p in parts]) for k in first.params},
    )


def _code_check(bake: Bake) -> tuple[dict, bool]:
    from usdahd.version import __version__

    res = bake.results
    if res.generator and res.generator.split(";")[0].strip() != f"usdahd {__version__}":
        return {}, False

    from usdahd.validate.loading import record_encoder

    encode_params = record_encoder(bake)  # an atlas record: with its page's factors

    def encode(sh):
        # the float32 SH, what the baker fits (and stores in the sidecar)
        fitted = fit_chunked(res, sh)
        with np.errstate(all="ignore"):
            channels = encode_params(fitted.params)
        if channels is None:
            return None
        return {r: np.asarray(c).reshape(len(sh), -1) for r, c in channels.items()}

    def same(a, b):
        if np.issubdtype(a.dtype, np.floating):  # bitwise (NaN == NaN, -0 != +0 is fine)
            return a.view(np.uint16 if a.itemsize == 2 else np.uint32) == b.astype(a.dtype).view(
                np.uint16 if a.itemsize == 2 else np.uint32
            )
        return a == b.astype(a.dtype)

    with np.errstate(all="ignore"):
        channels = encode_params(refit(bake).params)
    if channels is None:  # an atlas page whose factors cannot be re-derived
        return {}, False
    want = {r: np.asarray(c).reshape(len(bake.sh), -1) for r, c in channels.items()}
    out, pending = {}, False
    for role, stored in bake.channels.items():
        lay = bake.layout[role]
        keep = np.array([c != "reserved" for c in lay.codes])
        bad = ~same(stored, want[role]) & keep[None, :] & bake.valid[:, None]
        out[role] = bad
        pending |= bool(bad.any())
    if not pending:
        return out, True
    # A texture whose file no longer has the digest the bake recorded is Textures' finding
    # (TextureReplaced, naming the file): its codes are not judged here too.
    from usdahd.usd import schema

    for role, mask in out.items():
        digest = res.digests.get(role)
        if mask.any() and digest:
            try:
                replaced = schema.file_digest(res.textures[role]) != digest
            except OSError:
                replaced = True
            if replaced:
                mask[:] = False
    # Antithetic pairs (+e, -e): a value within the noise of a rounding boundary crosses it
    # with one of the two, whichever side it sits on. A scale (for what is linear in the SH)
    # and two random directions (for directions and ratios, which a scale leaves alone).
    rng = np.random.default_rng(0)
    shifts = [np.ones_like(bake.sh), *rng.standard_normal((2,) + bake.sh.shape)]
    rows = np.nonzero(np.any([m.any(axis=1) for m in out.values()], axis=0))[0]
    for e in shifts:
        for sign in (1.0, -1.0):
            noisy = bake.sh.copy()  # the whole prim: a model's scale factors see every texel
            noisy[rows] *= 1.0 + sign * AMBIGUITY_NOISE * e[rows]
            alt = encode(noisy)
            if alt is None:  # noise past the page's maxima: another factor, no evidence
                continue
            for role, stored in bake.channels.items():
                out[role][rows] &= ~same(stored[rows], alt[role][rows])
    return out, True


#: Texels per chunk of IzCheck's work (memory stays O(chunk) for big lightmaps).
CHUNK = 32768


def _at(bake: Bake, channels: dict, normals: np.ndarray, sl=slice(None)) -> np.ndarray:
    """Decoded I(n) (m, k, 3) float64 at ``normals`` (k, 3) of the stored channels of the texels
    ``sl`` (as an engine computes it)."""
    chans = {r: c[sl] for r, c in channels.items()}
    params = bake.mod.decode(chans, ratio=bake.results.ratio, factors=bake.factors)
    m = len(next(iter(chans.values())))
    return bake.mod.evaluate(params, np.broadcast_to(normals, (m,) + normals.shape)).astype(
        np.float64
    )


def decoded_iz(bake: Bake, channels: dict) -> np.ndarray:
    """Decoded I(n = z) (n, 3) float64 of stored channels (as an engine computes it)."""
    return _at(bake, channels, np.array([[0.0, 0.0, 1.0]]))[:, 0]


def channel_steps(bake: Bake, sl=slice(None)):
    """Yield (role, channel index, channels with that channel moved one code step up, ... down)
    for every stored channel that is not reserved, of the texels ``sl`` only (a chunk's codes
    are stepped, not the whole map's for every chunk)."""
    chans = {r: c[sl] for r, c in bake.channels.items()}
    for role, codes in chans.items():
        for j, code in enumerate(bake.layout[role].codes):
            if code == "reserved":
                continue
            moved = []
            for up in (True, False):
                c = codes.copy()
                c[:, j] = code_step(codes[:, j], up)
                moved.append({**chans, role: c})
            yield role, j, moved[0], moved[1]


def sensitivities(bake: Bake, normals: np.ndarray, sl=slice(None), base=None):
    """[(role, j, (m, k, 3) |I(n; code_j +- 1 step) - I(n)| (the larger side))] of the texels
    ``sl``: how much one code step of each stored channel moves the decode at each normal.
    base : the decode of the stored codes at ``normals`` (``_at``), when the caller has it."""
    if base is None:
        base = _at(bake, bake.channels, normals, sl)
    out = []
    for role, j, up, down in channel_steps(bake, sl):
        worst = np.zeros_like(base)
        for moved in (up, down):
            with np.errstate(all="ignore"):
                diff = np.abs(_at(bake, moved, normals) - base)
            worst = np.maximum(worst, np.where(np.isfinite(diff), diff, 0.0))
        out.append((role, j, worst))
    return out


def quantization_tolerance(
    bake: Bake, got: np.ndarray | None = None, normals: np.ndarray | None = None, sl=slice(None)
) -> np.ndarray:
    """Per texel (and normal) and colour, how far the decoded I(n) may lie from the unquantized
    fit: (n, 3) at z, or (n, k, 3) at ``normals``.

    Derived from the storage, not guessed: every stored code c_j is the rounding of the exact
    value to the nearest code (half a code step away at most), so to first order
    ``|I(n) - I_exact(n)| <= sum_j 0.5 |I(n; c_j + 1 step) - I(n)|`` (the larger of the two
    one-sided differences). One step is the next float16 (an ULP, 2^-11 relative at most, times
    the decode scale) or one 8-bit code; every channel of every texture enters, so a model
    whose I(n) involves several coefficients or an 8-bit direction gets the sum of their
    quantization errors at n. Plus TOLERANCE_SLACK of that. docs/validate.md, IzCheck.
    """
    at_z = normals is None
    normals = np.array([[0.0, 0.0, 1.0]]) if at_z else normals
    tol = None
    for _role, _j, worst in sensitivities(bake, normals, sl, got):
        tol = 0.5 * worst if tol is None else tol + 0.5 * worst
    if tol is None:
        tol = np.zeros_like(_at(bake, bake.channels, normals, sl))
    tol = tol * (1.0 + TOLERANCE_SLACK)
    return tol[:, 0] if at_z else tol


def _reference(bake: Bake, normals: np.ndarray, sl=slice(None)) -> np.ndarray:
    """The unquantized I(n) (m, k, 3) the decode is compared with: the model refitted to the
    sidecar SH (same ratio and solver), clamped to what its textures can represent, at every
    normal; for IrradZ models at z the sidecar's own ``max(I_z, 0)`` (the fit stores negative
    SH ringing as 0)."""
    res = bake.results
    sh = np.asarray(bake.sh[sl], np.float64)
    with np.errstate(all="ignore"):
        params = models.representable(refit(bake, sl), bake.mod)
        ref = bake.mod.evaluate(params, np.broadcast_to(normals, (len(sh),) + normals.shape))
        ref = ref.astype(np.float64)
        if res.model in IRRADZ:
            ref[:, 0] = np.maximum(shm.iz(sh), 0.0)
    return ref


def _suspect(bake: Bake, i: int, normals: np.ndarray, ref: np.ndarray, allowed: np.ndarray):
    """(role, channel name, code, code it should be) of the one code step that best explains
    texel ``i``'s mismatch (brings its worst error / tolerance lowest), or None when no single
    step brings it within the tolerance."""
    sl = slice(i, i + 1)
    best, found = None, None
    with np.errstate(all="ignore"):
        for role, j, up, down in channel_steps(bake, sl):
            for moved in (up, down):
                err = np.abs(_at(bake, moved, normals)[0] - ref)
                r = float(np.max(np.where(allowed > 0, err / np.maximum(allowed, 1e-300), 0.0)))
                if np.isfinite(r) and (best is None or r < best):
                    name = bake.layout[role].channels[j]
                    best = r
                    found = (role, name, bake.channels[role][i, j], moved[role][0, j])
    return found if best is not None and best <= 1.0 else None


def _show(code) -> str:
    return (
        f"{float(code):.6g}"
        if np.issubdtype(np.asarray(code).dtype, np.floating)
        else str(int(code))
    )


def check_iz(prim) -> list[Finding]:
    """Rule IzCheck (see RULES)."""
    r = RuleFindings("IzCheck", prim)
    bake = load_for(r, prim, sidecar=" (see SchemaValues)")
    if bake is None:
        return r.out
    res = bake.results
    normals = check_normals()
    n = len(bake.xy)
    what = "I_z" if res.model in IRRADZ else f"{res.model} irradiance at n = z"
    # Per texel: finite, failing, worst error / tolerance, max relative error, relative tolerance.
    finite = np.zeros(n, bool)
    fail = np.zeros(n, bool)
    ratio_t = np.zeros(n)
    rel_t = np.zeros(n)
    rel_sum = np.zeros(n)
    reltol_t = np.zeros(n)
    bright = np.zeros(n)
    worst_normal = np.zeros(n, np.int64)
    for a in range(0, n, CHUNK):
        sl = slice(a, min(a + CHUNK, n))
        with np.errstate(all="ignore"):
            got = _at(bake, bake.channels, normals, sl)
            ref = _reference(bake, normals, sl)
            if OPTIONS.iz_tolerance is not None:  # --tolerance: a plain relative tolerance
                scale = np.abs(ref).max(axis=2, keepdims=True)
                allowed = np.broadcast_to(float(OPTIONS.iz_tolerance) * scale, ref.shape)
            else:
                allowed = quantization_tolerance(bake, got, normals, sl)
        # Texels TexelValues rejects (non-finite values, d_z below the floor) are its findings.
        ok = bake.valid[sl] & np.isfinite(got).all(axis=(1, 2)) & np.isfinite(ref).all(axis=(1, 2))
        err = np.where(ok[:, None, None], np.abs(got - ref), 0.0)
        # Relative figures against the texel's brightest reference value (a black channel or
        # normal next to a bright one is judged relative to the bright one).
        denom = np.maximum(np.where(ok[:, None, None], np.abs(ref), 0.0).max(axis=(1, 2)), 1e-30)
        ratio = np.where(
            allowed > 0,
            err / np.where(allowed > 0, allowed, 1.0),
            np.where(err > 0, np.inf, 0.0),
        )
        finite[sl] = ok
        fail[sl] = ok & (err > allowed).any(axis=(1, 2))
        rmax = ratio.reshape(len(ok), -1)
        ratio_t[sl] = np.where(ok, rmax.max(axis=1), 0.0)
        worst_normal[sl] = rmax.argmax(axis=1) // 3
        rel_t[sl] = np.where(ok, err.max(axis=(1, 2)) / denom, 0.0)
        rel_sum[sl] = np.where(ok, (err / denom[:, None, None]).sum(axis=(1, 2)), 0.0)
        reltol_t[sl] = np.where(ok, (allowed / denom[:, None, None]).max(axis=(1, 2)), 0.0)
        bright[sl] = np.where(ok, denom, 0.0)
    n_skip = int((~finite).sum())
    if not finite.any():
        r.skipped("no texel decodes to finite values (TexelValues)")
        return r.out
    bad_codes, codes_checked = code_check(bake) if OPTIONS.iz_tolerance is None else ({}, False)
    code_texels = np.zeros(n, bool)
    for mask in bad_codes.values():
        code_texels |= mask.any(axis=1)
    lit = finite & (bright > 1e-6 * bright[finite].max())  # texels bright enough for a ratio
    worst = int(np.argmax(np.where(fail, ratio_t, -1.0))) if fail.any() else int(np.argmax(rel_t))
    x, y = texel_xy(bake, worst)
    stats = dict(
        texels=int(finite.sum()),
        failing=int(fail.sum()),
        normals=len(normals),
        max_relative=float(rel_t.max()),
        mean_relative=float(rel_sum[finite].sum() / (finite.sum() * normals.size)),
        worst_texel=(x, y),
        worst_normal=normals[int(worst_normal[worst])].round(4).tolist(),
        tolerance=float(reltol_t[lit].max()) if lit.any() else 0.0,
        tolerance_median=float(np.median(reltol_t[lit])) if lit.any() else 0.0,
        worst_error_over_tolerance=float(ratio_t[finite].max()),
        skipped_nonfinite=n_skip,
        codes_checked=codes_checked,
        code_mismatches=int(code_texels.sum()),
    )
    codes = (
        "; every stored code equals the encoder's for the sidecar SH"
        if codes_checked and not code_texels.any()
        else ""
        if codes_checked
        else "; codes not re-encoded (written by another usdahd or --tolerance given)"
    )
    summary = (
        f"{what} vs the SH sidecar over "
        f"{stats['texels']} covered texels: max relative error {stats['max_relative']:.3g}, "
        f"mean {stats['mean_relative']:.3g}, worst at texel ({x}, {y}); tolerance from the "
        f"quantization up to {stats['tolerance']:.3g} relative (median "
        f"{stats['tolerance_median']:.3g}), worst error "
        f"{stats['worst_error_over_tolerance']:.3g} of it{codes}"
    )

    def code_at(i):
        """(role, channel, stored, expected) of texel i's first mismatching code, or None."""
        for role, mask in bad_codes.items():
            js = np.nonzero(mask[i])[0]
            if js.size:
                j = int(js[0])
                return role, bake.layout[role].channels[j], bake.channels[role][i, j]
        return None

    if not fail.any() and code_texels.any():
        i = int(np.argmax(code_texels))
        cx, cy = texel_xy(bake, i)
        role, name, code = code_at(i)
        stats.update(suspect_role=role, suspect_channel=name, first_code_texel=(cx, cy))
        r.error(
            "CodeMismatch",
            f"{stats['code_mismatches']} texel(s) hold a code the encoder does not give their "
            f"SH sidecar values, first at texel ({cx}, {cy}): {role} texture channel {name} "
            f"holds {_show(code)} (I_z is within the tolerance: {summary})",
            "re-bake the prim; a texture was edited or corrupted (or the sidecar replaced)",
            **stats,
        )
        return r.out
    if fail.any():
        sl = slice(worst, worst + 1)
        with np.errstate(all="ignore"):
            ref = _reference(bake, normals, sl)[0]
            allowed = (
                quantization_tolerance(bake, None, normals, sl)[0]
                if OPTIONS.iz_tolerance is None
                else float(OPTIONS.iz_tolerance) * np.abs(ref).max(axis=1, keepdims=True)
            )
        hint = ""
        if code_texels[worst]:
            role, name, code = code_at(worst)
            stats.update(suspect_role=role, suspect_channel=name)
            hint = (
                f"; at texel ({x}, {y}) {role} texture channel {name} holds {_show(code)}, "
                "not the code the encoder gives the sidecar SH"
            )
        else:
            suspect = _suspect(bake, worst, normals, ref, allowed)
            if suspect is not None:
                role, name, code, should = suspect
                stats.update(suspect_role=role, suspect_channel=name)
                hint = (
                    f"; at texel ({x}, {y}) one code explains it: {role} texture channel "
                    f"{name} holds {_show(code)} where {_show(should)} fits"
                )
        r.error(
            "IzMismatch",
            f"{stats['failing']} texel(s) exceed the tolerance: {summary}{hint}",
            "re-bake the prim; a texture was edited, corrupted or written with another "
            "quantization than the schema declares",
            **stats,
        )
    else:
        r.info("IzOk", summary, **stats)
    return r.out


# ---------------------------------------------------------------------- rule 5: EncodingError


def hemisphere_irradiance(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """``shm.irradiance(sh[:, None], dirs[None])`` (n, d, 3) float64 as one matrix product
    (the SH basis at the d normals, once): 6x faster than the einsum at 64 normals, equal to
    1e-15 relative. sh : (n, 3, 9); dirs : (d, 3)."""
    basis = shm.basis(np.asarray(dirs, np.float64))  # (d, 9)
    conv = np.asarray(sh, np.float64) * shm.COSINE_FACTORS  # (n, 3, 9)
    return np.matmul(conv, basis.T).transpose(0, 2, 1)


#: Seed of EncodingError's texel sample (a prim above OPTIONS.rmse_max_texels texels).
SAMPLE_SEED = 0


def _texels_phrase(n: int, population: int) -> str:
    """'N texels', or 'N of M texels (random sample)' when EncodingError sampled them."""
    if n == population:
        return f"{n} texels"
    return f"{n} of {population} texels (random sample)"


def check_encoding_error(prim) -> list[Finding]:
    """Rule EncodingError (see RULES and docs/validate.md).

    Three hemispherical RMSEs over OPTIONS.rmse_normals upper-hemisphere normals (spherical
    Fibonacci), each relative to the mean |SH irradiance| over those normals and texels
    (:func:`usdahd.numerics.stats.pooled_rmse_over_mean_abs`; per texel
    :func:`~usdahd.numerics.stats.rmse_over_mean_abs`):
    ``relative_rmse`` decoded textures vs the SH irradiance (what a renderer gets), ``model_rmse``
    the unquantized refit vs the SH irradiance (the model's own approximation error, a note:
    a model choice, not a defect), ``quantization_rmse`` decoded vs the unquantized refit (what
    the textures add). Warns when the quantization part exceeds OPTIONS.rmse_warning.
    """
    r = RuleFindings("EncodingError", prim)
    bake = load_for(r, prim, sidecar="")
    if bake is None:
        return r.out
    # Texels holding codes the encoder does not give their SH are IzCheck's findings.
    bad_codes, _ran = code_check(bake)
    corrupt = np.zeros(len(bake.xy), bool)
    for mask in bad_codes.values():
        corrupt |= mask.any(axis=1)
    idx = np.nonzero(bake.valid & ~corrupt & np.isfinite(bake.sh).all(axis=(1, 2)))[0]
    if idx.size == 0:
        r.skipped(
            "no valid covered texel"
            + (" with the encoder's codes for its SH (see IzCheck)" if corrupt.any() else "")
        )
        return r.out
    population = int(idx.size)
    if idx.size > OPTIONS.rmse_max_texels:
        # A seeded simple random sample (docs/validate.md states what it detects): a region
        # of >= 6% of the texels is a region in the sample with >= 99.7% probability.
        pick = np.random.default_rng(SAMPLE_SEED).choice(
            idx.size, OPTIONS.rmse_max_texels, replace=False
        )
        idx = idx[np.sort(pick)]
    dirs = shm.fibonacci_sphere(OPTIONS.rmse_normals, hemisphere=True)
    sh = bake.sh[idx].astype(np.float64)
    params = {k: v[idx] for k, v in bake.params.items()}
    res = bake.results
    with np.errstate(all="ignore"):
        target = hemisphere_irradiance(sh, dirs)  # (n, d, 3)
        normals = np.broadcast_to(dirs, (idx.size,) + dirs.shape)
        got = bake.mod.evaluate(params, normals).astype(np.float64)
        exact = bake.mod.evaluate(models.representable(refit(bake, idx), bake.mod), normals)
        exact = exact.astype(np.float64)
    scale = np.abs(target).mean(axis=(1, 2))
    per_texel = rmse_over_mean_abs(got, target, scale)
    total = pooled_rmse_over_mean_abs(got, target, scale)
    model_total = pooled_rmse_over_mean_abs(exact, target, scale)
    q_texel = rmse_over_mean_abs(got, exact, scale)
    q_total = pooled_rmse_over_mean_abs(got, exact, scale)
    worst = int(np.argmax(per_texel))
    x, y = int(bake.xy[idx[worst], 0]), int(bake.xy[idx[worst], 1])
    qw = int(np.argmax(np.where(np.isfinite(q_texel), q_texel, 0.0)))
    stats = dict(
        texels=int(idx.size),
        population_texels=population,
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
        f"{OPTIONS.rmse_normals} hemisphere normals and {_texels_phrase(idx.size, population)}: "
        "relative RMSE "
        f"{total:.3g} (model fit {model_total:.3g}, quantization {q_total:.3g}); per texel mean "
        f"{stats['texel_relative_rmse_mean']:.3g}, max {stats['texel_relative_rmse_max']:.3g} "
        f"at texel ({x}, {y})"
    )
    if res.model in IRRADZ:
        # Texels lit from below their tangent plane: I_z <= 0 while the hemisphere is lit;
        # an IrradZ model stores max(I_z, 0) and decodes them black.
        below = (shm.iz(sh).max(axis=1) <= 0.0) & (scale > 0)
        stats["below_horizon_texels"] = int(below.sum())
    over_mask = ~(per_texel <= OPTIONS.model_rmse_warning)  # NaN counts as over
    over = float(np.mean(over_mask))
    stats["texel_share_above_warning"] = over
    # a region is a share of the texels AND enough of them: on a small map (8 x 8) a handful
    # of noisy grazing texels is more than 5 % of a prim without being a region
    region = over > OPTIONS.model_texel_share and int(over_mask.sum()) >= OPTIONS.model_texel_min
    loose = model_total > MODEL_RMSE_NOTE or total > OPTIONS.model_rmse_warning or region
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
    if not math.isfinite(total) or total > OPTIONS.model_rmse_warning or region:
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
            found[name] = pooled_rmse_over_mean_abs(got.astype(np.float64), tgt, sc)
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
