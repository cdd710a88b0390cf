"""HDR lightmap textures as 8-bit RGBA PNG a browser loads: RGBM and RGBE (docs/gltf.md).

Both store ``v - offset`` (offset <= 0 per channel, the texture's most negative value, so the
signed SH / basis coefficients fit) and are decoded **per texel, before filtering** (the
reference importer fetches the four texels and filters the decoded values, which is what the
float16 texture gives under bilinear filtering):

- ``rgbm``: ``v = offset + multiplier * (A/255) * (RGB/255)``; ``multiplier`` = the largest
  ``v - offset`` of the texture, the alpha code the smallest that holds the texel's largest
  channel (``ceil(255 m / multiplier)``);
- ``rgbe``: ``v = offset + (RGB + 0.5)/256 * 2^(A - 128)`` (Radiance's shared exponent;
  ``A = 0`` and ``RGB = 0`` is zero).

:func:`encode` returns the bytes' pixels and the parameters; :func:`decode` is the numpy
reference of what the shader does. The error each adds against the float16 bake is measured in
docs/gltf.md (``python -m usdahd.export STAGE.lightmaps.usda ...``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ENCODINGS", "decode", "encode"]

ENCODINGS = ("rgbm", "rgbe")


def encode(values: np.ndarray, encoding: str) -> tuple[np.ndarray, dict]:
    """values (h, w, 3) float -> (pixels (h, w, 4) uint8, params {multiplier?, offset})."""
    v = np.asarray(values, np.float64)[..., :3]
    if not np.isfinite(v).all():
        raise ValueError("HDR texture values must be finite")
    offset = np.minimum(v.reshape(-1, 3).min(axis=0), 0.0)
    w = np.maximum(v - offset, 0.0)
    m = w.max(axis=-1)
    px = np.zeros(v.shape[:2] + (4,), np.uint8)
    if encoding == "rgbm":
        mult = float(m.max()) if m.size else 0.0
        if mult <= 0.0:
            mult = 1.0
        a = np.clip(np.ceil(255.0 * m / mult), 0, 255)
        scale = mult * a / 255.0
        rgb = np.where(scale[..., None] > 0, w / np.maximum(scale, 1e-300)[..., None], 0.0)
        px[..., :3] = np.clip(np.rint(255.0 * rgb), 0, 255).astype(np.uint8)
        px[..., 3] = a.astype(np.uint8)
        params = {"multiplier": mult, "offset": [float(x) for x in offset]}
    elif encoding == "rgbe":
        with np.errstate(divide="ignore"):
            e = np.where(m > 1e-38, np.floor(np.log2(np.maximum(m, 1e-38))) + 1.0, -128.0)
        e = np.clip(e, -128.0, 127.0)
        mant = np.floor(w / np.exp2(e)[..., None] * 256.0)
        px[..., :3] = np.clip(mant, 0, 255).astype(np.uint8)
        px[..., 3] = np.where(m > 1e-38, e + 128.0, 0).astype(np.uint8)
        params = {"offset": [float(x) for x in offset]}
    else:
        raise ValueError(f"unknown HDR encoding {encoding!r}; use one of {ENCODINGS}")
    return px, params


def decode(pixels: np.ndarray, encoding: str, params: dict) -> np.ndarray:
    """(h, w, 4) uint8 -> (h, w, 3) float64: what the reference importer's shader computes."""
    p = np.asarray(pixels, np.float64)
    off = np.asarray(params["offset"], np.float64)
    if encoding == "rgbm":
        return off + params["multiplier"] * (p[..., 3:4] / 255.0) * (p[..., :3] / 255.0)
    if encoding == "rgbe":
        zero = (p[..., 3:4] == 0) & (p[..., :3] == 0)
        v = (p[..., :3] + 0.5) / 256.0 * np.exp2(p[..., 3:4] - 128.0)
        return off + np.where(zero, 0.0, v)
    raise ValueError(f"unknown HDR encoding {encoding!r}; use one of {ENCODINGS}")
