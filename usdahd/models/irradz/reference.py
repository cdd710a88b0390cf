"""IrradZ reference (numpy): tolerances, model constants, formulas, solves and evaluate.

These are the oracles the numba kernel (:mod:`usdahd.models.irradz.kernel`) is tested
against, and what the direct solvers, ``evaluate`` and the validator use. Overview of the
models, parameters and solvers: :mod:`usdahd.models.irradz` and docs/models.md.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics import encoding
from usdahd.numerics import sh as shm
from usdahd.numerics.hemi import self_bounce

__all__ = [
    "AMB_AHD",
    "AMB_HHD",
    "B_Z",
    "DZ_FLOOR",
    "GOLDEN_ITERS",
    "GOLDEN_SCAN",
    "GRAM_I",
    "GRAM_J",
    "GRAM_PAIRS",
    "G_BY",
    "G_B_SCALE",
    "IZ_FROM_L10",
    "IZ_MAX",
    "IZ_TINY",
    "KINDS",
    "PHI_HALF_WIDTH",
    "PHI_ITERS",
    "PHI_SCAN",
    "SOLVERS",
    "SQRT_PI",
    "WA_ONE",
    "ambient_sh",
    "c_bounded",
    "colors",
    "directional_sh",
    "evaluate",
    "expand",
    "gram_hemi",
    "hhd_direct_linear",
    "hlsh_direct",
    "linear_sh",
    "model_sh",
    "nullspace_bounds",
    "nullspace_colors",
    "sh_error",
    "sparse_gram",
    "wa_bounded",
    "wa_literal",
]

# ---------------------------------------------------------------------------------------------
# Tolerances, in one place, with the reason for each.
#: Smallest d_z: an 8-bit hemi-octahedral code cannot decode anything closer to the horizon
#: (encoding.OCT_CODE_MAX), and C_d = I_z (1 - w_a) / d_z must stay finite.
DZ_FLOOR = encoding.DZ_MIN
#: I_z at or below this fraction of the texel's max |coefficient| is treated as zero light:
#: w_a = 1, d = z (w_a = C_a / I_z is meaningless there). 1e-7 ~ float32 epsilon.
IZ_TINY = 1e-7
#: w_a this close to 1 means no directional light: d is set to z (its value is then arbitrary
#: and would only add quantization noise and interpolation artifacts).
WA_ONE = 1.0 - 1e-7
#: d_z search (solver "golden"): a uniform scan of GOLDEN_SCAN points brackets the minimum
#: (E(d_z) is not always unimodal), GOLDEN_ITERS golden-section steps shrink the bracket
#: (width 2/7 * 0.618^k), then one parabolic step through the best point and its neighbours.
#: Measured in docs/models.md: 16 golden steps alone left up to 1e-4 of the target energy
#: unfitted on sun-dominated texels (sharp minima); 16 + the parabolic step leave < 1e-6.
GOLDEN_SCAN = 8
GOLDEN_ITERS = 16
#: Outer phi search (golden_phi): half-width of the phi interval around the optimal-linear phi,
#: scan and golden steps. The optimal-linear phi is also evaluated, so the result is never worse.
PHI_HALF_WIDTH = np.pi / 3.0
PHI_SCAN = 6
PHI_ITERS = 10
#: Largest float32.
F32_MAX = float(np.finfo(np.float32).max)
#: Largest I_z output: x1e200 inputs are clipped here, leaving float32 headroom for
#: C_d <= 127 I_z and for the float16 pre-scale's rounding (no real light gets near it).
IZ_MAX = 1e36

KINDS = ("ahd", "hhd", "hlsh")
SOLVERS = {
    "ahd": ("golden", "golden_phi", "2018_sphere", "2018_hemi"),
    "hhd": ("golden", "golden_phi", "direct", "2018_sphere", "2018_hemi"),
    "hlsh": ("direct",),
}

# ---------------------------------------------------------------------------------------------
# Constants of the models in (normalized) irradiance SH. Each is checked by quadrature in
# tests/test_models_irradz.py and tests/test_irradz_corrections.py.
SQRT_PI = shm.SQRT_PI
#: Irradiance SH of a unit ambient light (AHD): constant 1 -> Y00 coefficient 2 sqrt(pi).
AMB_AHD = np.array([2.0 * SQRT_PI, 0, 0, 0, 0, 0, 0, 0, 0])
#: Irradiance SH of a unit hemisphere light around z (HHD): radiance SH of 2024 Eq 42
#: [sqrt(pi), 0, sqrt(3 pi)/2, 0, 0...] times the cosine factors [1, 2/3, 1/4]; the band-1
#: value is sqrt(3 pi)/3 (2024 Eq 43 prints sqrt(3) pi / 3, which is wrong).
AMB_HHD = np.array([SQRT_PI, 0, np.sqrt(3.0 * np.pi) / 3.0, 0, 0, 0, 0, 0, 0])
#: I_z from the radiance l_1^0 of hemispherical data, 2/sqrt(3 pi) (2024 Eq 28 prints
#: 2/(sqrt(3) pi), which is wrong).
IZ_FROM_L10 = shm.IZ_FROM_L10
#: G_BY of 2024 Eq 21 with corrected signs: rows B = (1 - z, x, y), columns the 9 SH functions,
#: integrated over the upper hemisphere.
G_BY = np.zeros((3, 9))
G_BY[0, 0] = SQRT_PI / 2.0
G_BY[0, 2] = np.sqrt(np.pi / 12.0)
G_BY[0, 6] = -np.sqrt(5.0 * np.pi) / 8.0
G_BY[1, 3] = -np.sqrt(np.pi / 3.0)
G_BY[1, 7] = -np.sqrt(15.0 * np.pi) / 8.0
G_BY[2, 1] = -np.sqrt(np.pi / 3.0)
G_BY[2, 5] = -np.sqrt(15.0 * np.pi) / 8.0
#: 2024 Eq 20 (over Omega+): integral of B(w) w_z over the upper hemisphere = (pi/3, 0, 0).
B_Z = np.array([np.pi / 3.0, 0.0, 0.0])
#: G_B = integral over Omega+ of B B^T = (2 pi / 3) I.
G_B_SCALE = 2.0 * np.pi / 3.0

#: Off-diagonal index pairs of the hemispherical Gram matrix (all others are zero, tested).
GRAM_PAIRS = np.array([[0, 2], [1, 5], [2, 6], [3, 7]])
GRAM_I = GRAM_PAIRS[:, 0].copy()
GRAM_J = GRAM_PAIRS[:, 1].copy()


def gram_hemi() -> np.ndarray:
    """Hemispherical Gram (9, 9) float64, read-only: usdahd.numerics.sh.HEMISPHERICAL_GRAM."""
    return shm.HEMISPHERICAL_GRAM


def sparse_gram(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(diag (9,), off (4,)) for the GRAM_PAIRS structure; identity -> (ones, zeros)."""
    return np.ascontiguousarray(np.diag(g)), np.array([g[i, j] for i, j in GRAM_PAIRS])


