"""Shared pieces of the linear-basis models (hemisphere, sh_l1, sh_l2, ambient_cube, hl2).

Every model here is linear in its colours: ``I(n) = sum_k w_k(n) C_k`` with fixed basis
functions ``w_k``. Fitting from tangent-space radiance SH is then a fixed linear map: the
hemispherical least-squares optimum ``C = Gb^-1 P i`` with ``Gb = int_{Omega+} w w^T`` and
``P = int_{Omega+} w Y^T``, applied to the irradiance SH ``i = conv(sh)``. It is exact (no
point sampling): Gb and P are computed once, in closed form or by exact quadrature.

Conventions shared by these models (see docs/models-linear.md):

- params ``coefficients`` : (..., N, 3) float32, basis k x RGB (stored as N RGB float16
  textures ``coefficients<k>``, one per basis function, channels R, G, B);
- params ``invalid`` : (..., 1) float32, 1.0 where the input texel held NaN/Inf (its colours are
  then 0: black output, never propagated);
- ``evaluate`` returns float32 (..., 3); with ``albedo`` it adds the self-bounce of 2024 App. A
  (:func:`usdahd.numerics.hemi.self_bounce`) with I_z = the model's own irradiance in z.
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import InputError, ModelError
from usdahd.models.base import MAX_COEFFICIENT_TEXTURES, TextureLayout, rgb_layout
from usdahd.numerics import encoding, hemi
from usdahd.numerics import sh as shm

__all__ = [
    "CHANNELS",
    "F32_MAX",
    "apply_fit_matrix",
    "coefficient_model",
    "coefficient_role",
    "coefficients_layout",
    "decode_coefficients",
    "encode_coefficients",
    "expand",
    "finish",
    "gather_coefficients",
    "hemisphere_fit_matrix",
    "irradiance_sh",
    "prepare",
    "valid_flag",
    "with_self_bounce",
]

#: Largest float32: fitted values are clipped to it (inputs near 1e200 would overflow).
F32_MAX = float(np.finfo(np.float32).max)
CHANNELS = ("R", "G", "B")


def prepare(sh) -> tuple[np.ndarray, np.ndarray]:
    """Validate radiance SH; zero non-finite texels.

    sh : (..., 3, 9) float. returns (x (..., 3, 9) float64, invalid (...,) bool).
    """
    x = np.asarray(sh)
    if x.ndim < 2 or x.shape[-2:] != (3, 9):
        raise InputError(f"SH must have shape (..., 3, 9) (RGB x 9 coefficients), got {x.shape}")
    if not (np.issubdtype(x.dtype, np.floating) or np.issubdtype(x.dtype, np.integer)):
        raise InputError(f"SH must be a float array, got dtype {x.dtype}")
    x = x.astype(np.float64)
    bad = ~np.all(np.isfinite(x), axis=(-2, -1))
    if bad.any():
        x = np.where(bad[..., None, None], 0.0, x)
    return x, bad


def finish(coeffs: np.ndarray, bad: np.ndarray, **extra) -> dict:
    """float64 coefficients (..., N, 3) -> float32 params dict with ``invalid`` (..., 1)."""
    c = np.clip(np.where(bad[..., None, None], 0.0, coeffs), -F32_MAX, F32_MAX)
    out = {"coefficients": c.astype(np.float32), "invalid": bad[..., None].astype(np.float32)}
    out.update(extra)
    return out


def irradiance_sh(x: np.ndarray) -> np.ndarray:
    """Radiance SH (..., 3, 9) -> normalized irradiance SH (..., 3, 9)."""
    return x * shm.COSINE_FACTORS


def apply_fit_matrix(f: np.ndarray, irr: np.ndarray) -> np.ndarray:
    """(N, 9) fit matrix and irradiance SH (..., 3, 9) -> coefficients (..., N, 3)."""
    return np.swapaxes(irr @ f.T, -1, -2)  # matmul: ~3x faster than the equivalent einsum


def normals_array(normals) -> np.ndarray:
    """Validate normals (..., 3) -> float64."""
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim < 1 or n.shape[-1] != 3:
        raise InputError(f"normals must have shape (..., 3), got {n.shape}")
    return n


def expand(p, n: np.ndarray, core_ndim: int) -> np.ndarray:
    """Broadcast a parameter against normals with the texel shape as a *prefix*.

    p : (P..., *core) with ``core_ndim`` trailing per-texel axes; n : (P..., E..., 3) (several
    normals per texel) or plain numpy-broadcastable. Axes are inserted after P so that
    ``p`` becomes (P..., 1..., *core) (the convention of the IrradZ models and ``usdahd fit``).
    """
    p = np.asarray(p, dtype=np.float64)
    while p.ndim - core_ndim < n.ndim - 1:
        p = np.expand_dims(p, p.ndim - core_ndim)
    return p


def with_self_bounce(eval_fn, params: dict, normals, albedo) -> np.ndarray:
    """``eval_fn(params, n)`` (float64) plus, with an albedo, 2024 App. A self-bounce.

    Params have leading (texel) shape P; normals (..., 3) have leading shape P or P + extra
    axes (several normals per texel, see :func:`expand`).

    I_z for the self-bounce is the model's own irradiance in z (exact I_z for models fitted with
    the IrradZ constraint, the reconstructed value otherwise). returns float32 (..., 3).
    """
    n = normals_array(normals)
    out = eval_fn(params, n)
    if albedo is not None:
        z = np.zeros(out.shape[:-1] + (3,))
        z[..., 2] = 1.0
        out = out + hemi.self_bounce(eval_fn(params, z), n, albedo)
    # Saturate rather than overflow: coefficients near the float32 maximum sum past it.
    return np.clip(out, -F32_MAX, F32_MAX).astype(np.float32)


def coefficient_role(k: int) -> str:
    """Texture role of basis function k: ``coefficients<k>``."""
    return f"coefficients{k}"


def coefficients_layout(names: tuple[str, ...]) -> list[TextureLayout]:
    """One RGB float16 texture per basis function k: ``coefficients<k>`` holds
    ``<name k>.R, .G, .B`` (raw, × coefficientsScale)."""
    if len(names) > MAX_COEFFICIENT_TEXTURES:
        raise ModelError(f"{len(names)} basis functions; the schema has {MAX_COEFFICIENT_TEXTURES}")
    return [
        rgb_layout(coefficient_role(k), b, "half", "raw", "coefficientsScale")
        for k, b in enumerate(names)
    ]


def encode_coefficients(params: dict) -> tuple[dict, dict]:
    """(..., N, 3) coefficients -> {coefficients<k>: float16 (..., 3)} and coefficientsScale
    (one power-of-two scale for all N textures)."""
    c = np.asarray(params["coefficients"], dtype=np.float64)
    h, s = encoding.encode_half(c)
    return {coefficient_role(k): h[..., k, :] for k in range(c.shape[-2])}, {"coefficientsScale": s}


def gather_coefficients(channels: dict, n_basis: int, n_channels: int = 3) -> np.ndarray:
    """The ``coefficients<k>`` textures (..., n_channels) each -> (..., n_basis, n_channels)."""
    missing = [coefficient_role(k) for k in range(n_basis) if coefficient_role(k) not in channels]
    if missing:
        raise InputError(
            f"missing texture role(s) {', '.join(missing)} (have {', '.join(channels) or 'none'})"
        )
    out = []
    for k in range(n_basis):
        h = np.asarray(channels[coefficient_role(k)])
        if h.shape[-1] != n_channels:
            raise InputError(
                f"{coefficient_role(k)} texture must have {n_channels} channels, got {h.shape[-1]}"
            )
        out.append(h)
    return np.stack(out, axis=-2)


def decode_coefficients(channels: dict, factors: dict | None, n_basis: int) -> np.ndarray:
    """float16 ``coefficients<k>`` textures -> float32 coefficients (..., N, 3)."""
    h = gather_coefficients(channels, n_basis)
    return encoding.decode_half(h, (factors or {}).get("coefficientsScale", 1.0))


def valid_flag(shape) -> np.ndarray:
    """Decoded params carry ``invalid`` = 0 (the texture has no flag channel)."""
    return np.zeros(tuple(shape) + (1,), np.float32)


def hemisphere_fit_matrix(basis_sh: np.ndarray) -> np.ndarray:
    """Least-squares fit matrix over Omega+ for a basis spanned by SH functions.

    basis_sh : (N, 9) each basis function as SH coefficients. returns (N, 9): C = F i.
    """
    g = hemi.HEMISPHERE_GRAM
    gb = basis_sh @ g @ basis_sh.T
    return np.linalg.solve(gb, basis_sh @ g)


def coefficient_model(name: str, basis: tuple[str, ...], ratios: tuple[str, ...], weights):
    """The evaluate / layout / encode / decode functions of a model that is a plain weighted sum
    of its ``len(basis)`` RGB coefficient textures (hemisphere-free: ambient_cube, hl2, sh_l2).

    weights : callable, tangent-space unit normals (..., 3) float64 -> basis weights (..., N)
    float64, so that ``I(n) = sum_k weights(n)_k C_k``. The functions returned are the module's
    public API (``models/<name>.py`` binds them to its names).
    """
    from usdahd.models.base import check_choice

    n_basis = len(basis)

    def _eval(params, n):
        c = expand(params["coefficients"], n, 2)
        return np.einsum("...k,...kc->...c", weights(n), c)

    def evaluate(params, normals, *, albedo=None):
        """Normalized irradiance (..., 3) float32 at tangent-space unit normals (..., 3)."""
        return with_self_bounce(_eval, params, normals, albedo)

    def layout(ratio="none"):
        check_choice(name, "ratio", ratio, ratios)
        return coefficients_layout(basis)

    def encode(params, *, ratio="none"):
        check_choice(name, "ratio", ratio, ratios)
        return encode_coefficients(params)

    encode.__doc__ = (
        f"-> ({{'coefficients0'..'coefficients{n_basis - 1}': float16 (..., 3)}}, "
        "{'coefficientsScale': s})."
    )

    def decode(channels, *, ratio="none", factors=None):
        """Textures -> {coefficients (..., N, 3) float32, invalid (..., 1) float32 (0)}."""
        check_choice(name, "ratio", ratio, ratios)
        c = decode_coefficients(channels, factors, n_basis)
        return {"coefficients": c, "invalid": valid_flag(c.shape[:-2])}

    return evaluate, layout, encode, decode
