"""Hemisphere-only model (Roughton et al. 2024 Sec 3.1.1): ``I(n) = C (1 + n_z) / 2``.

A scalar (RGB) lightmap interpreted as a hemisphere light around the vertex normal: the cheapest
model that still varies with the normal-mapped normal.

Solvers:

``iz``          ``C = I_z`` (IrradZ: exact irradiance in the normal, the value a normal map
                sees most). One multiply per texel.
``hemisphere``  hemispherical least squares, ``C = int h E / int h^2`` over Omega+ with
                ``h = (1 + z)/2`` (exact via the hemispherical Gram matrix).

Params: ``ambient`` (..., 3) float32 (>= 0), ``invalid`` (..., 1). Texture: role ``ambient``,
RGB float16, lin_rec709_scene, factor ``ambientScale``.
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import InputError
from usdahd.models import linear
from usdahd.models.base import check_choice, rgb_layout
from usdahd.numerics import encoding
from usdahd.numerics import sh as shm

NAME = "hemisphere"
RATIOS = ("none",)
SOLVERS = ("iz", "hemisphere")
DEFAULT_SOLVER = "iz"

#: The basis function h = (1 + z)/2 as SH: sqrt(pi) Y00 + sqrt(pi/3) Y10.
H_SH = np.array([np.sqrt(np.pi), 0, np.sqrt(np.pi / 3), 0, 0, 0, 0, 0, 0])
#: Least-squares fit row over Omega+ (1, 9): C = FIT @ irradiance_sh; int h^2 = 7 pi / 6.
FIT = linear.hemisphere_fit_matrix(H_SH[None])


def fit(sh, *, ratio="none", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) tangent-space radiance SH -> {ambient (..., 3), invalid (..., 1)}."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    check_choice(NAME, "solver", solver, SOLVERS)
    x, bad = linear.prepare(sh)
    if solver == "iz":
        c = shm.iz(x)
    else:
        c = linear.apply_fit_matrix(FIT, linear.irradiance_sh(x))[..., 0, :]
    c = np.clip(np.where(bad[..., None], 0.0, np.maximum(c, 0.0)), 0.0, linear.F32_MAX)
    return {"ambient": c.astype(np.float32), "invalid": bad[..., None].astype(np.float32)}


def _eval(params, n):
    c = linear.expand(params["ambient"], n, 1)
    return c * (0.5 * (1.0 + n[..., 2:3]))


def evaluate(params, normals, *, albedo=None):
    """Normalized irradiance (..., 3) float32 at tangent-space unit normals (..., 3)."""
    return linear.with_self_bounce(_eval, params, normals, albedo)


def layout(ratio="none"):
    check_choice(NAME, "ratio", ratio, RATIOS)
    return [rgb_layout("ambient", "C", "half", "lin_rec709_scene", "ambientScale")]


def encode(params, *, ratio="none"):
    """-> ({"ambient": float16 (..., 3)}, {"ambientScale": s})."""
    check_choice(NAME, "ratio", ratio, RATIOS)
    h, s = encoding.encode_half(np.asarray(params["ambient"], dtype=np.float64))
    return {"ambient": h}, {"ambientScale": s}


def decode(channels, *, ratio="none", factors=None):
    check_choice(NAME, "ratio", ratio, RATIOS)
    if "ambient" not in channels:
        raise InputError("hemisphere model needs the 'ambient' texture")
    c = encoding.decode_half(channels["ambient"], (factors or {}).get("ambientScale", 1.0))
    return {"ambient": c, "invalid": linear.valid_flag(c.shape[:-1])}
