"""Blending a denoiser's output with its noisy input by the noise (stage 3 of
:mod:`usdahd.bake.denoise`): per texel and coefficient ``out = x + w (d - x)`` with
``w = min(1, g var / change)`` (:func:`blend_weights`), directional coefficients blended as
ratios to c00 (:func:`blend_sh`) and each chart's summed I_z kept (:func:`keep_chart_energy`),
then each ring's from the chart border (:func:`border_depth`) over a record's charts
(:func:`keep_class_energy`).

Numerics only (numpy, and the numba kernels of :mod:`usdahd.numerics.windows` and
:mod:`usdahd.numerics.noise`); arrays are float64 canvases ``(h, w, c)`` or per-texel SH
``(m, 3, 9)``.
"""

from __future__ import annotations

import numba
import numpy as np

from usdahd.numerics import numba_cache, windows
from usdahd.numerics.noise import second_differences
from usdahd.numerics.windows import box_mean, count_table, finite, summed, window

__all__ = [
    "BAND_BOUND",
    "BIAS_RADIUS",
    "BLEND_GAIN",
    "EDGE_CONTRAST",
    "RATIO_COEFFS",
    "blend_chart",
    "blend_sh",
    "blend_weights",
    "border_depth",
    "box_mean",
    "class_scale",
    "class_sums",
    "edge_texels",
    "keep_chart_energy",
    "keep_class_energy",
]

#: sqrt(2l + 1) per coefficient: |c_lm| <= sqrt(2l+1) c00 for non-negative functions.
BAND_BOUND = np.sqrt(2.0 * np.array([0, 1, 1, 1, 2, 2, 2, 2, 2]) + 1.0)
#: Coefficients denoised as ratios to c00 (OIDN's directional mode).
RATIO_COEFFS = (1, 3, 4, 5, 6, 7, 8)
#: (Their blend is also judged texel by texel: the directional network moved single texels
#: by many noise deviations, since the ratios swing fast next to a small light, and the
#: error is multiplied by c00 there.)
#: Chebyshev radius of the window averaging (denoised - input)^2 into the local change estimate.
BIAS_RADIUS = 2
#: The denoised value is fully trusted while the local mean squared change is below
#: BLEND_GAIN x the noise variance (a change of 2 sigma): the variance estimate itself is
#: noisy and (a mean, not robust) inflated by fireflies; at 1 the blend kept fireflies that
#: OIDN removed (pillar_room at 16 spp: error 0.29 -> 0.38), at 4 it costs nothing measurable
#: on the samples and still returns noise-free inputs unchanged.
BLEND_GAIN = 4.0
#: With the integrator's variance, a texel where the denoised image has an edge (squared
#: second differences along the row and the column summing to more than EDGE_CONTRAST x the
#: noise variance: the signal bends by more than 4 noise deviations there) is also judged by
#: its own move: its weight is at most var / (d - x)^2, the MSE-optimal weight for a texel
#: the denoiser moved by d - x. The window mean alone dilutes a one-texel-wide sun-shadow
#: edge among flat texels. Measured (denoise_gain, 2 seeds): exterior_sun_sky's ground 1.35
#: / 1.15 / 1.09 -> 0.76 / 0.90 / 1.06 at 16 / 64 / 256 spp; contrasts 1-16 measured alike,
#: ungated (every texel) it kept noise (shared Cornell box at 16 spp 0.24 -> 0.35). A step
#: bends on both sides; a soft penumbra (a ramp across many texels) does not, and the test
#: before 2026-12-07 (the squared central-difference gradient) held its noisy texels back.
#: Against the Cycles point truth (issue 43, docs/time-to-quality.md): stretched_boxes at
#: 128^2 0.382 / 0.221 % -> 0.366 / 0.203 % net at 64 / 256 spp, floor_lamp at 128^2 2.16 /
#: 0.86 -> 2.04 / 0.79 %, cornell_box at 32^2 1.17 / 0.70 -> 1.08 / 0.63 % at 256 / 1024
#: spp; exterior_sun_sky, the stage the rule is for, unchanged at both sizes (within 0.5 %).
EDGE_CONTRAST = 16.0
#: Canvas elements (float64) per channel block of :func:`blend_chart`'s kernel (~32 MB each
#: of its two canvases; all 27 channels at once for charts up to ~385 x 385 texels).
_WORK_ELEMENTS = 4_000_000


