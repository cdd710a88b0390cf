"""A minimal PNG writer (8-bit RGB/RGBA), deterministic bytes, optional gAMA chunk.

The glTF exporter embeds images in memory; OpenImageIO writes files, this writes bytes.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

__all__ = ["encode"]

#: PNG colour type by channel count.
_COLOR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}


def _chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def encode(pixels: np.ndarray, *, linear: bool) -> bytes:
    """PNG bytes of ``pixels`` (h, w, c) uint8, c in 1..4, row 0 at the top. ``linear``: a gAMA
    chunk of 1.0 (the values are data or linear, as usdahd's bake writes them); else an sRGB
    chunk (colour in sRGB, e.g. a glTF baseColorTexture)."""
    px = np.asarray(pixels)
    if px.ndim == 2:
        px = px[..., None]
    if px.dtype != np.uint8 or px.ndim != 3 or px.shape[2] not in _COLOR_TYPE:
        raise ValueError(f"PNG pixels must be (h, w, 1..4) uint8, got {px.shape} {px.dtype}")
    h, w, c = px.shape
    raw = np.zeros((h, 1 + w * c), np.uint8)  # filter type 0 (none) per row
    raw[:, 1:] = px.reshape(h, w * c)
    head = struct.pack(">IIBBBBB", w, h, 8, _COLOR_TYPE[c], 0, 0, 0)
    out = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", head)
    if linear:
        out += _chunk(b"gAMA", struct.pack(">I", 100000))
    else:
        out += _chunk(b"sRGB", b"\x00")
    out += _chunk(b"IDAT", zlib.compress(raw.tobytes(), 9))
    return out + _chunk(b"IEND", b"")
