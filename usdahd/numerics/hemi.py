"""Hemisphere and cone multiplies of quadratic SH, hemisphere lights and self-bounce (numpy only).

Formulas of Roughton et al. 2024 ("Hemispherical Lighting Insights"), with the corrections of
issue 2 applied (each pinned by ``tests/test_hemi_corrections.py``):

- App. B Eq 47, row 6 col 2 is ``3*sqrt(5)/16`` (printed ``3*sqrt(5)/15``; the matrix is
  symmetric): :data:`HEMISPHERE_GRAM`.
- Eq 35, row 2 col 5 is ``(n_y^2 - n_x^2) * n_z`` (printed ``... * n_x``): :func:`p2_vector`.
- Eq 43 has ``sqrt(3*pi)/3`` (printed ``sqrt(3)*pi/3``): :func:`hemisphere_light_irradiance_sh`.
- Eq 37 ("order-4 multiply") means: multiply the radiance by the hemisphere into SH bands
  l <= 4, convolve with the normalized clamped cosine through band 4 (A_3 = 0, A_4 = -1/24),
  then solve the IrradZ-constrained HLSH least squares (Eq 19-22) with I_z taken from the
  *untruncated* product (the exact irradiance in the normal). This reproduces the printed
  2203/8192 and 2573/4096 exactly; truncating I_z to band 4 gives 2211/8192, a band-2 multiply
  gives 2200/8192 and 2588/4096: :data:`HLSH_HEMISPHERE_MATRIX`, :func:`cone_hlsh_matrix`.
- Eq 20: the I_z term integrates over the upper hemisphere Omega+ (printed Omega), giving
  ``HLSH_B_Z = [pi/3, 0, 0]`` as used in Eq 22.

Conventions are those of :mod:`usdahd.numerics.sh`: SH order
``[Y00, Y1-1, Y10, Y11, Y2-2, ..., Y22]``, colour SH ``(..., C, 9)``, irradiance normalized
(uniform sky radiance 1 -> 1). In SH slot order a linear-band vector is ``[-y, z, -x]`` times
``sqrt(3/(4 pi))``; ``n_sh = [-n_y, n_z, -n_x]``.

**Do not hemisphere-multiply data that is already hemispherical in tangent space** (the
tangent-space radiance SH every fitter receives): on SH truncated to band 2 the multiply is not
idempotent (``G @ G != G``), so a second multiply throws away upper-hemisphere signal and raises
the error 1.7-5x. The multiplies here are for *spherical* radiance: volumetric probes, distant
environments or world-space bakes on curved surfaces.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics import sh as _sh

__all__ = ["HEMISPHERE_GRAM", "self_bounce"]

_PI = np.pi
_SQRT_PI = np.sqrt(np.pi)
_S3PI = np.sqrt(3.0 * np.pi)
_R3 = np.sqrt(3.0)
_R5 = np.sqrt(5.0)
_R15 = np.sqrt(15.0)

#: Gram matrix of the 9 SH basis functions over the upper hemisphere z >= 0, in closed form
#: (2024 App. B Eq 47 with row 6 col 2 corrected to 3*sqrt(5)/16). G[k, l] = int_{z>0} Y_k Y_l.
HEMISPHERE_GRAM = np.diag(np.full(9, 0.5))
for _k, _l, _v in [(0, 2, _R3 / 4), (1, 5, 3 * _R5 / 16), (2, 6, _R15 / 16), (3, 7, 3 * _R5 / 16)]:
    HEMISPHERE_GRAM[_k, _l] = HEMISPHERE_GRAM[_l, _k] = _v
HEMISPHERE_GRAM.flags.writeable = False

#: Normalized clamped-cosine (radiance -> irradiance) factor per band through band 4.
COSINE_BAND_FACTORS_L4 = np.array([1.0, 2.0 / 3.0, 1.0 / 4.0, 0.0, -1.0 / 24.0])

#: HLSH solve (2024 Eq 19-22): G_B = int_{Omega+} B B^T = (2 pi / 3) I for B = (1 - z, x, y).
HLSH_GRAM_B = (2.0 * _PI / 3.0) * np.eye(3)
#: int_{Omega+} B(w) w_z dw (Eq 20, over the upper hemisphere; over the sphere it is
#: [-4 pi / 3, 0, 0], which would not give Eq 22).
HLSH_B_Z = np.array([_PI / 3.0, 0.0, 0.0])


def _poly(c, coeffs):
    """Evaluate sum_k coeffs[k] c^k (Horner). c : (...) float."""
    out = np.zeros_like(c, dtype=np.float64) + coeffs[-1]
    for a in coeffs[-2::-1]:
        out = out * c + a
    return out


# Cone-multiply HLSH coefficients as exact polynomials in c = cos(alpha) (derived by the band-4
# procedure above for the cone z > c; c = 0 is the hemisphere, Eq 37; all vanish at c = 1).
# Each entry: (scale, polynomial coefficients in increasing powers of c).
_CONE = {
    "a0": (1 / (4 * _SQRT_PI), [1, -1767 / 1024, 1 / 2, 105 / 512, 0, 21 / 1024]),
    "a1": (1 / (8192 * _S3PI), [2203, 0, -5301, 2048, 945, 0, 105]),
    "a2": (
        _R5 / (128 * _SQRT_PI),
        [-7, 1767 / 64, -8, -1977 / 64, 12, 357 / 64, 0, 45 / 64],
    ),
    "b1": (1 / (4096 * _S3PI), [-2573, 3072, 945, -1024, -315, 0, -105]),
    "b2": (_R15 / (128 * _SQRT_PI), [-11, 0, 16, 105 / 16, -8, -21 / 8, 0, -15 / 16]),
    "i0": (1 / (2 * _SQRT_PI), [1, 0, -1]),
    "i1": (1 / _S3PI, [1, 0, 0, -1]),
    "i2": (_R5 / (8 * _SQRT_PI), [1, 0, 2, 0, -3]),
}


def cone_hlsh_coefficients(alpha) -> dict[str, np.ndarray]:
    """Scalar coefficients of the cone multiply to HLSH, as functions of the half-angle.

    For tangent-space radiance SH ``l`` and a visibility cone of half-angle ``alpha`` around z::

        I_z = i0 l0 + i1 l1^0 + i2 l2^0      (exact irradiance in z of the cone-masked radiance)
        C_a = a0 l0 + a1 l1^0 + a2 l2^0
        c_x = b1 l1^1 + b2 l2^1,   c_y = b1 l1^-1 + b2 l2^-1

    alpha : (...) float radians in [0, pi] (pi/2 = hemisphere, giving Eq 37).
    returns : dict of (...) float64 arrays with keys a0 a1 a2 b1 b2 i0 i1 i2.
    """
    c = np.cos(np.asarray(alpha, dtype=np.float64))
    return {k: s * _poly(c, p) for k, (s, p) in _CONE.items()}


def cone_hlsh_matrix(alpha=np.pi / 2) -> np.ndarray:
    """Tangent-space matrix: radiance SH -> cone-multiplied, cosine-convolved HLSH.

    Rows are ``[I_z, C_a, c_x, c_y]`` (HLSH basis ``(z, 1 - z, x, y)`` of 2024 Eq 14), so
    ``I(n) = I_z n_z + C_a (1 - n_z) + c_x n_x + c_y n_y``. With ``alpha = pi/2`` rows 1-3 are
    2024 Eq 37. alpha : (...) float. returns : (..., 4, 9) float64.
    """
    k = cone_hlsh_coefficients(alpha)
    m = np.zeros(np.shape(k["a0"]) + (4, 9))
    m[..., 0, 0], m[..., 0, 2], m[..., 0, 6] = k["i0"], k["i1"], k["i2"]
    m[..., 1, 0], m[..., 1, 2], m[..., 1, 6] = k["a0"], k["a1"], k["a2"]
    m[..., 2, 3], m[..., 2, 7] = k["b1"], k["b2"]
    m[..., 3, 1], m[..., 3, 5] = k["b1"], k["b2"]
    return m


#: 2024 Eq 37 (rows C_a, c_x, c_y): tangent-space radiance SH -> hemisphere-multiplied HLSH.
HLSH_HEMISPHERE_MATRIX = cone_hlsh_matrix()[1:]
HLSH_HEMISPHERE_MATRIX.flags.writeable = False


def _nsh(n):
    """Normals (..., 3) -> SH-slot vector [-n_y, n_z, -n_x] (..., 3)."""
    return np.stack([-n[..., 1], n[..., 2], -n[..., 0]], axis=-1)


def _from_nsh(v):
    """SH-slot vector [-y, z, -x] (..., 3) -> Cartesian (x, y, z) (..., 3)."""
    return np.stack([-v[..., 2], -v[..., 0], v[..., 1]], axis=-1)


def _as_normals(sh, normals):
    sh = np.asarray(sh, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)[..., None, :]  # broadcast over the colour axis
    return sh, n


def p2_vector(l2: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Band-2 -> band-1 part of the oriented hemisphere multiply (2024 Eq 35, corrected).

    The tangential band-2 coefficients ``[l2^-1', 0, l2^1']`` in the frame whose z is ``n``,
    rotated back and returned as a linear-band vector in SH slot order (the normal component is
    zero). Row 2 col 5 is ``(n_y^2 - n_x^2) n_z`` (printed ``... n_x``).

    l2 : (..., 5) band-2 coefficients; normals : (..., 3) unit, broadcastable.
    returns : (..., 3) float64.
    """
    l2 = np.asarray(l2, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    m2, m1, m0, p1, p2 = (l2[..., i] for i in range(5))
    xx, yy, zz = x * x, y * y, z * z
    r0 = (
        (2 * yy - 1) * x * m2
        - (2 * yy - 1) * z * m1
        + _R3 * y * zz * m0
        - 2 * x * y * z * p1
        + (xx - yy + 1) * y * p2
    )
    r1 = (
        -2 * x * y * z * m2
        + (2 * zz - 1) * y * m1
        + _R3 * (1 - zz) * z * m0
        + (2 * zz - 1) * x * p1
        + (yy - xx) * z * p2
    )
    r2 = (
        (2 * xx - 1) * y * m2
        - 2 * x * y * z * m1
        + _R3 * x * zz * m0
        - (2 * xx - 1) * z * p1
        + (xx - yy - 1) * x * p2
    )
    return np.stack([r0, r1, r2], axis=-1)


def zonal_l2(l2: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Zonal band-2 coefficient about ``n``: sqrt(4 pi / 5) Y_2(n) . l2 (2024 Eq 38).

    l2 : (..., 5); normals : (..., 3) unit, broadcastable. returns : (...) float64.
    """
    y2 = _sh.basis(np.asarray(normals, dtype=np.float64))[..., 4:]
    return np.sqrt(4 * _PI / 5) * np.einsum("...k,...k->...", np.asarray(l2, np.float64), y2)


def hemisphere_multiply_linear(sh: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Oriented quadratic -> linear hemisphere multiply (2024 Eq 34-36).

    The first four SH coefficients of ``H_n(w) L(w)`` (H_n = 1 on the hemisphere around ``n``,
    0 below), exactly, without rotating the SH: the result feeds a direct HHD solve (Eq 7-11).
    For spherical radiance only (see the module note).

    sh : (..., C, 9) world-space radiance SH; normals : (..., 3) unit, broadcastable against
    ``sh[..., 0, :]``. returns : (..., C, 4) float64 linear radiance SH.
    """
    sh, n = _as_normals(sh, normals)
    nsh = _nsh(n)
    l1 = sh[..., 1:4]
    d = np.einsum("...k,...k->...", nsh, l1)
    p0 = 0.5 * sh[..., 0] + (_R3 / 4) * d  # Eq 34
    iz = _sh.irradiance(sh, normals)  # exact for band-2 radiance: the I_z of Eq 36
    p1 = (  # Eq 36
        0.5 * (l1 - d[..., None] * nsh)
        + (_S3PI / 2) * iz[..., None] * nsh
        + (3 * _R5 / 16) * p2_vector(sh[..., 4:], n)
    )
    return np.concatenate([p0[..., None], p1], axis=-1)


def hlsh_multiply(sh: np.ndarray, normals: np.ndarray, alpha=np.pi / 2):
    """Hemisphere (alpha = pi/2, 2024 Eq 38-40) or cone (Sec 5.2.1) multiply to world-space HLSH.

    Spherical radiance SH is multiplied by the cone of half-angle ``alpha`` around ``n``,
    cosine-convolved, and solved to HLSH with the IrradZ constraint, all without rotating
    the SH. Irradiance is then ``I(m) = C_a + c . m`` for any unit ``m``; ``c . n = I_z - C_a``,
    so ``I(n) = I_z`` exactly (the irradiance in ``n`` of the cone-masked radiance).

    sh : (..., C, 9) world-space radiance SH; normals : (..., 3) unit, broadcastable against
    ``sh[..., 0, :]``; alpha : scalar or (...) half-angle in radians (broadcastable against
    ``sh[..., 0, 0]``).
    returns : (ca (..., C), c (..., C, 3)) float64; c is a Cartesian (x, y, z) vector.
    """
    sh, n = _as_normals(sh, normals)
    k = cone_hlsh_coefficients(np.asarray(alpha, dtype=np.float64)[..., None])
    nsh = _nsh(n)
    l1 = sh[..., 1:4]
    d = np.einsum("...k,...k->...", nsh, l1)
    pz = zonal_l2(sh[..., 4:], n)
    ca = k["a0"] * sh[..., 0] + k["a1"] * d + k["a2"] * pz  # Eq 39
    iz = k["i0"] * sh[..., 0] + k["i1"] * d + k["i2"] * pz
    s = (  # Eq 40 in SH slot order: [-c_y, c_z, -c_x]
        -k["b1"][..., None] * (l1 - d[..., None] * nsh)
        - k["b2"][..., None] * p2_vector(sh[..., 4:], n)
        + (iz - ca)[..., None] * nsh
    )
    return ca, _from_nsh(s)


def hlsh_irradiance(ca: np.ndarray, c: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Evaluate world-space HLSH from :func:`hlsh_multiply`: ``C_a + c . m``.

    ca : (..., C); c : (..., C, 3); normals : (..., 3). returns : (..., C).
    """
    m = np.asarray(normals, dtype=np.float64)[..., None, :]
    return ca + np.einsum("...k,...k->...", c, m)


def tangent_hemisphere_multiply(sh: np.ndarray) -> np.ndarray:
    """Least-squares hemisphere multiply in tangent space: ``G @ l`` (2024 Sec 5, App. B).

    For spherical SH only: it is not idempotent on band-2 SH (see the module note).
    sh : (..., C, 9). returns : (..., C, 9) float64.
    """
    return np.asarray(sh, dtype=np.float64) @ HEMISPHERE_GRAM


def hemisphere_light_sh(h: np.ndarray) -> np.ndarray:
    """Radiance SH of a unit-radiance hemisphere light oriented along ``h`` (2024 Eq 42).

    ``[sqrt(pi), sqrt(3 pi)/2 * h_sh, 0 x 5]`` (band 2 of a hemisphere is zero).
    h : (..., 3) unit. returns : (..., 9) float64.
    """
    h = np.asarray(h, dtype=np.float64)
    out = np.zeros(h.shape[:-1] + (9,))
    out[..., 0] = _SQRT_PI
    out[..., 1:4] = (_S3PI / 2) * _nsh(h)
    return out


def hemisphere_light_irradiance_sh(h: np.ndarray) -> np.ndarray:
    """Cosine-convolved SH of the unit hemisphere light (2024 Eq 43, corrected).

    ``[sqrt(pi), sqrt(3 pi)/3 * h_sh, 0 x 5]`` (printed ``sqrt(3) pi / 3``). Evaluated in n it
    gives ``(1 + h . n) / 2`` (Eq 45). h : (..., 3) unit. returns : (..., 9) float64.
    """
    return hemisphere_light_sh(h) * _sh.COSINE_FACTORS


def self_bounce(
    iz: np.ndarray,
    normals: np.ndarray,
    albedo: np.ndarray,
    vertex_normals: np.ndarray | None = None,
) -> np.ndarray:
    """IrradZ self-bounce term (2024 App. A, Eq 41): ``albedo * I_z * (1 - n_v . n) / 2``.

    Normalized irradiance that a normal-mapped normal ``n`` receives from the surface itself, a
    Lambertian plane of ``albedo`` lit by ``I_z``. Reference decoders add it to their evaluation
    when given an albedo; any model can use it: pass the model's own irradiance in the vertex
    normal as ``iz`` (for IrradZ models the stored I_z).

    iz : (..., C) irradiance in the vertex normal; normals : (..., 3) unit shading normals;
    albedo : (..., C) in [0, 1]; vertex_normals : (..., 3) or None for tangent space (z).
    All broadcast. returns : (..., C) float64.
    """
    n = np.asarray(normals, dtype=np.float64)
    cos = n[..., 2] if vertex_normals is None else np.einsum("...k,...k->...", n, vertex_normals)
    w = 0.5 * (1.0 - cos)
    return np.asarray(albedo, np.float64) * np.asarray(iz, np.float64) * w[..., None]