def blend_weights(
    noisy: np.ndarray,
    denoised: np.ndarray,
    variance: np.ndarray,
    mask: np.ndarray,
    pointwise: np.ndarray | None = None,
    gain: float = BLEND_GAIN,
    edges: bool = False,
) -> np.ndarray:
    """Weight ``w (h, w, c)`` of the denoised image in ``noisy + w (denoised - noisy)``.

    noisy, denoised, variance : (h, w, c) canvases (values outside ``mask`` ignored);
    mask : (h, w) bool, the chart's texels; pointwise : (c,) bool, channels whose change is
    also judged texel by texel.
    ``w = min(1, g var / change)`` with ``g = gain`` and ``change`` the mean of
    ``(d - x)^2`` over the chart texels within ``BIAS_RADIUS`` (for ``pointwise`` channels the
    larger of that and the texel's own ``(d - x)^2``, so no single texel moves by more than
    ``sqrt(g)`` noise deviations); 0 where var = 0 (a noise-free input is kept). With
    ``edges``, texels where the denoised image has an edge (:data:`EDGE_CONTRAST`) also get
    at most ``var / (d - x)^2``.
    """
    diff = np.nan_to_num(np.asarray(denoised, np.float64) - np.asarray(noisy, np.float64))
    change = box_mean(diff**2, mask, BIAS_RADIUS)
    if pointwise is not None:
        change = np.where(np.asarray(pointwise, bool), np.maximum(change, diff**2), change)
    v = np.nan_to_num(np.asarray(variance, np.float64))
    var = gain * v
    w = np.where(var > 0, var / np.maximum(np.maximum(change, var), 1e-300), 0.0)
    if edges:
        own = np.where(v > 0, v / np.maximum(np.maximum(diff**2, v), 1e-300), 0.0)
        w = np.where(edge_texels(denoised, mask, v), np.minimum(w, own), w)
    return w