# ---------------------------------------------------------------------------------------------
# Reference (numpy) formulas, used by the solvers and as test oracles.


def directional_sh(d: np.ndarray) -> np.ndarray:
    """Irradiance SH of a unit directional light (C_d = 1) in directions d: pi conv(Y(d)).

    d : (..., 3) unit. returns (..., 9) float64. Evaluates to the band-2 truncation of
    max(0, n.d).
    """
    return np.pi * shm.basis(np.asarray(d, dtype=np.float64)) * shm.COSINE_FACTORS


def ambient_sh(kind: str) -> np.ndarray:
    """Irradiance SH (9,) of the unit ambient term: constant (ahd, hlsh) or hemisphere (hhd)."""
    return AMB_HHD if kind == "hhd" else AMB_AHD


def linear_sh(d: np.ndarray) -> np.ndarray:
    """Irradiance SH of the linear function n.d (HLSH's directional term). (..., 9) float64."""
    y = shm.basis(np.asarray(d, dtype=np.float64)) * (4.0 * np.pi / 3.0)
    y[..., [0, 4, 5, 6, 7, 8]] = 0.0
    return y


def colors(params: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C_a, C_d, d) from IrradZ params, float64, broadcast to (..., 3)."""
    iz = np.asarray(params["iz"], dtype=np.float64)
    d = np.asarray(params["direction"], dtype=np.float64)
    wa = np.asarray(params["ambient_ratio"], dtype=np.float64)
    dz = np.maximum(d[..., 2:3], DZ_FLOOR)
    return iz * wa, iz * (1.0 - wa) / dz, d


def model_sh(kind: str, params: dict) -> np.ndarray:
    """Irradiance SH (..., 3, 9) of the fitted model (band-2 truncation for ahd/hhd)."""
    ca, cd, d = colors(params)
    if kind == "hlsh":
        dirs = linear_sh(d)
        amb = AMB_AHD
    else:
        dirs = directional_sh(d)
        amb = ambient_sh(kind)
    return ca[..., None] * amb + cd[..., None] * dirs[..., None, :]


def sh_error(kind: str, sh: np.ndarray, params: dict, gram: np.ndarray | None = None):
    """SH-domain squared error per texel and channel: (m - t)^T G (m - t), G hemispherical.

    sh : (..., 3, 9) radiance; returns (..., 3) float64 (integral over the hemisphere of the
    squared irradiance difference, for the band-2 truncations).
    """
    g = gram_hemi() if gram is None else gram
    r = model_sh(kind, params) - np.asarray(sh, dtype=np.float64) * shm.COSINE_FACTORS
    return np.einsum("...k,kl,...l->...", r, g, r)


def wa_literal(a, d_sh, i, gram):
    """2024 Eq 33 as printed: w_a = (a - d)^T G (i - d) / (a - d)^T G (a - d).

    a : (9,) ambient irradiance SH; d_sh : (..., 9) = pi conv(Y(d)) / d_z (terms ~ 1/d_z);
    i : (..., 9) target / I_z. Reference for tests; the solvers use :func:`wa_bounded`.
    """
    am = a - d_sh
    num = np.einsum("...k,kl,...l->...", am, gram, i - d_sh)
    den = np.einsum("...k,kl,...l->...", am, gram, am)
    return num / den


def c_bounded(a, dir_sh, dz, i, gram):
    """Eq 33 solved for c = C_d / I_z = (1 - w_a) / d_z, bounded by 1/d_z for w_a in [0, 1]:
    c = u^T G (i - a) / u^T G u with u = pi conv(Y(d)) - d_z a (no 1/d_z anywhere).

    a : (9,); dir_sh : (..., 9) = pi conv(Y(d)); dz : (...,); i : (..., 9) target / I_z.
    Reference (numpy, any float dtype) of what the numba kernel does per texel.
    """
    u = dir_sh - dz[..., None] * a
    r = i - a
    return np.einsum("...k,kl,...l->...", u, gram, r) / np.einsum("...k,kl,...l->...", u, gram, u)


def wa_bounded(a, dir_sh, dz, i, gram):
    """w_a = 1 - c d_z with c from :func:`c_bounded`."""
    return 1.0 - c_bounded(a, dir_sh, dz, i, gram) * dz


def nullspace_colors(iz, dz, t):
    """2018 Eq 11: (C_a, C_d) = I_z/(d_z^2+1) (1, d_z) + t (-d_z, 1)."""
    base = iz / (dz * dz + 1.0)
    return base - t * dz, base * dz + t


def nullspace_bounds(iz, dz):
    """[t_min, t_max] of 2018 Eq 11 for C_a >= 0 and C_d >= 0 (I_z >= 0)."""
    base = iz / (dz * dz + 1.0)
    return -base * dz, base / dz


# ---------------------------------------------------------------------------------------------
# Direct solves.


def hhd_direct_linear(l0, l1m1, l10, l11):
    """HHD from linear radiance SH (2024 Eq 8, 56 in the cancellation-free form, 10, 11).

    Inputs (...,) float. returns C_a, C_d, d (..., 3) (no clamping; C_d may be 0 -> d NaN is
    avoided: d = z where C_d <= 0).
    """
    k = 2.0 / np.sqrt(3.0 * np.pi)
    bc = (2.0 / SQRT_PI) * l0
    bx = -k * l11
    by = -k * l1m1
    bz = k * l10
    disc = (bc - 2.0 * bz) ** 2 + 3.0 * (bx * bx + by * by)
    ca = ((2.0 * bc - bz) - np.sqrt(disc)) / 3.0
    cd = bc - 2.0 * ca
    v = np.stack([bx, by, bz - ca], axis=-1)
    nv = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = nv > 0
    d = np.where(ok, v / np.where(ok, nv, 1.0), np.array([0.0, 0.0, 1.0]))
    return ca, cd, d


def hlsh_direct(t, iz):
    """HLSH IrradZ-constrained least squares (2024 Eq 22): b = 3/(2 pi) (G_BY i - I_z B_z).

    t : (..., 9) target irradiance SH; iz : (...,). returns (..., 3) = (C_a, c_x, c_y).
    """
    return (t @ G_BY.T - iz[..., None] * B_Z) / G_B_SCALE


# ---------------------------------------------------------------------------------------------
# Fit.


# Evaluate, layout, encode, decode.


def expand(p, ndim):
    """Append axes before the last one so the parameter's leading shape is a *prefix* of the
    normals' leading shape (one texel, many normals), then numpy-broadcast."""
    while p.ndim < ndim:
        p = p[..., None, :]
    return p


