"""Texture-channel quantizers shared by the lighting models (numpy only).

- Hemi-octahedral direction encoding (Meyer et al. 2010) of upper-hemisphere unit vectors to two
  SNORM8 values. SNORM (codes -127..127, decoded ``c / 127``) represents 0 exactly, so the
  direction ``d = z`` (code (0, 0)) is exact; UNORM cannot do this.
- UNORM8 / SNORM8 scalar quantizers with the D3D/Vulkan/GL decode rules, and signed values
  biased into UNORM8 (``code = snorm + 128``, decoded ``(q - 128) / 127``): PNG, engines and
  usdz packages hold unsigned 8-bit data only (format version 2 stores no int8 texture).
- float16 storage of HDR colours with an overflow pre-scale: values above the float16 range
  (65504) are divided by a power-of-two scale which the caller records (``izScale``).

Hemi-octahedral layout: a unit vector ``d`` with ``d_z >= 0`` is projected onto the octahedron
``|x| + |y| + z = 1`` giving ``(p_x, p_y)``; the diamond is rotated by 45 degrees to fill the
square, ``u = p_x + p_y``, ``v = p_x - p_y``, both in [-1, 1]. Decoding inverts this:
``p_x = (u + v) / 2``, ``p_y = (u - v) / 2``, ``z = 1 - |p_x| - |p_y| = 1 - max(|u|, |v|)``, then
normalises. A code with ``max(|u|, |v|) = 1`` would decode to ``d_z = 0`` and make
``C_d = I_z (1 - w_a) / d_z`` infinite, so codes are clamped to [-126, 126]: then
``d_z >= 1/126.004 > 1/127`` for every code (tested exhaustively).
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import InputError

__all__ = [
    "DZ_MIN",
    "decode_direction_u8",
    "decode_half",
    "dequantize_snorm8_biased",
    "dequantize_unorm8",
    "encode_direction_u8",
    "encode_half",
    "quantize_snorm8_biased",
    "quantize_unorm8",
]

#: Largest finite float16.
HALF_MAX = 65504.0
#: Largest SNORM8 magnitude used for direction codes: keeps decoded d_z >= 1/127 (see above).
OCT_CODE_MAX = 126
#: The smallest d_z a clamped 8-bit hemi-octahedral code decodes to is just above this.
DZ_MIN = 1.0 / 127.0


def _check_finite(x: np.ndarray, what: str) -> np.ndarray:
    x = np.asarray(x)
    if not np.all(np.isfinite(x)):
        raise InputError(f"{what}: cannot quantize NaN or Inf values (fit flags them as invalid)")
    return x


def quantize_unorm8(x: np.ndarray) -> np.ndarray:
    """[0, 1] floats -> uint8 codes (clamped, round to nearest). x : (...) float."""
    x = _check_finite(x, "UNORM8")
    return np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


def dequantize_unorm8(c: np.ndarray) -> np.ndarray:
    """uint8 codes -> float32 in [0, 1] (code / 255)."""
    return np.asarray(c).astype(np.float32) / np.float32(255.0)


def quantize_snorm8(x: np.ndarray) -> np.ndarray:
    """[-1, 1] floats -> int8 codes in [-127, 127] (clamped, round to nearest)."""
    x = _check_finite(x, "SNORM8")
    return np.rint(np.clip(x, -1.0, 1.0) * 127.0).astype(np.int8)


def dequantize_snorm8(c: np.ndarray) -> np.ndarray:
    """int8 codes -> float32 in [-1, 1]: max(code / 127, -1) (so -128 decodes to -1)."""
    return np.maximum(np.asarray(c).astype(np.float32) / np.float32(127.0), np.float32(-1.0))


#: Bias of signed values stored in UNORM8 (format version 2): code = snorm code + 128, so
#: 128 is 0 exactly and the SNORM8 codes -127..127 become 1..255.
SNORM_BIAS = 128


def bias_snorm8(codes: np.ndarray) -> np.ndarray:
    """int8 SNORM codes (-127..127; -128 is treated as -127) -> biased uint8 codes (1..255)."""
    c = np.maximum(np.asarray(codes).astype(np.int16), -127)
    return (c + SNORM_BIAS).astype(np.uint8)


def quantize_snorm8_biased(x: np.ndarray) -> np.ndarray:
    """[-1, 1] floats -> biased uint8 codes ``round(127 x) + 128`` in 1..255 (clamped)."""
    return bias_snorm8(quantize_snorm8(x))


def dequantize_snorm8_biased(c: np.ndarray) -> np.ndarray:
    """Biased uint8 codes -> float32 ``max((q - 128) / 127, -1)`` (q = 0 decodes as -1)."""
    q = np.asarray(c).astype(np.float32) - np.float32(SNORM_BIAS)
    return np.maximum(q / np.float32(127.0), np.float32(-1.0))


def hemioct_encode(d: np.ndarray) -> np.ndarray:
    """Upper-hemisphere unit vectors -> hemi-octahedral (u, v) in [-1, 1] (unquantized).

    d : (..., 3) float, d_z >= 0 (negative d_z is treated as 0). returns (..., 2) float64.
    """
    d = np.asarray(d, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], np.maximum(d[..., 2], 0.0)
    s = np.abs(x) + np.abs(y) + z
    s = np.where(s > 0, s, 1.0)
    px, py = x / s, y / s
    return np.stack([px + py, px - py], axis=-1)


def hemioct_decode(uv: np.ndarray) -> np.ndarray:
    """Hemi-octahedral (u, v) in [-1, 1] -> unit vectors (..., 3) float32 (what a shader does)."""
    uv = np.asarray(uv, dtype=np.float32)
    u, v = uv[..., 0], uv[..., 1]
    px, py = 0.5 * (u + v), 0.5 * (u - v)
    z = 1.0 - np.abs(px) - np.abs(py)
    d = np.stack([px, py, z], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def encode_direction(d: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3), d_z >= 0 -> (..., 2) int8 hemi-octahedral SNORM8 codes.

    Codes are clamped to [-126, 126] so that the decoded d_z >= 1/127.
    """
    d = _check_finite(d, "direction")
    c = np.rint(hemioct_encode(d) * 127.0)
    return np.clip(c, -OCT_CODE_MAX, OCT_CODE_MAX).astype(np.int8)


