"""Classic AHD: (C_a, d, C_d) stored directly, I(n) = C_a + max(0, n.d) C_d.

The naive baseline whose interpolation artifact the 2018 IrradZ paper fixes: texture filtering
interpolates C_a, d and C_d independently, so between texels with different directions the
irradiance in z overshoots (2018 Fig. 2). At texel centres it is the same function as the
IrradZ AHD fit with ``ratio="rgb"`` (C_a = I_z w_a, C_d = I_z (1 - w_a) / d_z per channel),
which is how it is fitted here: same solvers as ``usdahd.models.irradz.AHD``. It has no ambient
ratio, so ``RATIOS = ("none",)``; it stores two HDR colours instead of one.

Params: ``ambient`` (..., 3), ``direction`` (..., 3) unit with d_z >= 1/127, ``directional``
(..., 3), ``invalid`` (..., 1) (1.0 where the input held NaN/Inf; output black).
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import InputError
from usdahd.models import irradz as _irradz
from usdahd.models.base import RESERVED_CODE, TextureLayout, rgb_layout
from usdahd.numerics import encoding
from usdahd.numerics.hemi import self_bounce

NAME = "ahd_classic"
RATIOS = ("none",)
SOLVERS = _irradz.SOLVERS["ahd"]
DEFAULT_SOLVER = "golden"


def fit(sh, *, ratio="none", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) radiance SH -> float32 ambient, direction, directional (..., 3),
    invalid (..., 1)."""
    p = _irradz.fit(sh, "ahd", ratio="rgb", solver=solver, **options)
    ca, cd, d = _irradz.colors(p)
    return {
        "ambient": ca.astype(np.float32),
        "direction": p["direction"],
        "directional": cd.astype(np.float32),
        "invalid": p["invalid"],
    }


def evaluate(params, normals, *, albedo=None):
    """Normalized irradiance (..., 3); albedo adds App. A self-bounce (I_z = C_a + d_z C_d)."""
    n = np.asarray(normals, dtype=np.float64)
    ca = np.asarray(params["ambient"], dtype=np.float64)
    cd = np.asarray(params["directional"], dtype=np.float64)
    d = np.asarray(params["direction"], dtype=np.float64)
    nd = max(n.ndim, ca.ndim)
    ca, cd, d = (_irradz.expand(x, nd) for x in (ca, cd, d))
    out = ca + np.maximum(np.sum(n * d, axis=-1, keepdims=True), 0.0) * cd
    if albedo is not None:
        iz = ca + d[..., 2:3] * cd
        out = out + self_bounce(iz, n, albedo)
    return out.astype(np.float32)


def layout(ratio="none"):
    return [
        rgb_layout("ambient", "C_a", "half", "lin_rec709_scene", "ambientScale"),
        TextureLayout(
            "direction", "unorm8", "raw", ("u", "v", "_"), ("snorm8b", "snorm8b", "reserved")
        ),
        rgb_layout("directional", "C_d", "half", "lin_rec709_scene", "directionalScale"),
    ]


def encode(params, *, ratio="none"):
    """-> ({"ambient": float16 (..., 3), "direction": uint8 (..., 3), "directional": float16
    (..., 3)}, {"ambientScale": s, "directionalScale": s})."""
    amb, sa = encoding.encode_half(params["ambient"])
    dirl, sd = encoding.encode_half(params["directional"])
    uv = encoding.encode_direction_u8(params["direction"])
    reserved = np.full(uv.shape[:-1] + (1,), RESERVED_CODE, np.uint8)
    ch = {"ambient": amb, "direction": np.concatenate([uv, reserved], -1), "directional": dirl}
    return ch, {"ambientScale": sa, "directionalScale": sd}


def decode(channels, *, ratio="none", factors=None):
    factors = factors or {}
    for role in ("ambient", "direction", "directional"):
        if role not in channels:
            raise InputError(f"ahd_classic decode needs a {role!r} channel set")
    return {
        "ambient": encoding.decode_half(channels["ambient"], factors.get("ambientScale", 1.0)),
        "direction": encoding.decode_direction_u8(np.asarray(channels["direction"])[..., :2]),
        "directional": encoding.decode_half(
            channels["directional"], factors.get("directionalScale", 1.0)
        ),
    }