def evaluate(kind: str, params: dict, normals, *, albedo=None) -> np.ndarray:
    """Normalized irradiance (..., 3) float32 at tangent-space unit normals.

    params : IrradZ params with leading shape P; normals : (..., 3) with leading shape P or
    P + extra axes (several normals per texel), or anything numpy-broadcastable.
    albedo : (..., 3) adds the 2024 App. A self-bounce via usdahd.numerics.hemi.self_bounce.
    """
    n = np.asarray(normals, dtype=np.float64)
    ca, cd, d = colors(params)
    nd = max(n.ndim, ca.ndim)
    ca, cd, d = (expand(x, nd) for x in (ca, cd, d))
    # n . d summed term by term in the order np.sum uses for 3 terms (bit-identical), without
    # the (..., 3) product array: 35-40 % faster for validate's 64 normals per texel.
    ndotd = n[..., 0:1] * d[..., 0:1] + n[..., 1:2] * d[..., 1:2] + n[..., 2:3] * d[..., 2:3]
    if kind == "hlsh":
        out = ca + ndotd * cd
    elif kind == "hhd":
        out = 0.5 * (n[..., 2:3] + 1.0) * ca + np.maximum(ndotd, 0.0) * cd
    else:
        out = ca + np.maximum(ndotd, 0.0) * cd
    if albedo is not None:
        out = out + self_bounce(expand(np.asarray(params["iz"]), nd), n, albedo)
    return out.astype(np.float32)
