"""Real spherical harmonics through band 2 (9 coefficients), numpy only.

Conventions (pinned in docs/conventions.md, tested in tests/test_sh.py):

- Order and signs of Roughton et al. 2024, Eq 2-3::

    [Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22]
    Y00  = 1/(2 sqrt(pi))
    Y1-1 = -sqrt(3/(4pi)) y     Y10 = sqrt(3/(4pi)) z     Y11 = -sqrt(3/(4pi)) x
    Y2-2 = sqrt(15/(4pi)) xy    Y2-1 = -sqrt(15/(4pi)) yz Y20 = sqrt(5/(16pi)) (3z^2 - 1)
    Y21  = -sqrt(15/(4pi)) xz   Y22 = sqrt(15/(16pi)) (x^2 - y^2)

- SH arrays of colour signals have shape ``(..., 3, 9)``: RGB x coefficients.
- Fitter input is tangent-space incident *radiance* SH; z is the surface normal.
- Irradiance is normalized: ``I(n) = (1/pi) * integral L(w) max(0, n.w) dw``, so the
  radiance-to-irradiance band factors are ``[1, 2/3, 1/4]`` and a uniform sky of radiance 1
  gives ``I = 1``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "C0",
    "C1",
    "C2",
    "C20",
    "C22",
    "COSINE_FACTORS",
    "HEMISPHERICAL_GRAM",
    "IZ_FROM_L10",
    "LUMINANCE",
    "SQRT_PI",
    "basis",
    "fibonacci_sphere",
    "irradiance",
    "iz",
]

SQRT_PI = np.sqrt(np.pi)
C0 = 1.0 / (2.0 * SQRT_PI)  # Y00
C1 = np.sqrt(3.0 / (4.0 * np.pi))  # band-1 scale
C2 = np.sqrt(15.0 / (4.0 * np.pi))  # Y2-2, Y2-1, Y21
C20 = np.sqrt(5.0 / (16.0 * np.pi))  # Y20
C22 = np.sqrt(15.0 / (16.0 * np.pi))  # Y22

N_COEFFS = 9
#: Band index of each of the 9 coefficients.
BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])
#: Normalized clamped-cosine convolution factor per band (radiance -> normalized irradiance).
COSINE_BAND_FACTORS = np.array([1.0, 2.0 / 3.0, 1.0 / 4.0])
#: The same per coefficient, shape (9,).
COSINE_FACTORS = COSINE_BAND_FACTORS[BAND]
#: I_z = IZ_FROM_L10 * l_1^0 for radiance that is zero in the lower hemisphere.
IZ_FROM_L10 = 2.0 / np.sqrt(3.0 * np.pi)
#: Rec. 709 / sRGB luminance weights, used for ``ratio="luminance"``.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def basis(dirs: np.ndarray) -> np.ndarray:
    """SH basis functions evaluated at unit directions.

    dirs : (..., 3) float, unit vectors (not renormalized here).
    returns : (..., 9) same float dtype as ``dirs`` (float64 for integer input).
    """
    d = np.asarray(dirs)
    if not np.issubdtype(d.dtype, np.floating):
        d = d.astype(np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = np.empty(d.shape[:-1] + (9,), dtype=d.dtype)
    out[..., 0] = C0
    out[..., 1] = -C1 * y
    out[..., 2] = C1 * z
    out[..., 3] = -C1 * x
    out[..., 4] = C2 * x * y
    out[..., 5] = -C2 * y * z
    out[..., 6] = C20 * (3.0 * z * z - 1.0)
    out[..., 7] = -C2 * x * z
    out[..., 8] = C22 * (x * x - y * y)
    return out


def evaluate(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Evaluate an SH signal in directions (no convolution).

    sh : (..., C, 9) coefficients; dirs : (..., 3) broadcastable against ``sh[..., 0, :]``.
    returns : (..., C).
    """
    return np.einsum("...ck,...k->...c", sh, basis(dirs))


