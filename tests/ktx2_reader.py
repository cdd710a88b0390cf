"""A KTX 2.0 reader written from the Khronos KTX 2.0 specification, independent of usdahd.ktx2,
with texture2ddecoder (Perfare's Texture2DDecoder) decoding the BC7 blocks.

Used by tests/test_ktx2.py and benchmarks/ktx2_bench.py; imports numpy and texture2ddecoder only.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

KTX2_IDENTIFIER = bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])
VK_R16G16B16A16_SFLOAT = 97
VK_BC7_UNORM_BLOCK = 145


def read(path: str | Path) -> dict:
    """Parse a KTX2 file: header fields, DFD basic block, key/values and every mip level decoded
    to (h, w, 4) float16 (RGBA16F) or uint8 (BC7, RGBA)."""
    import texture2ddecoder

    data = Path(path).read_bytes()
    assert data[:12] == KTX2_IDENTIFIER, "not a KTX2 file"
    (vk, type_size, w, h, depth, layers, faces, levels, scheme) = struct.unpack_from(
        "<9I", data, 12
    )
    dfd_off, dfd_len, kvd_off, kvd_len, sgd_off, sgd_len = struct.unpack_from("<4I2Q", data, 48)
    index = [struct.unpack_from("<3Q", data, 80 + 24 * i) for i in range(max(levels, 1))]
    # DFD: total size, then one basic descriptor block
    total = struct.unpack_from("<I", data, dfd_off)[0]
    assert total == dfd_len
    vendor_type, version, block_size = struct.unpack_from("<IHH", data, dfd_off + 4)
    model, primaries, transfer, flags = data[dfd_off + 12 : dfd_off + 16]
    dims = tuple(data[dfd_off + 16 : dfd_off + 20])
    planes = tuple(data[dfd_off + 20 : dfd_off + 28])
    samples = []
    for k in range((block_size - 24) // 16):
        off = dfd_off + 28 + 16 * k
        bit_off, bit_len, ch_type = struct.unpack_from("<HBB", data, off)
        lower, upper = struct.unpack_from("<II", data, off + 8)
        samples.append((bit_off, bit_len + 1, ch_type & 0x0F, ch_type & 0xF0, lower, upper))
    kv, pos = {}, kvd_off
    while pos < kvd_off + kvd_len:
        n = struct.unpack_from("<I", data, pos)[0]
        key, _, value = data[pos + 4 : pos + 4 + n].partition(b"\0")
        kv[key.decode()] = value.rstrip(b"\0").decode()
        pos += 4 + n
        pos += -pos % 4
    images = []
    for i, (off, length, ulength) in enumerate(index):
        lw, lh = max(1, w >> i), max(1, h >> i)
        raw = data[off : off + length]
        if vk == VK_R16G16B16A16_SFLOAT:
            assert length == lw * lh * 8 == ulength
            images.append(np.frombuffer(raw, np.float16).reshape(lh, lw, 4))
        elif vk == VK_BC7_UNORM_BLOCK:
            bw, bh = math.ceil(lw / 4), math.ceil(lh / 4)
            assert length == bw * bh * 16
            bgra = texture2ddecoder.decode_bc7(raw, 4 * bw, 4 * bh)
            px = np.frombuffer(bgra, np.uint8).reshape(4 * bh, 4 * bw, 4)[..., [2, 1, 0, 3]]
            images.append(px[:lh, :lw])
        else:
            raise AssertionError(f"unexpected vkFormat {vk}")
    return {
        "vk_format": vk,
        "type_size": type_size,
        "size": (w, h),
        "depth_layers_faces": (depth, layers, faces),
        "levels": levels,
        "supercompression": scheme,
        "sgd": (sgd_off, sgd_len),
        "level_index": index,
        "dfd": {
            "vendor_type": vendor_type,
            "version": version,
            "model": model,
            "primaries": primaries,
            "transfer": transfer,
            "flags": flags,
            "block_dims": dims,
            "bytes_plane": planes,
            "samples": samples,
        },
        "kv": kv,
        "images": images,
    }
