"""Valve's ambient cube: six RGB colours blended by the squared normal (Source engine).

Evaluation (McTaggart 2004; Mitchell et al. 2006)::

    I(n) = n_x^2 C[+x or -x] + n_y^2 C[+y or -y] + n_z^2 C[+z or -z]

choosing the face by the sign of each component. Params: ``coefficients`` (..., 6, 3) float32 in
Valve's order ``[+x, -x, +y, -y, +z, -z]`` x RGB (tangent space, z = normal), ``invalid``.

Fit (solver ``hemisphere``): least squares over the upper hemisphere against the SH irradiance,
exact: the basis functions ``x^2 [x > 0]`` ... are polynomials on octants, so their Gram matrix
and their products with the SH basis are sums of closed-form octant moments
``int x^a y^b z^c = G((a+1)/2) G((b+1)/2) G((c+1)/2) / (4 G((a+b+c+3)/2))``. No point sampling.
The ``-z`` face is never seen by upper-hemisphere normals, so least squares cannot determine it;
it is set to 0, the true irradiance at ``-z`` of radiance that is zero below the horizon.
"""

from __future__ import annotations

import itertools
from math import gamma

import numpy as np

from usdahd.models import linear
from usdahd.models.base import check_choice
from usdahd.numerics import sh as shm

NAME = "ambient_cube"
RATIOS = ("none",)
SOLVERS = ("hemisphere",)
DEFAULT_SOLVER = "hemisphere"
BASIS = ("posX", "negX", "posY", "negY", "posZ", "negZ")

# SH basis functions as polynomials {(a, b, c): coefficient of x^a y^b z^c} on the sphere.
_SH_POLY = [
    {(0, 0, 0): shm.C0},
    {(0, 1, 0): -shm.C1},
    {(0, 0, 1): shm.C1},
    {(1, 0, 0): -shm.C1},
    {(1, 1, 0): shm.C2},
    {(0, 1, 1): -shm.C2},
    {(0, 0, 2): 3 * shm.C20, (0, 0, 0): -shm.C20},
    {(1, 0, 1): -shm.C2},
    {(2, 0, 0): shm.C22, (0, 2, 0): -shm.C22},
]
# The five fitted faces over z > 0: (polynomial, sign constraint per axis; 0 = unconstrained).
_FACES = [
    ({(2, 0, 0): 1.0}, (1, 0, 1)),
    ({(2, 0, 0): 1.0}, (-1, 0, 1)),
    ({(0, 2, 0): 1.0}, (0, 1, 1)),
    ({(0, 2, 0): 1.0}, (0, -1, 1)),
    ({(0, 0, 2): 1.0}, (0, 0, 1)),
]


def _octant_moment(a: int, b: int, c: int) -> float:
    """Integral of |x|^a |y|^b |z|^c over one octant of the unit sphere."""
    al, be, ga = (a + 1) / 2, (b + 1) / 2, (c + 1) / 2
    return gamma(al) * gamma(be) * gamma(ga) / (4.0 * gamma(al + be + ga))


def _region_integral(poly: dict, signs) -> float:
    """Exact integral of a polynomial over the part of the sphere with the given axis signs."""
    axes = [(s,) if s else (1, -1) for s in signs]
    total = 0.0
    for ex, ey, ez in itertools.product(*axes):
        for (a, b, c), k in poly.items():
            total += k * ex**a * ey**b * ez**c * _octant_moment(a, b, c)
    return total


def _mul(p: dict, q: dict) -> dict:
    out: dict = {}
    for (a, b, c), u in p.items():
        for (d, e, f), v in q.items():
            key = (a + d, b + e, c + f)
            out[key] = out.get(key, 0.0) + u * v
    return out


def _meet(s, t):
    """Intersection of two sign regions, or None if empty."""
    out = []
    for a, b in zip(s, t):
        if a and b and a != b:
            return None
        out.append(a or b)
    return tuple(out)


def _fit_matrices() -> tuple[np.ndarray, np.ndarray]:
    gb = np.zeros((5, 5))
    p = np.zeros((5, 9))
    for i, (pi, si) in enumerate(_FACES):
        for j, (pj, sj) in enumerate(_FACES):
            r = _meet(si, sj)
            gb[i, j] = 0.0 if r is None else _region_integral(_mul(pi, pj), r)
        for k, yk in enumerate(_SH_POLY):
            p[i, k] = _region_integral(_mul(pi, yk), si)
    return gb, p


#: Gram matrix (5, 5) of the fitted faces over Omega+ and their SH products (5, 9), exact.
GRAM, CROSS = _fit_matrices()
#: Fit matrix (6, 9): colours = FIT @ irradiance SH (row 5, the -z face, is zero).
FIT = np.vstack([np.linalg.solve(GRAM, CROSS), np.zeros((1, 9))])


def fit(sh, *, ratio="none", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) tangent-space radiance SH -> {coefficients (..., 6, 3), invalid}."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    check_choice(NAME, "solver", solver, SOLVERS)
    x, bad = linear.prepare(sh)
    return linear.finish(linear.apply_fit_matrix(FIT, linear.irradiance_sh(x)), bad)


def weights(normals: np.ndarray) -> np.ndarray:
    """Blend weights (..., 6) of the six faces for unit normals (..., 3) (Valve's selection)."""
    n = np.asarray(normals, dtype=np.float64)
    n2 = n * n
    neg = n < 0
    w = np.zeros(n.shape[:-1] + (6,))
    for axis in range(3):
        w[..., 2 * axis] = np.where(neg[..., axis], 0.0, n2[..., axis])
        w[..., 2 * axis + 1] = np.where(neg[..., axis], n2[..., axis], 0.0)
    return w


evaluate, layout, encode, decode = linear.coefficient_model(NAME, BASIS, RATIOS, weights)
