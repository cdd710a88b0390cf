"""IrradZ texture layout, encode and decode (format version 2).

encode : float32 params -> float16 ``iz`` + uint8 ``direction`` (+ ``ratio``) textures;
decode : the stored channels -> float32 params, as an engine does. Layout table: docs/models.md.
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import InputError
from usdahd.models.base import RESERVED_CODE, TextureLayout, rgb_layout
from usdahd.numerics import encoding

__all__ = ["HLSH_RATIO_SCALE_MAX", "decode", "encode", "layout"]


def layout(kind: str, ratio: str) -> list[TextureLayout]:
    """Textures of an IrradZ model (format version 2).

    ``iz``: RGB float16 EXR (× izScale). ``direction``: RGB UNORM8 PNG, R, G = hemi-octahedral
    (u, v) biased (snorm8b), B = the luminance ambient ratio w_a (ratio "luminance"; UNORM8 for
    ahd/hhd, snorm8b × ratioScale for hlsh) or reserved (ratio "rgb", whose three w_a are the
    ``ratio`` texture).
    """
    rcode = "snorm8b" if kind == "hlsh" else "unorm8"
    rscale = "ratioScale" if kind == "hlsh" else None
    iz = rgb_layout("iz", "I_z", "half", "lin_rec709_scene", "izScale")
    if ratio == "luminance":
        direction = TextureLayout(
            "direction",
            "unorm8",
            "raw",
            ("u", "v", "w_a"),
            ("snorm8b", "snorm8b", rcode),
            (None, None, rscale),
        )
        return [iz, direction]
    direction = TextureLayout(
        "direction", "unorm8", "raw", ("u", "v", "_"), ("snorm8b", "snorm8b", "reserved")
    )
    ratio_tex = TextureLayout(
        "ratio", "unorm8", "raw", ("w_a.R", "w_a.G", "w_a.B"), (rcode,) * 3, (rscale,) * 3
    )
    return [iz, direction, ratio_tex]


#: HLSH w_a is stored as SNORM8 of w_a / ratioScale, ratioScale a power of two >= max |w_a|,
#: at most this (beyond it w_a is clamped; a linear model with |w_a| > 16 is a texel with almost
#: no light in z, where the ratio barely matters for I(z) which stays exact).
HLSH_RATIO_SCALE_MAX = 16.0


def encode(kind: str, params: dict, *, ratio: str):
    """Quantize params -> ({"iz": float16 (..., 3), "direction": uint8 (..., 3)[, "ratio":
    uint8 (..., 3)]}, factors), the textures of :func:`layout`. factors: izScale (always),
    ratioScale (hlsh)."""
    iz = np.asarray(params["iz"], dtype=np.float64)
    wa = np.asarray(params["ambient_ratio"], dtype=np.float64)
    want = 1 if ratio == "luminance" else 3
    if wa.shape[-1] != want:
        raise InputError(
            f"ambient_ratio has {wa.shape[-1]} channel(s); ratio={ratio!r} needs {want}"
        )
    half, s = encoding.encode_half(iz)
    factors = {"izScale": s}
    if kind == "hlsh":
        m = float(np.max(np.abs(wa))) if wa.size else 1.0
        r = float(min(2.0 ** np.ceil(np.log2(max(m, 1.0))), HLSH_RATIO_SCALE_MAX))
        q = encoding.quantize_snorm8_biased(wa / r)
        factors["ratioScale"] = r
    else:
        q = encoding.quantize_unorm8(wa)
    uv = encoding.encode_direction_u8(params["direction"])
    out = {"iz": half}
    if ratio == "luminance":
        out["direction"] = np.concatenate([uv, q], axis=-1)
    else:
        reserved = np.full(uv.shape[:-1] + (1,), RESERVED_CODE, np.uint8)
        out["direction"] = np.concatenate([uv, reserved], axis=-1)
        out["ratio"] = q
    return out, factors


def decode(kind: str, channels: dict, *, ratio: str, factors: dict) -> dict:
    """Stored channels (the textures of :func:`layout`) -> float32 params, as an engine does."""
    need = ("iz", "direction") + (() if ratio == "luminance" else ("ratio",))
    for role in need:
        if role not in channels:
            raise InputError(f"IrradZ {kind} decode needs a {role!r} channel set")
    dq = np.asarray(channels["direction"])
    if dq.shape[-1] != 3:
        raise InputError(f"the direction texture has 3 channels, got {dq.shape[-1]}")
    iz = encoding.decode_half(channels["iz"], factors.get("izScale", 1.0))
    d = encoding.decode_direction_u8(dq[..., :2])
    rq = dq[..., 2:3] if ratio == "luminance" else np.asarray(channels["ratio"])
    if kind == "hlsh":
        wa = encoding.dequantize_snorm8_biased(rq) * np.float32(factors.get("ratioScale", 1.0))
    else:
        wa = encoding.dequantize_unorm8(rq)
    return {"iz": iz, "direction": d, "ambient_ratio": wa}
