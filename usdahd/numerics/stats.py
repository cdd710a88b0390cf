"""Error statistics with one name per definition (numpy only).

"Relative hemispherical RMSE" has meant four different numbers in this project; each now has
one name and one function here, and every report says which one it gives (docs/validate.md,
docs/benchmarks.md, ``usdahd fit``):

========================================  ==================================================
name                                      definition (``got``, ``ref`` (n, d, 3) irradiance
                                          at d upper-hemisphere normals of n texels)
========================================  ==================================================
:func:`rmse_over_mean_abs` (per texel)    sqrt(mean_{d,c} (got - ref)^2) / mean_{d,c} |ref|
:func:`pooled_rmse_over_mean_abs`         sqrt(mean_{n,d,c} (got - ref)^2) / mean_{n,d,c}
                                          |ref|: one number for a set of texels (a prim)
:func:`rmse_over_rms` (per texel)         sqrt(int (got - ref)^2 / int ref^2) over the
                                          hemisphere (quadrature sums ``err``, ``energy``)
:func:`pooled_rmse_over_rms`              sqrt(sum_n err / sum_n energy): dominated by
                                          bright texels, as an image difference is
========================================  ==================================================

The "over mean |ref|" pair is what ``usdahd validate`` (EncodingError) and ``usdahd fit``
report; the "over RMS" pair is what ``benchmarks/`` reports (``benchmarks/common.py``). For
a texel with a constant target the two per-texel numbers agree; in general
``rmse_over_rms <= rmse_over_mean_abs``, since RMS >= mean |.|.

Student's t distribution (the Retrace rule's quantiles) is here too, in numpy/math only: the
regularized incomplete beta :func:`betainc` by its continued fraction, :func:`t_sf` and the
cached inverse :func:`t_isf`. The chi-squared test of the samplers is a test helper
(``tests/stats.py``): no package module uses it.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from usdahd.errors import UsageError

__all__ = [
    "betainc",
    "pooled_rmse_over_mean_abs",
    "pooled_rmse_over_rms",
    "rmse_over_mean_abs",
    "rmse_over_rms",
    "t_isf",
    "t_sf",
]


def _scale(ref: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    return np.abs(ref).mean(axis=(1, 2)) if scale is None else scale


def rmse_over_mean_abs(got: np.ndarray, ref: np.ndarray, scale: np.ndarray | None = None):
    """(n,) per-texel RMSE of ``got - ref`` (n, d, 3) over directions and colours, divided by
    ``scale`` (n,), by default the texel's mean |ref|; 0 where the scale is 0 (a black target
    has no relative error)."""
    sq = ((got - ref) ** 2).mean(axis=(1, 2))
    return np.sqrt(sq) / np.where(_scale(ref, scale) > 0, _scale(ref, scale), np.inf)


def pooled_rmse_over_mean_abs(
    got: np.ndarray, ref: np.ndarray, scale: np.ndarray | None = None
) -> float:
    """RMSE of ``got - ref`` (n, d, 3) over texels, directions and colours, divided by the mean
    of ``scale`` (n,) (by default mean |ref|): the relative error of a set of texels."""
    sq = ((got - ref) ** 2).mean(axis=(1, 2))
    return float(np.sqrt(sq.mean()) / max(float(_scale(ref, scale).mean()), 1e-30))


def rmse_over_rms(err: np.ndarray, energy: np.ndarray) -> np.ndarray:
    """(n,) per-texel sqrt(err / energy) of hemispherical integrals of the squared difference
    ``err`` (n,) and the squared target ``energy`` (n,); NaN where the energy is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(energy > 0, np.sqrt(err / np.where(energy > 0, energy, 1.0)), np.nan)


def pooled_rmse_over_rms(err: np.ndarray, energy: np.ndarray) -> float:
    """sqrt(sum err / sum energy) of a set of texels (the absolute RMS error where the total
    energy is 0)."""
    tot = float(energy.sum())
    return float(np.sqrt(err.sum() / tot)) if tot > 0 else float(np.sqrt(err.sum()))


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the regularized incomplete beta (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 10000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def betainc(a: float, b: float, x: float) -> float:
    """Regularized incomplete beta I_x(a, b) for a, b > 0, x in [0, 1] (float)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x)
    ln += b * math.log1p(-x)
    front = math.exp(ln)
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def t_sf(t: float, dof: float) -> float:
    """P(T > t) for Student's t with ``dof`` degrees of freedom (float)."""
    if dof <= 0:
        raise UsageError(f"the t distribution needs dof > 0, got {dof}")
    if math.isinf(dof):
        return 0.5 * math.erfc(t / math.sqrt(2.0))
    tail = 0.5 * betainc(0.5 * dof, 0.5, dof / (dof + t * t))
    return tail if t >= 0 else 1.0 - tail


@functools.lru_cache(maxsize=256)
def t_isf(p: float, dof: float) -> float:
    """The t with P(T > t) = p, for p in (0, 0.5] (bisection to 1e-12 relative; cached)."""
    if not 0.0 < p <= 0.5:
        raise UsageError(f"t_isf needs 0 < p <= 0.5, got {p}")
    lo, hi = 0.0, 1.0
    while t_sf(hi, dof) > p:
        lo, hi = hi, 2.0 * hi
        if hi > 1e300:
            return math.inf
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_sf(mid, dof) > p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    return 0.5 * (lo + hi)