def irradiance(sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Normalized irradiance I(n) of a radiance SH (cosine-convolved, then evaluated).

    sh : (..., C, 9) radiance coefficients; normals : (..., 3) unit vectors.
    returns : (..., C).
    """
    return evaluate(np.asarray(sh) * COSINE_FACTORS, normals)


def iz(sh: np.ndarray) -> np.ndarray:
    """Normalized irradiance in local z of *hemispherical* radiance SH (exact, uses l_1^0 only).

    sh : (..., C, 9).  returns : (..., C).
    """
    return IZ_FROM_L10 * np.asarray(sh)[..., 2]


def project(values: np.ndarray, dirs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Project a sampled signal into SH by quadrature: sum_i w_i f(d_i) Y(d_i).

    values : (n, C) samples; dirs : (n, 3); weights : (n,) quadrature weights (solid angle).
    returns : (C, 9).
    """
    return np.einsum("nc,nk,n->ck", values, basis(dirs), weights)


def sphere_quadrature(n_theta: int = 64, n_phi: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Product Gauss-Legendre (in cos theta) x uniform (in phi) rule over the sphere.

    Exact for polynomials in (x, y, z) of degree < min(2*n_theta, n_phi).
    returns : dirs (n_theta*n_phi, 3) float64, weights (n,) float64 summing to 4*pi.
    """
    n_phi = n_phi or 2 * n_theta
    u, wu = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    return _product_rule(u, wu, phi, 2 * np.pi / n_phi)


def hemisphere_quadrature(
    n_theta: int = 64, n_phi: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Product Gauss-Legendre rule over the upper hemisphere z >= 0 (weights sum to 2*pi).

    Exact for polynomials in (x, y, z) of degree < min(2*n_theta, n_phi) restricted to z > 0,
    which is what makes hemispherical Gram matrices and least-squares fits exact.
    returns : dirs (n, 3) float64, weights (n,) float64.
    """
    n_phi = n_phi or 2 * n_theta
    u, wu = np.polynomial.legendre.leggauss(n_theta)
    z = 0.5 * (u + 1.0)
    wz = 0.5 * wu
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    return _product_rule(z, wz, phi, 2 * np.pi / n_phi)


def _product_rule(z, wz, phi, wphi):
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    dirs = np.stack(
        np.broadcast_arrays(
            s[:, None] * np.cos(phi)[None, :],
            s[:, None] * np.sin(phi)[None, :],
            z[:, None] + 0 * phi[None, :],
        ),
        axis=-1,
    ).reshape(-1, 3)
    w = (wz[:, None] * wphi + 0 * phi[None, :]).reshape(-1)
    return dirs, w


def fibonacci_sphere(n: int, hemisphere: bool = False) -> np.ndarray:
    """Deterministic, nearly uniform unit directions (spherical Fibonacci lattice).

    returns : (n, 3) float64; on the upper hemisphere only if ``hemisphere``.
    """
    i = np.arange(n) + 0.5
    z = 1.0 - i / n if hemisphere else 1.0 - 2.0 * i / n
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of (..., 3) -> (...,)."""
    return np.asarray(rgb) @ LUMINANCE


def hemispherical_gram(n_theta: int = 8) -> np.ndarray:
    """Gram matrix of the 9 SH basis functions over the upper hemisphere, by exact quadrature.

    G[k, l] = integral_{z>0} Y_k Y_l dw. The product of two basis functions is a polynomial of
    degree <= 4, so an 8 x 16 Gauss-Legendre product rule is exact to rounding.
    returns : (9, 9) float64, symmetric positive definite.
    """
    d, w = hemisphere_quadrature(n_theta)
    y = basis(d)
    return np.einsum("nk,nl,n->kl", y, y, w)


#: The hemispherical Gram matrix (9, 9) float64, read-only: :func:`hemispherical_gram` at its
#: default (exact) rule. The one copy the fits and the integrator use (usdahd.numerics.hemi
#: HEMISPHERE_GRAM is its closed form, equal to rounding, tested in tests/test_hemi.py).
HEMISPHERICAL_GRAM = hemispherical_gram()
HEMISPHERICAL_GRAM.flags.writeable = False
