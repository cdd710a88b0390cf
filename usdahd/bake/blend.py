"""Blending a denoiser's output with its noisy input by the noise (stage 3 of
:mod:`usdahd.bake.denoise`): per texel and coefficient ``out = x + w (d - x)`` with
``w = min(1, g var / change)`` (:func:`blend_weights`), directional coefficients blended as
ratios to c00 (:func:`blend_sh`) and each chart's summed I_z kept (:func:`keep_chart_energy`),
then each ring's from the chart border (:func:`border_depth`) over a record's charts
(:func:`keep_class_energy`).

Numerics only (numpy); arrays are float64 canvases ``(h, w, c)`` or per-texel SH ``(m, 3, 9)``.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics.noise import second_differences

__all__ = [
    "BAND_BOUND",
    "BIAS_RADIUS",
    "BLEND_GAIN",
    "EDGE_CONTRAST",
    "RATIO_COEFFS",
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


def box_mean(img: np.ndarray, mask: np.ndarray, radius: int) -> np.ndarray:
    """Mean of ``img (h, w, c)`` over the mask texels in each (2r+1)^2 window (0 if none)."""
    h, w, _ = img.shape
    r = radius
    v = np.where(mask[..., None], img, 0.0)
    s = np.pad(v, ((r + 1, r), (r + 1, r), (0, 0))).cumsum(0).cumsum(1)
    m = np.pad(mask.astype(np.float64), ((r + 1, r), (r + 1, r))).cumsum(0).cumsum(1)
    k = 2 * r + 1

    def box(a):
        return a[k:, k:] - a[:-k, k:] - a[k:, :-k] + a[:-k, :-k]

    tot, cnt = box(s)[:h, :w], box(m)[:h, :w]
    return tot / np.maximum(cnt, 1.0)[..., None]


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
