"""Quadratic (L2) spherical harmonics, plus Enlighten's 4x4 matrix evaluation.

Params: ``coefficients`` (..., 9, 3) float32, the tangent-space radiance SH (usdahd.sh basis,
order and signs of 2024 Eq 2-3) x RGB; ``invalid`` (..., 1). Evaluation is the normalized
irradiance ``I(n) = sum_k A_k l_k Y_k(n)``, A = [1, 2/3, 1/4]. The only solver, ``project``,
stores the input SH itself (the hemispherical least-squares fit of a 9-function basis to a
9-function target is the identity).

Enlighten form (Enlighten documentation, "L2 spherical harmonics"): Enlighten stores the
irradiance polynomial coefficients ``[L00, L11, L10, L1-1, L20, L21, L2-1, L2-2, L22]`` of
``1, x, y, z, 3y^2 - 1, xy, yz, xz, x^2 - z^2`` with the radiance->irradiance constants baked in,
in axes where **y and z are swapped** relative to Ramamoorthi-Hanrahan (and to us): Enlighten's
``(x, y, z)`` is our ``(x, z, y)``, i.e. Enlighten's y is our z (the normal). Then
``I(n) = n4^T M n4`` with ``n4 = (1, x_E, y_E, z_E)`` and the symmetric 4x4 matrix of
:func:`enlighten_matrix`. :func:`enlighten_coefficients` converts our SH, and
:func:`evaluate_enlighten` applies the swap to our normals; both are tested equal to
direct evaluation.
"""

from __future__ import annotations

import numpy as np

from usdahd.models import linear
from usdahd.models.base import check_choice
from usdahd.numerics import sh as shm

NAME = "sh_l2"
RATIOS = ("none",)
SOLVERS = ("project",)
DEFAULT_SOLVER = "project"
BASIS = ("Y00", "Y1m1", "Y10", "Y11", "Y2m2", "Y2m1", "Y20", "Y21", "Y22")

_A1 = 2.0 / 3.0
_A2 = 0.25
#: Enlighten coefficient j = ENLIGHTEN_SCALE[j] * our radiance coefficient ENLIGHTEN_INDEX[j].
#: (Our basis: Y1-1 = -C1 y, Y10 = C1 z, Y11 = -C1 x, Y2-2 = C2 xy, Y2-1 = -C2 yz,
#: Y20 = C20 (3z^2 - 1), Y21 = -C2 xz, Y22 = C22 (x^2 - y^2); with x_E = x, y_E = z, z_E = y.)
ENLIGHTEN_INDEX = np.array([0, 3, 2, 1, 6, 7, 5, 4, 8])
ENLIGHTEN_SCALE = np.array(
    [
        shm.C0,  # L00   : 1
        -shm.C1 * _A1,  # L11   : x_E = x
        shm.C1 * _A1,  # L10   : y_E = z
        -shm.C1 * _A1,  # L1-1  : z_E = y
        shm.C20 * _A2,  # L20   : 3 y_E^2 - 1 = 3 z^2 - 1
        -shm.C2 * _A2,  # L21   : x_E y_E = x z
        -shm.C2 * _A2,  # L2-1  : y_E z_E = z y
        shm.C2 * _A2,  # L2-2  : x_E z_E = x y
        shm.C22 * _A2,  # L22   : x_E^2 - z_E^2 = x^2 - y^2
    ]
)


def fit(sh, *, ratio="none", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) tangent-space radiance SH -> {coefficients (..., 9, 3), invalid}."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    check_choice(NAME, "solver", solver, SOLVERS)
    x, bad = linear.prepare(sh)
    return linear.finish(np.swapaxes(x, -1, -2), bad)


def enlighten_coefficients(coefficients: np.ndarray) -> np.ndarray:
    """Our radiance SH (..., 9, 3) -> Enlighten irradiance coefficients (..., 9, 3) float64."""
    c = np.asarray(coefficients, dtype=np.float64)
    return c[..., ENLIGHTEN_INDEX, :] * ENLIGHTEN_SCALE[:, None]


def enlighten_matrix(enlighten: np.ndarray) -> np.ndarray:
    """Enlighten coefficients (..., 9, 3) -> symmetric matrices (..., 3, 4, 4) per colour.

    Rows (Enlighten documentation)::

        [L00 - L20, L11/2,  L10/2,  L1-1/2]
        [L11/2,     L22,    L21/2,  L2-2/2]
        [L10/2,     L21/2,  3 L20,  L2-1/2]
        [L1-1/2,    L2-2/2, L2-1/2, -L22  ]
    """
    e = np.moveaxis(np.asarray(enlighten, dtype=np.float64), -1, -2)  # (..., 3, 9)
    l00, l11, l10, l1m1, l20, l21, l2m1, l2m2, l22 = (e[..., j] for j in range(9))
    h = 0.5
    rows = [
        [l00 - l20, h * l11, h * l10, h * l1m1],
        [h * l11, l22, h * l21, h * l2m2],
        [h * l10, h * l21, 3.0 * l20, h * l2m1],
        [h * l1m1, h * l2m2, h * l2m1, -l22],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def evaluate_enlighten(matrix: np.ndarray, normals: np.ndarray, *, clamp: bool = True):
    """Enlighten ``RamaL2``: ``n4^T M n4`` per colour, n4 = (1, x, z, y) from our normals.

    matrix : (..., 3, 4, 4); normals : (..., 3) unit (our tangent axes; swapped here).
    clamp : max(0, .) as Enlighten's shader does. returns (..., 3) float64.
    """
    n = np.asarray(normals, dtype=np.float64)
    one = np.ones(n.shape[:-1] + (1,))
    n4 = np.concatenate([one, n[..., 0:1], n[..., 2:3], n[..., 1:2]], axis=-1)[..., None, :]
    out = np.einsum("...i,...ij,...j->...", n4, matrix, n4)
    return np.maximum(out, 0.0) if clamp else out


def _weights(n):
    """(..., 9) float64: the SH basis times the cosine-lobe factors (irradiance = sum w_k C_k)."""
    return shm.basis(n) * shm.COSINE_FACTORS


evaluate, layout, encode, decode = linear.coefficient_model(NAME, BASIS, RATIOS, _weights)
