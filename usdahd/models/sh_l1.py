"""Linear (L1) spherical harmonics, with the three Enlighten evaluation/storage variants.

Params: ``coefficients`` (..., 4, 3) float32: radiance SH ``[l0, l1-1, l10, l11]`` (our basis,
usdahd.sh) x RGB; ``invalid`` (..., 1); and, for ``ratio="nonlinear"`` only, ``nonlinear``
(..., 1) = 1.0, which tells :func:`evaluate` to use the non-linear reconstruction (evaluate
receives no ratio, so the variant travels with the parameters; decode restores it).

The ratio slot selects the variant (sh_l1 has no ambient ratio):

``linear``     ``I(n) = sum_k A_k l_k Y_k(n)`` (cosine factors A = [1, 2/3]); textures
               ``coefficients0..3``, one RGB float16 per basis function.
``nonlinear``  Geomerics' non-linear reconstruction from the Enlighten documentation, per
               channel, never negative (see :func:`nonlinear_irradiance`); same texture.
``8bit``       Enlighten's compressed L1: per colour channel 4 UNORM8 values ``sqrt(L0 /
               l0Scale)`` and ``L1 / L0`` mapped from [-1, 1] to [0, 254] (textures
               ``coefficients0..2``: one RGBA UNORM8 PNG per colour); linear evaluation.

Enlighten's L0 / L1 are the mean and first moment of the radiance: ``L0 = <L>``,
``L1 = <L w>`` over the sphere, so ``L = L0 + 3 L1 . w`` and, for non-negative radiance,
``|L1| <= L0`` (which is what the 8-bit ratio range and the non-linear model assume). In our SH:
``L0 = l0 / (2 sqrt(pi))``, ``L1 = (-l11, -l1-1, l10) / (2 sqrt(3 pi))`` in tangent axes
(x, y, z = normal). The non-linear formula is rotation invariant, so no axis swap is needed.

Solvers:

``hemisphere``  hemispherical least squares of the *linear* irradiance against the band-2
                target over Omega+ (exact, via the hemispherical Gram matrix): the best L1
                for linear evaluation of normals in the upper hemisphere.
``project``     plain truncation to the first four radiance coefficients (spherical projection,
                what an Enlighten probe stores); the input the non-linear model expects.
``auto``        ``hemisphere`` for ``linear``, ``project`` for ``nonlinear`` and ``8bit``.
                Projections of non-negative radiance satisfy ``|L1| <= L0``, the range the
                non-linear model and the 8-bit ratio codes assume; hemisphere least-squares
                L1 often exceeds it (the 8-bit encode then clamps each ratio to [-1, 1]).
"""

from __future__ import annotations

import numpy as np

from usdahd.models import linear
from usdahd.models.base import TextureLayout, check_choice
from usdahd.numerics import sh as shm

NAME = "sh_l1"
RATIOS = ("linear", "nonlinear", "8bit")
SOLVERS = ("auto", "hemisphere", "project")
DEFAULT_SOLVER = "auto"
BASIS = ("Y00", "Y1m1", "Y10", "Y11")

#: Hemispherical least-squares fit matrix (4, 9): L1 irradiance SH = FIT @ irradiance SH.
FIT = linear.hemisphere_fit_matrix(np.eye(9)[:4])
#: Enlighten's 8-bit L1 codes: ratio code = 127 + 127 * L1/L0 in [0, 254].
U8_CENTER = 127.0
#: log2 slack when picking the power-of-two l0Scale (float32 rounding is ~1e-7 relative).
L0_SCALE_SLACK = 1e-6
_L0_FROM_SH = 1.0 / (2.0 * np.sqrt(np.pi))
_L1_FROM_SH = shm.IZ_FROM_L10 / 4.0  # 1 / (2 sqrt(3 pi)), exactly


