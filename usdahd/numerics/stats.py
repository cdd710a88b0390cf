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

The Student-t quantiles the Retrace rule tests with are :func:`usdahd.validate.retrace.t_isf`
(to move here with that module's restructuring); the chi-squared test of the samplers is a
test helper (``tests/stats.py``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "pooled_rmse_over_mean_abs",
    "pooled_rmse_over_rms",
    "rmse_over_mean_abs",
    "rmse_over_rms",
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