def decode_direction(codes: np.ndarray) -> np.ndarray:
    """(..., 2) int8 SNORM8 hemi-octahedral codes -> (..., 3) float32 unit vectors."""
    return hemioct_decode(dequantize_snorm8(codes))


def encode_direction_u8(d: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3), d_z >= 0 -> (..., 2) biased uint8 codes (2..254), see
    :func:`encode_direction` (same quantization, stored as ``snorm code + 128``)."""
    return bias_snorm8(encode_direction(d))


def decode_direction_u8(codes: np.ndarray) -> np.ndarray:
    """(..., 2) biased uint8 hemi-octahedral codes -> (..., 3) float32 unit vectors."""
    return hemioct_decode(dequantize_snorm8_biased(codes))


def half_scale(x: np.ndarray, headroom: float = 0.5) -> float:
    """Power-of-two scale s so that max|x| / s fits float16 with ``headroom`` (s >= 1).

    s = 1 unless max|x| > headroom * 65504. Power of two: dividing by s is exact in binary.
    """
    x = _check_finite(x, "float16 texture")
    m = float(np.max(np.abs(x))) if x.size else 0.0
    limit = headroom * HALF_MAX
    if m <= limit:
        return 1.0
    return float(2.0 ** np.ceil(np.log2(m / limit)))


def encode_half(x: np.ndarray) -> tuple[np.ndarray, float]:
    """float array -> (float16 array, scale) with x ~= float16 * scale, never overflowing."""
    s = half_scale(x)
    return (np.asarray(x, dtype=np.float64) / s).astype(np.float16), s


_F32_MAX = float(np.finfo(np.float32).max)


def decode_half(h: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """float16 array and its recorded scale -> float32, saturating at the float32 range.

    The product is formed in float64: a float16 near 65504 times a scale near 2^113 would
    overflow float32 (the soak in benchmarks/soak.py found Inf for inputs above ~1e39).
    """
    out = np.asarray(h, dtype=np.float64) * float(scale)
    return np.clip(out, -_F32_MAX, _F32_MAX).astype(np.float32)
