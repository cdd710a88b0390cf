"""Noise variance of baked radiance SH, for the denoiser's blend (:mod:`usdahd.bake.denoise`).

Two sources: the integrator's own per-texel bounds (:func:`integrator_iz_variance`, spread to
every coefficient by :func:`sh_variance`), and second differences of neighbouring texels of
one chart (:func:`canvas_noise`; ``usdahd.bake.denoise.noise_variance`` for texels). Numpy and
the numba kernels of :mod:`usdahd.numerics.noise` and :mod:`usdahd.numerics.windows` only.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics.noise import tile_stats
from usdahd.numerics.windows import neighbour_mean

__all__ = [
    "MIN_NOISE_SAMPLES",
    "NOISE_TILE",
    "ROBUST_CAP",
    "canvas_noise",
    "integrator_iz_variance",
    "neighbour_mean",
    "sh_variance",
]

#: Side (texels) of the tiles over which squared second differences are pooled into a noise
#: estimate (then over the 3 x 3 neighbouring tiles: an 18 x 18 window).
NOISE_TILE = 6
#: Fewest second differences behind a noise estimate (else the chart's, else none: keep input).
MIN_NOISE_SAMPLES = 8
#: The noise estimate (a mean of squared second differences, so fireflies count as noise) is
#: capped at ROBUST_CAP x the robust one (median, converted for Gaussian noise), so a bright
#: hotspot's curvature does not pass for noise: without it the blend let OIDN's directional
#: output through at pillar_room's light (l=2 error x5.6 at 1024 spp); 16 keeps the firefly
#: removal at 16 spp intact (I_z error unchanged).
ROBUST_CAP = 16.0
#: Median of chi-square with 1 degree of freedom: median(D^2) = 0.45494 E[D^2] for Gaussian D.
_CHI2_1_MEDIAN = 0.454936423119572


def canvas_noise(
    img: np.ndarray, mask: np.ndarray, tile: int = NOISE_TILE, support: np.ndarray | None = None
) -> np.ndarray:
    """(h, w, c) noise variance per texel of a one-chart canvas (0 where unknown), from the
    second differences whose three texels are all in ``support`` ((h, w) bool, default
    ``mask``), assigned to every ``mask`` texel."""
    h, w, _ = img.shape
    th, tw = -(-h // tile), -(-w // tile)
    # the tiles holding chart texels (only theirs are used: the chart-wide median is taken
    # only when one of them falls back to it)
    need = np.pad(mask, ((0, th * tile - h), (0, tw * tile - w)))
    need = need.reshape(th, tile, tw, tile).any(axis=(1, 3))
    # per tile: E[D^2] = 6 var for iid noise
    mean, med, cnt, fmean, fmed, fcnt = tile_stats(
        img, mask if support is None else support, tile, need=need, min_count=MIN_NOISE_SAMPLES
    )
    ok = cnt >= MIN_NOISE_SAMPLES
    # too few differences nearby: the whole chart's estimate, else unknown (0: keep the input)
    enough = fcnt >= MIN_NOISE_SAMPLES
    fmean = np.where(enough, fmean, 0.0)
    fmed = np.where(enough, fmed, 0.0)
    local = neighbour_mean(mean, ok, fmean)
    robust = neighbour_mean(med, ok, fmed) / _CHI2_1_MEDIAN
    local = np.minimum(local, ROBUST_CAP * robust)
    per_texel = np.repeat(np.repeat(local, tile, axis=0), tile, axis=1)[:h, :w]
    return np.where(mask[..., None], per_texel / 6.0, 0.0)


def integrator_iz_variance(stats: dict) -> np.ndarray | None:
    """(n,) float64 per-texel variance of the mean luminance I_z from ``bake_texels``' stats,
    or None when it has none (e.g. a refit from a sidecar): the smaller of its two upper
    bounds, ``iz_variance`` (s^2 / S, tight for a smooth integrand) and
    ``iz_variance_halves`` (the two interleaved halves, tight where stratification pays
    most: a penumbra's s^2 / S is ~8x the real variance, the halves' ~3.5x;
    tests/bake/test_integrate.py)."""
    s2 = stats.get("iz_variance")
    if s2 is None:
        return None
    halves = stats.get("iz_variance_halves")
    s2 = np.asarray(s2, np.float64)
    return s2 if halves is None else np.minimum(s2, np.asarray(halves, np.float64))


def sh_variance(sh: np.ndarray, iz_variance: np.ndarray) -> np.ndarray:
    """Per-coefficient noise variance (n, 3, 9) float64 of radiance SH ``sh (n, 3, 9)`` from
    the integrator's per-texel variance of luminance I_z ``iz_variance (n,)``
    (``bake_texels``' stats), for :func:`denoise_sh`'s blend.

    I_z = IZ_FROM_L10 c10, so var(c10) = var(I_z) / IZ_FROM_L10^2 in luminance; a channel's
    noise scales with its share of the luminance (c00 of that channel / c00 luminance); every
    coefficient is given c10's variance (all are Monte Carlo estimates of the same samples
    weighted by a basis function of the same order of magnitude). Unlike the
    second-difference estimate, a shadow edge or a hotspot does not read as noise here.
    A read-only broadcast view of one (n, 3) array (the denoiser pools it once, not per
    coefficient)."""
    from usdahd.numerics import sh as shm

    sh = np.asarray(sh, np.float64)
    c00 = np.maximum(sh[:, :, 0], 0.0)
    lum = c00 @ np.asarray(shm.LUMINANCE, np.float64)
    share = np.where(lum[:, None] > 0, c00 / np.where(lum > 0, lum, 1.0)[:, None], 1.0)
    var = np.asarray(iz_variance, np.float64)[:, None] / shm.IZ_FROM_L10**2 * share**2
    return np.broadcast_to(var[:, :, None], (len(var), 3, 9))