def edge_texels(img: np.ndarray, mask: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """(h, w, c) bool: chart texels where ``img (h, w, c)`` bends: its squared second
    differences along the row and the column (:func:`usdahd.numerics.noise.
    second_differences`; an axis counts where its three texels are in the chart) sum to more
    than EDGE_CONTRAST x ``variance (h, w, c)``."""
    sd = second_differences(np.asarray(img, np.float64), mask, directions=2, fill=0.0)
    return mask[..., None] & (sd.sum(axis=2) > EDGE_CONTRAST * variance)


def blend_sh(x: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(m, 3, 9) ``x + w (d - x)`` per coefficient for the input SH ``x``, OIDN's ``d`` and
    the blend weights ``w``, except that each directional coefficient (``RATIO_COEFFS``) is
    blended as its ratio to c00 and multiplied by the blended c00 (where both c00 are > 0):
    its weight is often smaller than c00's (judged texel by texel), and blended alone a
    texel whose c00 was denoised but whose direction was kept came out with |c_lm| >
    sqrt(2l+1) c00, i.e. negative radiance (floor_lamp at 8^2, 16 spp: HLSH's fit error 0.29
    on the wall, the validator's HighEncodingError). A convex mix of two valid ratios is valid.
    c00 and c10 (I_z) are blended directly, then c00 raised to |c10| / sqrt(3) where it
    fell below (the least change that keeps I_z and a non-negative radiance). Both ratios are
    clipped to the band bound ``sqrt(2l + 1)`` first: a Monte Carlo input's ratio is beyond it
    where its c00 is small by chance, and multiplied by a denoised c00 that spike became a
    large error (floor_lamp 32^2, 16 spp: 54 of 5,184 texel channels beyond the bound made
    the blended L2 coefficients 2-4x the raw input's error, e.g. c2-2 43 % vs 10 %; 6 % with
    the clip)."""
    out = x + w * (d - x)
    out[:, :, 0] = np.maximum(out[:, :, 0], np.abs(out[:, :, 2]) / BAND_BOUND[2])
    r = list(RATIO_COEFFS)
    x00, d00 = x[:, :, :1], d[:, :, :1]
    ok = (x00 > 0) & (d00 > 0)
    bound = BAND_BOUND[r]
    rx = np.clip(x[:, :, r] / np.where(ok, x00, 1.0), -bound, bound)
    rd = np.clip(d[:, :, r] / np.where(ok, d00, 1.0), -bound, bound)
    out[:, :, r] = np.where(ok, (rx + w[:, :, r] * (rd - rx)) * out[:, :, :1], out[:, :, r])
    # elsewhere (an input or denoised c00 <= 0) each directional coefficient is held within
    # the band bound of the blended c00 too: an unlit texel (c00 = 0, noise free) beside lit
    # ones keeps its c00 but took a share of the denoised direction through the pooled
    # variance, and came out with l = 1, 2 coefficients and no c00 (the classroom: up to
    # 4e-7 on 124 of 620 unlit texels of a prim, which the validator then read as light from
    # below the tangent plane, EncodingError on 13 more prims)
    lim = bound * np.maximum(out[:, :, :1], 0.0)
    out[:, :, r] = np.where(ok, out[:, :, r], np.clip(out[:, :, r], -lim, lim))
    return out


def blend_chart(
    x: np.ndarray,
    d: np.ndarray,
    var: np.ndarray,
    ly: np.ndarray,
    lx: np.ndarray,
    mask: np.ndarray,
    *,
    gain: float = BLEND_GAIN,
    edges: bool = False,
    backend: str = "numba",
    out: np.ndarray | None = None,
) -> np.ndarray:
    """(m, 3, 9) float64 blend of one chart: :func:`blend_weights` of every coefficient on the
    chart's canvas (the per-texel input ``x``, OIDN's ``d`` and the noise variance ``var``,
    each (m, 3, 9), placed at ``(ly, lx) (m,)`` of the canvas ``mask (h, w) bool`` and
    rounded to float32 as :class:`usdahd.bake.canvas.Canvas` images are; the directional
    coefficients ``RATIO_COEFFS`` judged texel by texel too), then :func:`blend_sh`.

    ``backend="numpy"`` is that composition (the definition); the numba kernel (default)
    computes the same numbers bit for bit texel by texel, without the (h, w, 27) canvases
    and ~40 array passes (a 128 x 128 chart, 27 channels: numpy 72 ms, the kernel 12 ms on
    one core; tests/bake/test_denoise.py checks the parity). A change to the blend's rule
    goes into the numpy functions (the definition, what an experiment patches and runs with
    ``backend="numpy"``), then into the kernel until the parity test passes.
    ``out``: a C-contiguous (m, 3, 9) float64 array to write into and return (``d`` itself
    is fine: no second copy of a large chart's SH); default a new array."""
    m = len(x)
    if out is not None and not (
        out.shape == (m, 3, 9) and out.dtype == np.float64 and out.flags.c_contiguous
    ):
        raise ValueError(f"out must be a C-contiguous ({m}, 3, 9) float64 array")
    ly = np.asarray(ly, np.int64)
    lx = np.asarray(lx, np.int64)
    if backend == "numpy":
        weights = np.empty((m, 3, 9))
        for k in range(9):  # one coefficient at a time: each channel's weight is its own

            def img(v, k=k):
                c = np.full((*mask.shape, 3), np.nan, np.float32)
                c[ly, lx] = v[:, :, k]
                return c

            pointwise = np.full(3, k in RATIO_COEFFS)
            w = blend_weights(img(x), img(d), img(var), mask, pointwise, gain, edges)
            weights[:, :, k] = w[ly, lx]
        blended = blend_sh(np.asarray(x, np.float64), np.asarray(d, np.float64), weights)
        if out is None:
            return blended
        out[...] = blended
        return out
    if backend != "numba":
        raise ValueError(f"unknown backend {backend!r}")
    ratio = np.isin(np.arange(9), RATIO_COEFFS)
    return _blend_chart_numba(
        np.ascontiguousarray(x, np.float64),
        np.ascontiguousarray(d, np.float64),
        np.ascontiguousarray(var, np.float64),
        np.ascontiguousarray(ly),
        np.ascontiguousarray(lx),
        np.ascontiguousarray(mask, np.bool_),
        float(gain),
        bool(edges),
        int(BIAS_RADIUS),
        float(EDGE_CONTRAST),
        np.ascontiguousarray(BAND_BOUND, np.float64),
        ratio,
        _channel_block(mask.shape),
        np.empty((m, 3, 9)) if out is None else out,
    )


def _channel_block(shape: tuple[int, int]) -> int:
    """Channels per block of :func:`_blend_chart_numba` on a canvas of ``shape``."""
    side = 2 * BIAS_RADIUS + 1
    return int(np.clip(_WORK_ELEMENTS // ((shape[0] + side) * (shape[1] + side)), 1, 27))


@numba.njit(cache=True, nogil=True)
def _f32(v):
    """A float64 rounded to float32 (a Canvas image's value), then read as ``np.nan_to_num``."""
    return finite(np.float64(np.float32(v)))


@numba.njit(cache=True, nogil=True)
def _blend_chart_numba(
    x, d, var, ly, lx, mask, gain, edges, r, edge_contrast, bound, ratio, block, out
):  # fmt: skip
    m = x.shape[0]
    nc = x.shape[1] * x.shape[2]  # 27 channels, colour-major (c * 9 + k), texel-major arrays
    xs, ds, vs = x.reshape(m, nc), d.reshape(m, nc), var.reshape(m, nc)
    h, w = mask.shape
    kw = 2 * r + 1
    hh, ww = h + kw, w + kw
    cnt = count_table(ly, lx, h, w, r)  # the mask's summed-area table (box_mean's count)
    weights = np.empty((m, nc))
    # channels in blocks (bounded canvases for a large chart), texel-major within a block
    for c0 in range(0, nc, block):
        g = min(nc, c0 + block) - c0
        sat = np.zeros((hh, ww, g))  # (d - x)^2 of the float32 canvases, then its table
        dimg = np.zeros((h, w, g))  # the denoised canvas (float32 values)
        diff2 = np.empty((m, g))
        vv = np.empty((m, g))
        for i in range(m):
            y, xx = ly[i], lx[i]
            for j in range(g):
                df = _f32(ds[i, c0 + j])
                dx = df - _f32(xs[i, c0 + j])
                diff2[i, j] = dx * dx
                sat[y + r + 1, xx + r + 1, j] = dx * dx
                dimg[y, xx, j] = df
                vv[i, j] = _f32(vs[i, c0 + j])
        summed(sat)
        for i in range(m):
            y, xx = ly[i], lx[i]
            n = max(window(cnt, y, xx, 0, kw), 1.0)
            # the edge rule's row and column: both neighbours in the chart
            row = xx >= 1 and xx + 1 < w and mask[y, xx - 1] and mask[y, xx + 1]
            col = y >= 1 and y + 1 < h and mask[y - 1, xx] and mask[y + 1, xx]
            for j in range(g):
                change = window(sat, y, xx, j, kw) / n
                if ratio[(c0 + j) % 9]:
                    change = max(change, diff2[i, j])
                v = vv[i, j]
                vg = gain * v
                wt = vg / max(max(change, vg), 1e-300) if vg > 0 else 0.0
                if edges:
                    sd = 0.0
                    if row:
                        q = dimg[y, xx - 1, j] - 2.0 * dimg[y, xx, j]
                        q = q + dimg[y, xx + 1, j]
                        sd += q * q
                    if col:
                        q = dimg[y - 1, xx, j] - 2.0 * dimg[y, xx, j]
                        q = q + dimg[y + 1, xx, j]
                        sd += q * q
                    if sd > edge_contrast * v:
                        own = v / max(max(diff2[i, j], v), 1e-300) if v > 0 else 0.0
                        wt = min(wt, own)
                weights[i, c0 + j] = wt
    # blend_sh, texel by texel, into ``out`` (may be ``d`` itself: a texel's values are
    # read into ``t`` before its row is written)
    nk = x.shape[2]
    t = np.empty(nk)
    for i in range(m):
        for c in range(x.shape[1]):
            for k in range(nk):
                t[k] = x[i, c, k] + weights[i, c * nk + k] * (d[i, c, k] - x[i, c, k])
            t[0] = max(t[0], abs(t[2]) / bound[2])
            x00, d00 = x[i, c, 0], d[i, c, 0]
            ok = x00 > 0 and d00 > 0
            for k in range(nk):
                if not ratio[k]:
                    continue
                b = bound[k]
                if ok:
                    rx = min(max(x[i, c, k] / x00, -b), b)
                    rd = min(max(d[i, c, k] / d00, -b), b)
                    wk = weights[i, c * nk + k]
                    t[k] = (rx + wk * (rd - rx)) * t[0]
                else:
                    lim = b * max(t[0], 0.0)
                    t[k] = min(max(t[k], -lim), lim)
            for k in range(nk):
                out[i, c, k] = t[k]
    return out


def keep_chart_energy(x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``d (m, 3, 9)`` scaled per colour channel so the chart's summed c10 (the coefficient
    proportional to I_z) equals the input's ``x (m, 3, 9)``: an unbiased input's chart sum is
    an unbiased estimate of the true sum, and a partial blend need not keep it. OIDN moves
    energy out of a light's hotspot into its surroundings; where the per-texel variance is
    high (the hotspot) the blend keeps the move, where it is low (the surroundings) it keeps
    less, so without this the chart lost energy (pillar_room, 256 spp: -1.02 % overall)."""
    s_in = x[:, :, 2].sum(axis=0)
    s_out = d[:, :, 2].sum(axis=0)
    ok = (s_out > 0) & (s_in > 0)
    scale = np.where(ok, s_in / np.where(ok, s_out, 1.0), 1.0)
    d *= scale[None, :, None]  # in place: d is the caller's own blended array
    return d


def border_depth(mask: np.ndarray, cap: int) -> np.ndarray:
    """(h, w) int8: each ``mask`` texel's ring counted from the mask's border (0: one of its 8
    neighbours is outside, 1: the ring inside those, ...), at most ``cap``; -1 outside."""
    depth = np.where(mask, 0, -1).astype(np.int8)
    inner = np.asarray(mask, bool)
    h, w = inner.shape
    for level in range(1, cap + 1):
        p = np.pad(inner, 1, constant_values=False)
        nxt = inner.copy()
        for dy in range(3):
            for dx in range(3):
                nxt &= p[dy : dy + h, dx : dx + w]
        if not nxt.any():
            break
        depth[nxt] = level
        inner = nxt
    return depth


def class_sums(v: np.ndarray, classes: np.ndarray, count: int) -> np.ndarray:
    """(count, 3) float64 sums of c10 (``v[:, :, 2]`` of SH ``(m, 3, 9)``) per texel class
    ``classes (m,)`` in [0, count)."""
    out = np.zeros((count, 3), np.float64)
    np.add.at(out, np.asarray(classes, np.intp), np.asarray(v[:, :, 2], np.float64))
    return out


def keep_class_energy(d: np.ndarray, classes: np.ndarray, s_in: np.ndarray) -> np.ndarray:
    """``d (m, 3, 9)`` scaled in place per texel class and colour channel so each class's
    summed c10 equals ``s_in (count, 3)`` (the input's, :func:`class_sums`); classes whose
    sums are not both positive are left as they are. The classes of :mod:`usdahd.bake.denoise`
    are the texels' :func:`border_depth` over every denoised chart of a record: the network
    smooths across a chart a few texels wide, and where its border texels are darker than its
    middle (window frames, whose edges are occluded) it moves energy from the middle to the
    border that the chart's sum (:func:`keep_chart_energy`) does not see (Sponza's
    windows_lib_0 at 64^2: the compared middle texels -1.65 % -> -2.97 % against Cycles).
    Pooled over the record's charts, each class holds many texels, so the sums re-inject
    little of the input's noise (per chart they raised small meshes' error)."""
    scale = class_scale(s_in, class_sums(d, classes, len(s_in)))
    d *= scale[np.asarray(classes, np.intp)][:, :, None].astype(d.dtype)
    return d


def class_scale(s_in: np.ndarray, s_out: np.ndarray) -> np.ndarray:
    """(count, 3) factors taking the summed c10 ``s_out`` of each class and channel to
    ``s_in`` (1 where the sums are not both positive)."""
    ok = (s_out > 0) & (s_in > 0)
    return np.where(ok, s_in / np.where(ok, s_out, 1.0), 1.0)


# _blend_chart_numba links windows.finite: an edit there recompiles it
numba_cache.track(globals(), windows)
