"""Engine container: KTX 2.0 files with chart-aware mip chains (``usdahd bake --container ktx2``).

Per lightmap texture (docs/schema.md layout) one ``<name>.<role>.ktx2`` beside the EXR/PNG:

- 8-bit textures (directions, ratios, 8-bit sh_l1): **BC7** (``VK_FORMAT_BC7_UNORM_BLOCK``),
  encoded by etcpak (the maintained BC1-BC7 encoder on the package index), 1 byte per texel;
  RGB textures get A = 255. The codes keep their meaning (the biases of docs/schema.md apply
  to the decoded bytes).
- float16 textures: **RGBA16F** (``VK_FORMAT_R16G16B16A16_SFLOAT``), the same half values
  with A = 1, 8 bytes per texel: no maintained BC6H encoder is on the index, and BC6H has no
  sign bit for the signed SH coefficients of the linear models anyway (BC6H_SFLOAT aside).

Mips must not bleed across charts: level k+1 is built from level k by averaging, per coarse
texel, only the covered fine texels of the chart that covers most of them (ties: the lower
chart id), so two charts never mix and empty gutter texels never darken a chart; uncovered
coarse texels (gutters) are then dilated from their neighbours (:func:`usdahd.bake.post.dilate`)
so bilinear taps near borders read chart data. The full chain goes down to 1 x 1. Levels
average the stored values (float16, or 8-bit codes re-rounded): every code of docs/schema.md is
affine in its quantity except the 8-bit sh_l1 L0 (``(q/255)^2``), whose mips average the
square root like sRGB mips do.

The container follows the KTX 2.0 specification (Khronos): identifier, header, index, level
index (level 0 first, data stored smallest level first, each level aligned to
lcm(texel block size, 4)), a Basic Data Format Descriptor, key/value data (``KTXwriter``,
``KTXorientation = rd``: row 0 is the top, like the PNG/EXR) and no supercompression. numpy
and etcpak only; every write is atomic.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from usdahd._version import __version__
from usdahd.errors import ImageError
from usdahd.io_util import atomic_path

IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"
VK_FORMAT_R16G16B16A16_SFLOAT = 97
VK_FORMAT_BC7_UNORM_BLOCK = 145
#: Basic DFD colour models and channel ids (Khronos Data Format Specification 1.3).
KHR_DF_MODEL_RGBSDA = 1
KHR_DF_MODEL_BC7 = 134
KHR_DF_PRIMARIES_BT709 = 1
KHR_DF_TRANSFER_LINEAR = 1
KHR_DF_SAMPLE_DATATYPE_FLOAT = 0x80
KHR_DF_SAMPLE_DATATYPE_SIGNED = 0x40
#: bytes per texel (RGBA16F) / per 4 x 4 block (BC7)
BLOCK_BYTES = {VK_FORMAT_R16G16B16A16_SFLOAT: 8, VK_FORMAT_BC7_UNORM_BLOCK: 16}


def mip_chain(
    image: np.ndarray, mask: np.ndarray, charts: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Chart-aware mip levels of a lightmap down to 1 x 1.

    image : (h, w, c) float64 decoded values; mask : (h, w) bool covered texels; charts : (h, w)
    int chart id (any value where not covered). returns [(level image (h_k, w_k, c) float64,
    covered mask (h_k, w_k) bool)], level 0 first (level 0 is ``image`` dilated).
    """
    from usdahd.bake.post import dilate

    img = np.asarray(image, np.float64)
    m = np.asarray(mask, bool)
    ch = np.where(m, np.asarray(charts, np.int64), -1)
    levels = []
    while True:
        filled = dilate(img, m, None) if m.any() and not m.all() else img
        levels.append((filled, m))
        h, w = m.shape
        if h == 1 and w == 1:
            return levels
        img, m, ch = _downsample(img, m, ch)


