"""Half-Life 2 radiosity normal mapping: three colours along a tangent-space basis (Source).

Basis (Valve ``bumpvects.h``; McTaggart 2004), z = normal::

    b0 = ( sqrt(2/3),      0,      1/sqrt(3))
    b1 = (-1/sqrt(6),  1/sqrt(2),  1/sqrt(3))
    b2 = (-1/sqrt(6), -1/sqrt(2),  1/sqrt(3))

Evaluation as in Source's ``LightmappedGeneric`` pixel shader: ``w_i = saturate(n . b_i)^2``,
``I(n) = sum_i w_i C_i / sum_i w_i`` (0 where all w_i are 0, which never happens for
``n_z >= 0``). Params: ``coefficients`` (..., 3, 3) float32, basis b_i x RGB; ``invalid``.

Fit (solver ``hemisphere``): least squares over the upper hemisphere against the SH irradiance.
The model is linear in the colours with basis functions ``w_i / sum w``, which are not
polynomials and have kinks where ``n . b_i = 0``; the Gram matrix and the SH cross terms are
computed once by a quadrature that splits at those kinks (Gauss-Legendre in theta, split at
``cos(theta) = sqrt(2/3)`` where the kink circles enter the hemisphere, and in phi between the
kink points of every theta node), converged to ~1e-13 (tested against a brute-force rule).
This replaces vrad's point sampling of irradiance along each b_i.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from usdahd.models import linear
from usdahd.models.base import check_choice
from usdahd.numerics import sh as shm

NAME = "hl2"
RATIOS = ("none",)
SOLVERS = ("hemisphere",)
DEFAULT_SOLVER = "hemisphere"
BASIS = ("B0", "B1", "B2")

_R23 = np.sqrt(2.0 / 3.0)
#: The three tangent-space basis vectors (rows).
BUMP_BASIS = np.array(
    [
        [_R23, 0.0, 1 / np.sqrt(3)],
        [-1 / np.sqrt(6), 1 / np.sqrt(2), 1 / np.sqrt(3)],
        [-1 / np.sqrt(6), -1 / np.sqrt(2), 1 / np.sqrt(3)],
    ]
)
_BASIS_PHI = np.array([0.0, 2 * np.pi / 3, -2 * np.pi / 3])
#: Quadrature orders of the kink-split rule (theta nodes per piece, phi nodes per segment).
QUAD_THETA = 48
QUAD_PHI = 24


def weights(normals: np.ndarray) -> np.ndarray:
    """Normalized blend weights (..., 3) for unit normals (..., 3) (Source's shader)."""
    n = np.asarray(normals, dtype=np.float64)
    dp = np.clip(n @ BUMP_BASIS.T, 0.0, 1.0) ** 2
    s = dp.sum(axis=-1, keepdims=True)
    return np.where(s > 0, dp / np.where(s > 0, s, 1.0), 0.0)


def kink_quadrature(n_theta: int = QUAD_THETA, n_phi: int = QUAD_PHI):
    """Upper-hemisphere rule that is smooth-exact for :func:`weights`: splits at the kinks.

    returns dirs (n, 3) float64, weights (n,) float64 (summing to 2 pi).
    """
    u, wu = legendre.leggauss(n_theta)
    v, wv = legendre.leggauss(n_phi)
    t0 = np.arccos(_R23)  # below this theta no kink circle n . b_i = 0 is crossed
    dirs, wts = [], []
    for lo, hi in [(0.0, t0), (t0, np.pi / 2)]:
        th = lo + (hi - lo) * (u + 1) / 2
        wt = wu * (hi - lo) / 2 * np.sin(th)
        for t, w in zip(th, wt):
            cut = -1.0 / (np.tan(t) * np.sqrt(2.0))
            br = [0.0, 2 * np.pi]
            if cut >= -1.0:
                dl = np.arccos(cut)
                br += list(np.mod(np.concatenate([_BASIS_PHI + dl, _BASIS_PHI - dl]), 2 * np.pi))
            br = np.unique(br)
            for a, b in zip(br[:-1], br[1:]):
                phi = a + (b - a) * (v + 1) / 2
                dirs.append(
                    np.stack(
                        [
                            np.sin(t) * np.cos(phi),
                            np.sin(t) * np.sin(phi),
                            np.full_like(phi, np.cos(t)),
                        ],
                        -1,
                    )
                )
                wts.append(w * wv * (b - a) / 2)
    return np.concatenate(dirs), np.concatenate(wts)


def _fit_matrices():
    d, w = kink_quadrature()
    b = weights(d)
    gram = np.einsum("ni,nj,n->ij", b, b, w)
    cross = np.einsum("ni,nk,n->ik", b, shm.basis(d), w)
    return gram, cross


#: Gram matrix (3, 3) of the blend weights over Omega+, and their SH products (3, 9).
GRAM, CROSS = _fit_matrices()
#: Fit matrix (3, 9): colours = FIT @ irradiance SH.
FIT = np.linalg.solve(GRAM, CROSS)


def fit(sh, *, ratio="none", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) tangent-space radiance SH -> {coefficients (..., 3, 3), invalid}."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    check_choice(NAME, "solver", solver, SOLVERS)
    x, bad = linear.prepare(sh)
    return linear.finish(linear.apply_fit_matrix(FIT, linear.irradiance_sh(x)), bad)


evaluate, layout, encode, decode = linear.coefficient_model(NAME, BASIS, RATIOS, weights)
