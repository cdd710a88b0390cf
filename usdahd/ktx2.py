"""Engine container: KTX 2.0 files with chart-aware mip chains (``usdahd bake --container ktx2``).

Per lightmap texture (docs/schema.md layout) one ``<name>.<role>.ktx2`` beside the EXR/PNG, in
one of two compressions (``usdahd bake --container ktx2`` / ``--container ktx2-bc``):

- ``"none"`` (``ktx2``, the default): the stored values as they are, so an engine decodes
  exactly what the EXR/PNG hold: float16 textures ``VK_FORMAT_R16G16B16A16_SFLOAT`` (A = 1,
  8 bytes per texel), 8-bit textures ``VK_FORMAT_R8G8B8A8_UNORM`` (A = 255 for RGB, 4 bytes per
  texel).
- ``"bc"`` (``ktx2-bc``): block-compressed where the result holds up (issue 39: the default
  hhd/luminance within 2 % relRMSE of the EXR/PNG irradiance on every sample). Non-negative RGB
  float16 textures (I_z, ambient, C_d, hemisphere, ...) ``VK_FORMAT_BC6H_UFLOAT_BLOCK`` (1 byte per
  texel; -0.0 written as 0: the unsigned encoder reads the bits of -0.0 as 65504) when level 0
  decoded again (bcdec through imagecodecs) is within :data:`BC6H_MAX_REL_RMSE` (RMSE over the
  covered texels / their mean), else ``VK_FORMAT_E5B9G9R9_UFLOAT_PACK32`` (shared exponent, 4 bytes
  per texel, within 2^-8 of each texel's largest channel): BC6H interpolates a 4 x 4 block in its
  half-float bit domain with 8 or 16 levels, so a block that spans a hotspot (floor_lamp's floor:
  0.12 to 2.84) is off by up to 13 % per texel, and no ispc-texcomp profile (veryfast to veryslow)
  changes that much. Float16 textures with a negative value (the signed SH / HL2 / ambient-cube
  coefficients, no signed BC6H encoder on the package index) or an alpha stay RGBA16F. 8-bit
  textures ``VK_FORMAT_BC7_UNORM_BLOCK`` when level 0's decoded quantities (bcdec through
  imagecodecs) are within :data:`BC7_MAX_REL_RMSE`, else RGBA8, except the hemi-octahedral direction
  and ratio codes (:data:`LOSSLESS_PACKINGS`), which stay RGBA8: BC7 moves (u, v) codes by several
  steps where the direction varies texel to texel inside a block, and ``C_d = I_z (1 - w_a) / d_z``
  magnifies a move towards the horizon (hhd/luminance through BC7: 61 % relRMSE of irradiance on
  pillar_room; no BC7 profile, gutter fill or layout tried came within 10x of 2 %,
  docs/benchmarks.md). The encoder is ispc-texcomp (Python bindings of Intel's
  ISPCTextureCompressor, MIT; manylinux, macOS and Windows abi3 wheels): the only BC6H encoder on
  the package index, and its BC7 ("slow" profile) halves etcpak's error. BC6H uses the "slow"
  profile (2.2 s per 512 x 512 here; "veryslow" 4.7 s for the same result).

The codes keep their meaning (the biases of docs/schema.md apply to the decoded bytes).

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
lcm(texel block size, 4)), a Basic Data Format Descriptor (E5B9G9R9: the six samples libktx
writes), key/value data (``KTXwriter``, ``KTXorientation = rd``: row 0 is the top, like the
PNG/EXR) and no supercompression. numpy (and ispc-texcomp + imagecodecs for ``"bc"``) only;
every write is atomic.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from usdahd.errors import ImageError
from usdahd.io_util import atomic_path
from usdahd.version import __version__

__all__ = ["write"]

IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"
VK_FORMAT_R8G8B8A8_UNORM = 37
VK_FORMAT_R16G16B16A16_SFLOAT = 97
VK_FORMAT_E5B9G9R9_UFLOAT_PACK32 = 123
VK_FORMAT_BC6H_UFLOAT_BLOCK = 131
VK_FORMAT_BC7_UNORM_BLOCK = 145
#: the compressions of write(): "none" (lossless, ``--container ktx2``), "bc" (``ktx2-bc``)
COMPRESSIONS = ("none", "bc")
#: ISPCTextureCompressor profiles (speed/quality measured in the module docstring)
BC6H_PROFILE = "slow"
BC7_PROFILE = "slow"
#: the largest BC6H error a "bc" texture may keep: RMSE of level 0 (decoded by bcdec through
#: imagecodecs) over the covered texels, divided by their mean |value|; above it the texture is
#: written E5B9G9R9 (shared exponent, 4 B/texel; RGBA16F with an alpha). 1.5 % keeps the
#: default hhd/luminance within issue 39's 2 % of irradiance (linear in I_z; docs/benchmarks.md)
BC6H_MAX_REL_RMSE = 0.015
#: the largest BC7 error an 8-bit "bc" texture may keep: RMSE of level 0's decoded quantities
#: (:func:`packed_quantities`: the channel codes of its packing, for Enlighten's 8-bit SH the
#: irradiance L0 + L1 . n over :data:`CHECK_NORMALS`) over the covered texels, divided by their
#: mean |value|; above it the texture is written RGBA8. sh_l1/8bit through BC7 unchecked read
#: 2.9 % to 72 % of irradiance on 6 of 9 samples (docs/benchmarks.md): a BC7 endpoint error of a
#: few codes in a small L0 code q is 2 dq / q of L0, and every L1 code is relative to it.
BC7_MAX_REL_RMSE = 0.015
#: Tangent-space unit normals the 8-bit SH check evaluates L0 + L1 . n at: the pole and two rings
#: (45 and 80 degrees from it, 6 and 8 azimuths: the horizon is where L1 errors weigh most).
CHECK_NORMALS = np.concatenate(
    [
        [[0.0, 0.0, 1.0]],
        *(
            np.stack(
                [
                    np.sin(t) * np.cos(a),
                    np.sin(t) * np.sin(a),
                    np.full(len(a), np.cos(t)),
                ],
                axis=-1,
            )
            for t, a in (
                (np.radians(45.0), np.arange(6) * np.pi / 3),
                (np.radians(80.0), np.arange(8) * np.pi / 4),
            )
        ),
    ]
)
#: 8-bit packings that stay RGBA8 under "bc": the hemi-octahedral direction codes (u, v) of the
#: IrradZ models and ahd_classic and the IrradZ per-channel ambient ratios w_a (``ratio``), whose
#: BC7 error the decode multiplies by 1 / d_z (C_d = I_z (1 - w_a) / d_z)
LOSSLESS_PACKINGS = ("R=u:snorm8b", "R=w_a.R:")
#: Basic DFD colour models and channel ids (Khronos Data Format Specification 1.3).
KHR_DF_MODEL_RGBSDA = 1
KHR_DF_MODEL_BC6H = 133
KHR_DF_MODEL_BC7 = 134
KHR_DF_PRIMARIES_BT709 = 1
KHR_DF_TRANSFER_LINEAR = 1
KHR_DF_SAMPLE_DATATYPE_FLOAT = 0x80
KHR_DF_SAMPLE_DATATYPE_SIGNED = 0x40
KHR_DF_SAMPLE_DATATYPE_EXPONENT = 0x20
#: E5B9G9R9 (EXT_texture_shared_exponent): 9-bit mantissas, a 5-bit exponent, bias 15
E5_MANTISSA_BITS = 9
E5_BIAS = 15
E5_MAX = (2**9 - 1) / 2**9 * 2.0 ** (31 - 15)  # 65408
#: bytes per texel (RGBA8, RGBA16F) / per 4 x 4 block (BC6H, BC7)
BLOCK_BYTES = {
    VK_FORMAT_R8G8B8A8_UNORM: 4,
    VK_FORMAT_R16G16B16A16_SFLOAT: 8,
    VK_FORMAT_E5B9G9R9_UFLOAT_PACK32: 4,
    VK_FORMAT_BC6H_UFLOAT_BLOCK: 16,
    VK_FORMAT_BC7_UNORM_BLOCK: 16,
}
BLOCK_FORMATS = (VK_FORMAT_BC6H_UFLOAT_BLOCK, VK_FORMAT_BC7_UNORM_BLOCK)
#: typeSize of the KTX2 header: 1 for bytes and blocks, 2 for float16
TYPE_SIZE = {VK_FORMAT_R16G16B16A16_SFLOAT: 2, VK_FORMAT_E5B9G9R9_UFLOAT_PACK32: 4}


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
    elif vk_format == VK_FORMAT_BC6H_UFLOAT_BLOCK:
        # one 128-bit sample, channel 0 (BC6H colour), float, unsigned: lower 0.0, upper 1.0
        model, dims, plane0 = KHR_DF_MODEL_BC6H, (3, 3, 0, 0), 16
        qual = KHR_DF_SAMPLE_DATATYPE_FLOAT
        samples = [struct.pack("<HBB4BII", 0, 127, qual, 0, 0, 0, 0, 0, 0x3F800000)]
    elif vk_format == VK_FORMAT_R8G8B8A8_UNORM:
        model, dims, plane0 = KHR_DF_MODEL_RGBSDA, (0, 0, 0, 0), 4
        samples = [
            struct.pack("<HBB4BII", 8 * i, 7, cid, 0, 0, 0, 0, 0, 255)
            for i, cid in enumerate((0, 1, 2, 15))
        ]
    elif vk_format == VK_FORMAT_E5B9G9R9_UFLOAT_PACK32:
        # per channel a mantissa sample (bits 0, 9, 18; 1.0 = 8448 as libktx writes it) and the
        # shared exponent (bits 27..31, qualifier EXPONENT, bias 15, max 31)
        model, dims, plane0 = KHR_DF_MODEL_RGBSDA, (0, 0, 0, 0), 4
        exp = KHR_DF_SAMPLE_DATATYPE_EXPONENT
        samples = []
        for cid in (0, 1, 2):
            samples.append(struct.pack("<HBB4BII", 9 * cid, 8, cid, 0, 0, 0, 0, 0, 8448))
            samples.append(struct.pack("<HBB4BII", 27, 4, cid | exp, 0, 0, 0, 0, 15, 31))
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


def _pad4(px: np.ndarray) -> np.ndarray:
    """Edges replicated up to a multiple of 4 (whole blocks)."""
    h, w = px.shape[:2]
    return np.pad(px, ((0, -h % 4), (0, -w % 4), (0, 0)), mode="edge")


def _encoder():
    try:
        import ispc_texcomp
    except ImportError:
        raise ImageError(
            "KTX2 block compression (--container ktx2-bc) needs ispc-texcomp (the BC6H/BC7 "
            "encoder): pip install 'usdahd[ktx2]'"
        ) from None
    return ispc_texcomp


def _bcn_decode(blocks: bytes, h: int, w: int, fmt: str) -> np.ndarray:
    """BC6H_UF16 (``fmt`` "BC6HU": (h, w, 3)) or BC7 ("BC7": (h, w, 4) codes 0..255) blocks ->
    float64 (bcdec through imagecodecs)."""
    try:
        import imagecodecs
    except ImportError:
        raise ImageError(
            "KTX2 block compression (--container ktx2-bc) needs imagecodecs (it checks each "
            f"{fmt.rstrip('U')} texture's error): pip install 'usdahd[ktx2]'"
        ) from None
    hp, wp = h + (-h % 4), w + (-w % 4)
    c = 3 if fmt == "BC6HU" else 4
    out = imagecodecs.bcn_decode(blocks, getattr(imagecodecs.BCN.FORMAT, fmt), shape=(hp, wp, c))
    return np.asarray(out, np.float64)[:h, :w]


def _rel_rmse(dec: np.ndarray, src: np.ndarray) -> float:
    """RMSE of ``dec`` against ``src`` / mean |src| (0 when exact, inf for a zero source that
    does not decode to zero)."""
    if src.size == 0:
        return 0.0
    rmse = math.sqrt(float(((dec - src) ** 2).mean()))
    mean = float(np.abs(src).mean())
    if rmse == 0.0:
        return 0.0
    return rmse / mean if mean > 0 else math.inf


def bc6h_rel_rmse(blocks: bytes, px: np.ndarray, mask: np.ndarray, channels: int = 3) -> float:
    """Error of BC6H blocks against their (h, w, 4) float16 source: RMSE over the covered texels
    and the first ``channels`` channels (4: an alpha that BC6H decodes as 1) / their mean |value|
    (0 when exact, inf for a zero source that does not decode to zero)."""
    h, w = px.shape[:2]
    dec = np.concatenate([_bcn_decode(blocks, h, w, "BC6HU"), np.ones((h, w, 1))], axis=-1)
    m = np.asarray(mask, bool) if np.asarray(mask).any() else np.ones((h, w), bool)
    return _rel_rmse(dec[m][:, :channels], px.astype(np.float64)[m][:, :channels])


def _bc7(rgba: np.ndarray, alpha: bool) -> bytes:
    """(h, w, 4) uint8 -> BC7 blocks (ISPCTextureCompressor, all channels weigh the same; the
    ``alpha_`` profile when A holds data, as the opaque ones write A = 255)."""
    t = _encoder()
    p = np.ascontiguousarray(_pad4(rgba))
    surf = t.RGBASurface(p.tobytes(), p.shape[1], p.shape[0], p.shape[1] * 4)
    prof = ("alpha_" if alpha else "") + BC7_PROFILE
    return t.compress_blocks_bc7(surf, t.BC7EncSettings.from_profile(prof))


def packing_codes(packing: str) -> list[str]:
    """The channel codes of a ``usdahd:packing`` value (``R=L0.R:l0_8bit*l0Scale G=...`` ->
    ["l0_8bit", ...]; docs/schema.md), in channel order; [] for an empty packing."""
    return [item.split(":", 1)[1].split("*", 1)[0] for item in packing.split() if ":" in item]


def packed_quantities(q: np.ndarray, codes: list[str]) -> np.ndarray:
    """(n, 4) float64 8-bit codes -> (n, k) float64 quantities the BC7 check compares.

    Enlighten's 8-bit SH (codes ``l0_8bit, l1_8bit x 3``): the irradiance-like L0 + L1 . n at
    each of :data:`CHECK_NORMALS` with L0 = (q0 / 255)^2 and L1_i = (q_i - 127) / 127 L0 (the
    l0Scale factor cancels in a relative error). Otherwise each channel's own code
    (``unorm8`` q / 255, ``snorm8b`` (q - 128) / 127; ``reserved`` channels dropped; a channel
    without a code, e.g. RGBA8's opaque A, dropped; an unknown code read as q / 255)."""
    q = np.asarray(q, np.float64)
    if codes[:4] == ["l0_8bit", "l1_8bit", "l1_8bit", "l1_8bit"]:
        l0 = (q[:, 0] / 255.0) ** 2
        l1 = (q[:, 1:4] - 127.0) / 127.0 * l0[:, None]
        return l0[:, None] + l1 @ CHECK_NORMALS.T
    cols = []
    for i, code in enumerate(codes[: q.shape[1]]):
        if code == "reserved":
            continue
        cols.append((q[:, i] - 128.0) / 127.0 if code == "snorm8b" else q[:, i] / 255.0)
    return np.stack(cols, axis=-1) if cols else q[:, :0]


def bc7_rel_rmse(blocks: bytes, px: np.ndarray, mask: np.ndarray, codes: list[str]) -> float:
    """Error of BC7 blocks against their (h, w, 4) uint8 source: RMSE of the decoded quantities
    (:func:`packed_quantities`) over the covered texels / their mean |value| (0 when exact, inf
    for a zero source that does not decode to zero)."""
    h, w = px.shape[:2]
    m = np.asarray(mask, bool) if np.asarray(mask).any() else np.ones((h, w), bool)
    src = packed_quantities(px.astype(np.float64)[m], codes)
    return _rel_rmse(packed_quantities(_bcn_decode(blocks, h, w, "BC7")[m], codes), src)


def _bc6h(rgba: np.ndarray) -> bytes:
    """(h, w, 4) float16 >= 0 -> BC6H_UF16 blocks (ISPCTextureCompressor)."""
    t = _encoder()
    p = np.ascontiguousarray(_pad4(rgba))
    surf = t.RGBASurface(p.tobytes(), p.shape[1], p.shape[0], p.shape[1] * 8)
    return t.compress_blocks_bc6h(surf, t.BC6HEncSettings.from_profile(BC6H_PROFILE))


def e5b9g9r9(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) float >= 0 -> (h, w) uint32 E5B9G9R9 (EXT_texture_shared_exponent's encoder:
    the exponent of the largest channel, mantissas rounded to nearest)."""
    c = np.clip(np.nan_to_num(np.asarray(rgb, np.float64)), 0.0, E5_MAX)
    mx = c.max(axis=-1)
    _, e = np.frexp(mx)  # mx = f 2^e, f in [0.5, 1): floor(log2 mx) = e - 1 (mx > 0)
    exp_p = np.where(mx > 0, np.maximum(-E5_BIAS - 1, e - 1), -E5_BIAS - 1) + 1 + E5_BIAS
    n = E5_MANTISSA_BITS
    maxm = np.floor(mx / np.exp2(exp_p - E5_BIAS - n) + 0.5)
    exp = np.where(maxm >= 2**n, exp_p + 1, exp_p)
    m = np.floor(c / np.exp2(exp - E5_BIAS - n)[..., None] + 0.5).astype(np.uint32)
    m = np.minimum(m, 2**n - 1)
    return m[..., 0] | (m[..., 1] << 9) | (m[..., 2] << 18) | (exp.astype(np.uint32) << 27)


def _rgba(img: np.ndarray, dtype, one) -> np.ndarray:
    h, w, c = img.shape
    px = np.full((h, w, 4), one, dtype)
    if dtype == np.uint8:
        px[..., :c] = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    else:
        px[..., :c] = img.astype(np.float16)
    return px


def encode_levels(
    levels,
    fmt: str,
    compression: str = "none",
    *,
    lossless: bool = False,
    max_rel_rmse: float = BC6H_MAX_REL_RMSE,
    stats=None,
    codes: tuple[str, ...] = (),
    max_bc7_rel_rmse: float = BC7_MAX_REL_RMSE,
) -> tuple[int, list[bytes]]:
    """Mip levels [(image (h, w, c) float64, mask)] -> (VkFormat, level payloads).

    fmt "half": RGBA16F (A = 1), or with compression "bc" BC6H_UFLOAT when no value is negative
    and level 0's error (:func:`bc6h_rel_rmse` over its covered texels) is at most
    ``max_rel_rmse`` (:data:`BC6H_MAX_REL_RMSE`), else E5B9G9R9 (RGB) or RGBA16F (RGBA, or a
    negative value); fmt "unorm8": RGBA8 of the rounded codes (A = 255 for RGB), or BC7 with
    compression "bc" unless ``lossless`` (the codes of :data:`LOSSLESS_PACKINGS`) or level 0's
    error (:func:`bc7_rel_rmse` of the channel ``codes``, :func:`packing_codes`) is above
    ``max_bc7_rel_rmse`` (:data:`BC7_MAX_REL_RMSE`). ``stats``: a dict that receives
    ``bc_rel_rmse`` (the BC6H / BC7 error measured) and, when a "bc" texture is not
    block-compressed, ``bc_fallback`` (why, and the format written)."""
    if compression not in COMPRESSIONS:
        raise ImageError(f"KTX2 compression must be one of {COMPRESSIONS}, got {compression!r}")
    bc = compression == "bc"
    stats = {} if stats is None else stats
    if fmt == "half":
        pxs = [_rgba(img, np.float16, 1.0) for img, _ in levels]
        if bc and any((p < 0).any() for p in pxs):
            stats["bc_fallback"] = "negative values (no signed BC6H encoder): RGBA16F"
        elif bc:
            # -0.0 (sign bit set, e.g. an SH coefficient that cancels) passes "not < 0" but
            # an unsigned BC6H encoder reads its bits 0x8000 as the largest value: 65504
            pxs = [np.where(p == 0, np.float16(0), p) for p in pxs]
            first = _bc6h(pxs[0])
            err = bc6h_rel_rmse(first, pxs[0], levels[0][1], levels[0][0].shape[-1])
            stats["bc_rel_rmse"] = err if math.isfinite(err) else None
            if err <= max_rel_rmse:
                return VK_FORMAT_BC6H_UFLOAT_BLOCK, [first] + [_bc6h(p) for p in pxs[1:]]
            why = f"BC6H error {err:.3g} > {max_rel_rmse:g} (RMSE / mean of level 0)"
            if levels[0][0].shape[-1] == 3:  # no alpha: the shared-exponent format, 4 B/texel
                stats["bc_fallback"] = why + ": E5B9G9R9"
                rgb = [p[..., :3].astype(np.float64) for p in pxs]
                return VK_FORMAT_E5B9G9R9_UFLOAT_PACK32, [e5b9g9r9(p).tobytes() for p in rgb]
            stats["bc_fallback"] = why + ": RGBA16F"
            pxs = [_rgba(img, np.float16, 1.0) for img, _ in levels]
        return VK_FORMAT_R16G16B16A16_SFLOAT, [p.tobytes() for p in pxs]
    if fmt == "unorm8":
        pxs = [_rgba(img, np.uint8, 255) for img, _ in levels]
        if bc and lossless:
            stats["bc_fallback"] = "direction / ratio codes (BC7 error times 1 / d_z): RGBA8"
        elif bc:
            alpha = levels[0][0].shape[-1] == 4
            first = _bc7(pxs[0], alpha)
            err = bc7_rel_rmse(first, pxs[0], levels[0][1], list(codes))
            stats["bc_rel_rmse"] = err if math.isfinite(err) else None
            if err <= max_bc7_rel_rmse:
                return VK_FORMAT_BC7_UNORM_BLOCK, [first] + [_bc7(p, alpha) for p in pxs[1:]]
            stats["bc_fallback"] = (
                f"BC7 error {err:.3g} > {max_bc7_rel_rmse:g} (RMSE / mean of level 0's decoded "
                "quantities): RGBA8"
            )
        return VK_FORMAT_R8G8B8A8_UNORM, [p.tobytes() for p in pxs]
    raise ImageError(f"no KTX2 encoding for texture format {fmt!r}")


def write(
    path: str | Path,
    image: np.ndarray,
    mask: np.ndarray,
    charts: np.ndarray,
    fmt: str,
    *,
    compression: str = "none",
    attributes: dict[str, str] | None = None,
    max_rel_rmse: float = BC6H_MAX_REL_RMSE,
    max_bc7_rel_rmse: float = BC7_MAX_REL_RMSE,
) -> dict:
    """Write one lightmap texture as KTX2 with its chart-aware mip chain (atomically).

    image : (h, w, 3|4) stored values (float16 or uint8); mask, charts : (h, w) coverage and
    chart ids. fmt : the layout format ("half" or "unorm8"). compression : "none" (lossless
    RGBA16F / RGBA8) or "bc" (BC6H / BC7, see the module docstring). attributes : extra key/value
    pairs (e.g. ``usdahd:packing``; a packing of :data:`LOSSLESS_PACKINGS` stays RGBA8 under
    "bc"). max_rel_rmse, max_bc7_rel_rmse : the BC6H / BC7 error bounds of
    :func:`encode_levels` (the BC7 one on the quantities of the packing's channel codes).
    returns {"vk_format", "levels", "bytes", "bytes_per_texel"} plus, under "bc",
    ``bc_rel_rmse`` (the BC6H / BC7 error measured) and ``bc_fallback`` (why a texture is not
    block-compressed, and its format).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ImageError(f"{path}: KTX2 textures have 3 or 4 channels, got {image.shape}")
    h, w = image.shape[:2]
    levels = mip_chain(image.astype(np.float64), mask, charts)
    packing = (attributes or {}).get("usdahd:packing", "")
    lossless = any(packing.startswith(p) for p in LOSSLESS_PACKINGS)
    stats: dict = {}
    vk, payloads = encode_levels(
        levels,
        fmt,
        compression,
        lossless=lossless,
        max_rel_rmse=max_rel_rmse,
        stats=stats,
        codes=tuple(packing_codes(packing)),
        max_bc7_rel_rmse=max_bc7_rel_rmse,
    )
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
    head = IDENTIFIER + struct.pack("<9I", vk, TYPE_SIZE.get(vk, 1), w, h, 0, 0, 1, n, 0)
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
        **stats,
    }