def fit(sh, *, ratio="linear", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) tangent-space radiance SH -> {coefficients (..., 4, 3), invalid, ...}."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    check_choice(NAME, "solver", solver, SOLVERS)
    if solver == "auto":
        solver = "hemisphere" if ratio == "linear" else "project"
    x, bad = linear.prepare(sh)
    if solver == "project":
        c = np.swapaxes(x[..., :4], -1, -2)
    else:
        irr = linear.apply_fit_matrix(FIT, linear.irradiance_sh(x))
        c = irr / shm.COSINE_FACTORS[:4, None]
    extra = {}
    if ratio == "nonlinear":
        extra["nonlinear"] = np.ones(bad.shape + (1,), np.float32)
    return linear.finish(c, bad, **extra)


def to_enlighten(coefficients: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Our L1 radiance SH (..., 4, 3) -> Enlighten (L0 (..., 3), L1 (..., 3, 3) xyz per colour).

    L0 = mean radiance, L1 = first moment, tangent axes (x, y, z); float64.
    """
    c = np.asarray(coefficients, dtype=np.float64)
    l0 = _L0_FROM_SH * c[..., 0, :]
    l1 = _L1_FROM_SH * np.stack([-c[..., 3, :], -c[..., 1, :], c[..., 2, :]], axis=-1)
    return l0, l1


def from_enlighten(l0: np.ndarray, l1: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_enlighten`: L0 (..., 3), L1 (..., 3, 3) -> (..., 4, 3) float64."""
    l0, l1 = np.asarray(l0, np.float64), np.asarray(l1, np.float64)
    s = 1.0 / _L1_FROM_SH
    return np.stack([l0 / _L0_FROM_SH, -s * l1[..., 1], s * l1[..., 2], -s * l1[..., 0]], axis=-2)


def nonlinear_irradiance(l0: np.ndarray, l1: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Geomerics non-linear L1 reconstruction (Enlighten ``NonlinearL1ComputeChannel``).

    Per channel: ``q = (1 + n . L1/|L1|)/2``, ``r = |L1|/L0``, ``p = 1 + 2r``,
    ``a = (1 - r)/(1 + r)``, ``I = L0 ((1 - a)(1 + p) q^p + a)``, clamped at 0; ``I = L0`` when
    ``L1 = 0``; 0 when ``L0 <= 0``. Its spherical mean is L0 for every r (energy conserving).

    l0 : (..., C); l1 : (..., C, 3); normals : (..., 3) unit. returns (..., C) float64.
    """
    l0 = np.asarray(l0, np.float64)
    l1 = np.asarray(l1, np.float64)
    n = np.asarray(normals, np.float64)[..., None, :]
    mod = np.linalg.norm(l1, axis=-1)
    safe_mod = np.where(mod > 0, mod, 1.0)
    q = 0.5 + 0.5 * np.einsum("...k,...k->...", n, l1) / safe_mod
    pos = l0 > 0
    r = np.where(pos, mod / np.where(pos, l0, 1.0), 0.0)
    p = 1.0 + 2.0 * r
    a = (1.0 - r) / (1.0 + r)
    val = l0 * ((1.0 - a) * (1.0 + p) * np.power(np.clip(q, 0.0, 1.0), p) + a)
    val = np.where(mod > 0, val, l0)
    return np.where(pos, np.maximum(val, 0.0), 0.0)


def _eval(params, n):
    c = linear.expand(params["coefficients"], n, 2)
    if "nonlinear" in params:
        l0, l1 = to_enlighten(c)
        return nonlinear_irradiance(l0, l1, n)
    y = shm.basis(n)[..., :4] * shm.COSINE_FACTORS[:4]
    return np.einsum("...k,...kc->...c", y, c)


def evaluate(params, normals, *, albedo=None):
    """Normalized irradiance (..., 3) float32 at tangent-space unit normals (..., 3)."""
    return linear.with_self_bounce(_eval, params, normals, albedo)


def layout(ratio="linear"):
    check_choice(NAME, "ratio", ratio, RATIOS)
    if ratio == "8bit":
        return [
            TextureLayout(
                linear.coefficient_role(i),
                "unorm8",
                "raw",
                tuple(f"{k}.{c}" for k in ("L0", "L1x", "L1y", "L1z")),
                ("l0_8bit", "l1_8bit", "l1_8bit", "l1_8bit"),
                ("l0Scale", None, None, None),
            )
            for i, c in enumerate(linear.CHANNELS)
        ]
    return linear.coefficients_layout(BASIS)


def representable(params, *, ratio="linear"):
    """The params the stored range can represent (before rounding to codes): for ``8bit``,
    L0 >= 0 and each ratio L1_i / L0 clipped to [-1, 1], as :func:`encode` does (SH of
    non-negative radiance satisfies it; noisy or denoised SH may not). Other variants: as is.
    The validator compares the decoded textures against this, so the clip is no mismatch."""
    if ratio != "8bit":
        return params
    l0, l1 = to_enlighten(params["coefficients"])
    l0 = np.maximum(l0, 0.0)
    r = np.where(l0[..., None] > 0, l1 / np.where(l0 > 0, l0, 1.0)[..., None], 0.0)
    c = from_enlighten(l0, np.clip(r, -1.0, 1.0) * l0[..., None])
    return {**params, "coefficients": c.astype(np.float32)}


def encode(params, *, ratio="linear"):
    """Quantize. linear/nonlinear: float16 ``coefficients0..3`` (..., 3) + coefficientsScale;
    8bit: uint8 ``coefficients0..2`` (..., 4), one RGBA texture per colour R, G, B holding
    (L0, L1x, L1y, L1z) codes, + l0Scale."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    if ratio != "8bit":
        return linear.encode_coefficients(params)
    l0, l1 = to_enlighten(params["coefficients"])
    l0 = np.maximum(l0, 0.0)
    m = float(l0.max()) if l0.size else 0.0
    # l0Scale: Enlighten's 1 / m_U8OutputScale; a power of two >= max L0 keeps L0/scale in [0,1]
    # (L0_SCALE_SLACK absorbs float32 noise on an exact power of two; the clip below is then
    # at most that relative amount).
    scale = float(2.0 ** np.ceil(np.log2(m) - L0_SCALE_SLACK)) if m > 0 else 1.0
    u0 = np.rint(255.0 * np.sqrt(np.clip(l0 / scale, 0.0, 1.0)))
    ratio_v = np.where(l0[..., None] > 0, l1 / np.where(l0 > 0, l0, 1.0)[..., None], 0.0)
    u1 = np.rint(U8_CENTER + 127.0 * np.clip(ratio_v, -1.0, 1.0))
    codes = np.concatenate([u0[..., None], u1], axis=-1).astype(np.uint8)  # (..., 3, 4)
    out = {linear.coefficient_role(i): codes[..., i, :] for i in range(3)}
    return out, {"l0Scale": scale}


def decode(channels, *, ratio="linear", factors=None):
    """Stored channels -> float32 params (Enlighten's C++ decode for ``8bit``)."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    factors = factors or {}
    if ratio != "8bit":
        c = linear.decode_coefficients(channels, factors, 4)
    else:
        u = linear.gather_coefficients(channels, 3, 4).astype(np.float64)  # (..., RGB, 4)
        l0 = factors.get("l0Scale", 1.0) * (u[..., 0] / 255.0) ** 2
        l1 = (u[..., 1:] - U8_CENTER) * (l0[..., None] / 127.0)
        c = np.clip(from_enlighten(l0, l1), -linear.F32_MAX, linear.F32_MAX).astype(np.float32)
    out = {"coefficients": c, "invalid": linear.valid_flag(c.shape[:-2])}
    if ratio == "nonlinear":
        out["nonlinear"] = np.ones(c.shape[:-2] + (1,), np.float32)
    return out