def _footprint(n: int, n2: int) -> tuple[np.ndarray, np.ndarray]:
    """Fine indices (n2, 3) and validity (n2, 3) of each coarse texel along one axis: coarse i
    covers fine [i n / n2, (i + 1) n / n2) (2 texels, 3 where an odd size leaves one over)."""
    i = np.arange(n2)
    start, end = (i * n) // n2, ((i + 1) * n) // n2
    idx = start[:, None] + np.arange(3)[None, :]
    ok = idx < end[:, None]
    return np.minimum(idx, n - 1), ok


def _downsample(img, m, ch):
    """One chart-aware reduction to the next KTX2 level size max(1, floor(n / 2))."""
    h, w, c = img.shape
    h2, w2 = max(1, h // 2), max(1, w // 2)
    iy, oky = _footprint(h, h2)
    ix, okx = _footprint(w, w2)
    fy = np.broadcast_to(iy[:, None, :, None], (h2, w2, 3, 3)).reshape(h2, w2, 9)
    fx = np.broadcast_to(ix[None, :, None, :], (h2, w2, 3, 3)).reshape(h2, w2, 9)
    inside = (oky[:, None, :, None] & okx[None, :, None, :]).reshape(h2, w2, 9)
    sub_m = m[fy, fx] & inside
    sub_c = np.where(sub_m, ch[fy, fx], -1)
    sub_v = img[fy, fx]  # (h2, w2, 9, c)
    # the chart covering most of the footprint (ties: the lowest id); -1 when none is covered
    best = np.full((h2, w2), -1, np.int64)
    best_n = np.zeros((h2, w2), np.int64)
    for k in range(9):
        cand = sub_c[..., k]
        n = (sub_c == cand[..., None]).sum(axis=-1)
        better = (cand >= 0) & ((n > best_n) | ((n == best_n) & (cand < best)))
        best = np.where(better, cand, best)
        best_n = np.where(better, n, best_n)
    sel = (sub_c == best[..., None]) & (best[..., None] >= 0)
    wsum = sel.sum(axis=-1)
    mean_all = (sub_v * inside[..., None]).sum(axis=2) / inside.sum(axis=-1)[..., None]
    out = np.where(
        wsum[..., None] > 0,
        (sub_v * sel[..., None]).sum(axis=2) / np.maximum(wsum, 1)[..., None],
        mean_all,
    )
    return out, wsum > 0, best


def _dfd(vk_format: int) -> bytes:
    if vk_format == VK_FORMAT_BC7_UNORM_BLOCK:
        model, dims, plane0 = KHR_DF_MODEL_BC7, (3, 3, 0, 0), 16
        samples = [struct.pack("<HBB4BII", 0, 127, 0, 0, 0, 0, 0, 0, 0xFFFFFFFF)]
    elif vk_format == VK_FORMAT_R16G16B16A16_SFLOAT:
        model, dims, plane0 = KHR_DF_MODEL_RGBSDA, (0, 0, 0, 0), 8
        qual = KHR_DF_SAMPLE_DATATYPE_FLOAT | KHR_DF_SAMPLE_DATATYPE_SIGNED
        samples = [
            struct.pack("<HBB4BII", 16 * i, 15, cid | qual, 0, 0, 0, 0, 0xBF800000, 0x3F800000)
            for i, cid in enumerate((0, 1, 2, 15))
        ]
    else:  # pragma: no cover - internal
        raise ImageError(f"no DFD for VkFormat {vk_format}")
    block_size = 24 + 16 * len(samples)
    body = struct.pack(
        "<IHH4B4B8B",
        0,  # vendorId 0 (Khronos), descriptorType 0 (basic)
        2,  # versionNumber (KDF 1.3)
        block_size,
        model,
        KHR_DF_PRIMARIES_BT709,
        KHR_DF_TRANSFER_LINEAR,
        0,  # flags: straight alpha
        *dims,
        plane0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    ) + b"".join(samples)
    return struct.pack("<I", 4 + len(body)) + body


def _kvd(pairs: dict[str, str]) -> bytes:
    out = b""
    for key in sorted(pairs):
        kv = key.encode() + b"\0" + pairs[key].encode() + b"\0"
        out += struct.pack("<I", len(kv)) + kv
        out += b"\0" * (-len(out) % 4)
    return out


def _bc7(rgba: np.ndarray) -> bytes:
    """(h, w, 4) uint8 -> BC7 blocks (edges replicated up to a multiple of 4)."""
    import etcpak

    h, w = rgba.shape[:2]
    ph, pw = -h % 4, -w % 4
    if ph or pw:
        rgba = np.pad(rgba, ((0, ph), (0, pw), (0, 0)), mode="edge")
    p = etcpak.BC7CompressBlockParams()
    p.init_linear_weights()  # data, not colour: every channel weighs the same
    p.m_perceptual = False
    p.m_uber_level = 2
    p.m_max_partitions = 64
    p.m_try_least_squares = True
    return etcpak.compress_bc7(np.ascontiguousarray(rgba).tobytes(), w + pw, h + ph, p)


def encode_levels(levels, fmt: str) -> tuple[int, list[bytes]]:
    """Mip levels [(image (h, w, c) float64, mask)] -> (VkFormat, level payloads).

    fmt : "half" -> RGBA16F (A = 1); "unorm8" -> BC7 of the rounded codes (A = 255 for RGB)."""
    out = []
    if fmt == "half":
        for img, _ in levels:
            h, w, c = img.shape
            px = np.ones((h, w, 4), np.float16)
            px[..., :c] = img.astype(np.float16)
            out.append(px.tobytes())
        return VK_FORMAT_R16G16B16A16_SFLOAT, out
    if fmt == "unorm8":
        for img, _ in levels:
            h, w, c = img.shape
            px = np.full((h, w, 4), 255, np.uint8)
            px[..., :c] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
            out.append(_bc7(px))
        return VK_FORMAT_BC7_UNORM_BLOCK, out
    raise ImageError(f"no KTX2 encoding for texture format {fmt!r}")


def write(
    path: str | Path,
    image: np.ndarray,
    mask: np.ndarray,
    charts: np.ndarray,
    fmt: str,
    *,
    attributes: dict[str, str] | None = None,
) -> dict:
    """Write one lightmap texture as KTX2 with its chart-aware mip chain (atomically).

    image : (h, w, 3|4) stored values (float16 or uint8); mask, charts : (h, w) coverage and
    chart ids. fmt : the layout format ("half" or "unorm8"). attributes : extra key/value
    pairs (e.g. ``usdahd:packing``). returns {"vk_format", "levels", "bytes", "bytes_per_texel"}.
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ImageError(f"{path}: KTX2 textures have 3 or 4 channels, got {image.shape}")
    h, w = image.shape[:2]
    levels = mip_chain(image.astype(np.float64), mask, charts)
    vk, payloads = encode_levels(levels, fmt)
    dfd = _dfd(vk)
    kv = {"KTXwriter": f"usdahd {__version__}", "KTXorientation": "rd"}
    kv.update(attributes or {})
    kvd = _kvd(kv)
    n = len(payloads)
    header_len = 12 + 13 * 4 + 2 * 8 + n * 24
    dfd_off = header_len
    kvd_off = dfd_off + len(dfd)
    data_start = kvd_off + len(kvd)
    align = math.lcm(BLOCK_BYTES[vk], 4)
    # data: smallest level first
    offsets = [0] * n
    pos = data_start
    blob = b""
    for i in reversed(range(n)):
        pad = -pos % align
        blob += b"\0" * pad
        pos += pad
        offsets[i] = pos
        blob += payloads[i]
        pos += len(payloads[i])
    head = IDENTIFIER + struct.pack(
        "<9I", vk, 1 if vk == VK_FORMAT_BC7_UNORM_BLOCK else 2, w, h, 0, 0, 1, n, 0
    )
    head += struct.pack("<4I2Q", dfd_off, len(dfd), kvd_off, len(kvd), 0, 0)
    for i in range(n):
        head += struct.pack("<3Q", offsets[i], len(payloads[i]), len(payloads[i]))
    assert len(head) == header_len
    data = head + dfd + kvd + blob
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(data)
    return {
        "vk_format": vk,
        "levels": n,
        "bytes": len(data),
        "bytes_per_texel": len(payloads[0]) / (w * h),
    }
