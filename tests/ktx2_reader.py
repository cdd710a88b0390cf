"""A KTX 2.0 reader written from the Khronos KTX 2.0 specification, independent of usdahd.ktx2,
with texture2ddecoder (Perfare's Texture2DDecoder) decoding the BC7 blocks and Mesa's BC6H
decoder (lavapipe, through wgpu: a texture of format bc6h-rgb-ufloat read by a compute shader)
the BC6H blocks to float. texture2ddecoder's own BC6H decoder clamps to 8 bits in [0, 1]
(``half_to_u8``), so it cannot read HDR back; :func:`bc6h_u8` exposes it for a cross-check.

Used by tests/test_ktx2.py and benchmarks/ktx2_bench.py; imports numpy, texture2ddecoder and wgpu.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

KTX2_IDENTIFIER = bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])
VK_R8G8B8A8_UNORM = 37
VK_R16G16B16A16_SFLOAT = 97
VK_E5B9G9R9_UFLOAT_PACK32 = 123
VK_BC6H_UFLOAT_BLOCK = 131
VK_BC7_UNORM_BLOCK = 145

_LOAD = """
@group(0) @binding(0) var t: texture_2d<f32>;
@group(0) @binding(1) var<storage, read_write> o: array<vec4<f32>>;
@compute @workgroup_size(1) fn main(@builtin(global_invocation_id) g: vec3<u32>) {
  let d = textureDimensions(t);
  o[g.y * d.x + g.x] = textureLoad(t, vec2<i32>(i32(g.x), i32(g.y)), 0);
}"""
_DEVICE = []


def _device():
    if not _DEVICE:
        import wgpu

        adapter = wgpu.gpu.request_adapter_sync(power_preference="high-performance")
        if adapter is None or "texture-compression-bc" not in adapter.features:
            raise RuntimeError("no Vulkan adapter with BC textures (mesa-vulkan-drivers)")
        _DEVICE.append(adapter.request_device_sync(required_features=["texture-compression-bc"]))
    return _DEVICE[0]


def bc6h_float(blocks: bytes, w: int, h: int) -> np.ndarray:
    """BC6H_UFLOAT blocks -> (h, w, 4) float32 through the Vulkan driver's decoder."""
    return _driver_decode(blocks, w, h, "bc6h-rgb-ufloat")


def rgb9e5_float(texels: bytes, w: int, h: int) -> np.ndarray:
    """E5B9G9R9_UFLOAT texels -> (h, w, 4) float32 through the Vulkan driver's decoder."""
    return _driver_decode(texels, w, h, "rgb9e5ufloat")


def _driver_decode(raw: bytes, w: int, h: int, fmt: str) -> np.ndarray:
    import wgpu

    dev = _device()
    blocky = fmt.startswith("bc")
    bw, bh = (math.ceil(w / 4), math.ceil(h / 4)) if blocky else (w, h)
    usage = wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST
    size = (4 * bw, 4 * bh, 1) if blocky else (w, h, 1)
    tex = dev.create_texture(size=size, format=fmt, usage=usage)
    layout = {"bytes_per_row": bw * (16 if blocky else 4), "rows_per_image": bh}
    dev.queue.write_texture({"texture": tex}, raw, layout, size)
    out = dev.create_buffer(
        size=16 * size[0] * size[1], usage=wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC
    )
    module = dev.create_shader_module(code=_LOAD)
    pipe = dev.create_compute_pipeline(
        layout="auto", compute={"module": module, "entry_point": "main"}
    )
    group = dev.create_bind_group(
        layout=pipe.get_bind_group_layout(0),
        entries=[
            {"binding": 0, "resource": tex.create_view()},
            {"binding": 1, "resource": {"buffer": out}},
        ],
    )
    enc = dev.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipe)
    cp.set_bind_group(0, group)
    cp.dispatch_workgroups(size[0], size[1])
    cp.end()
    dev.queue.submit([enc.finish()])
    px = np.frombuffer(dev.queue.read_buffer(out), np.float32).reshape(size[1], size[0], 4)
    return px[:h, :w]


def bc6h_u8(blocks: bytes, w: int, h: int) -> np.ndarray:
    """BC6H_UFLOAT blocks -> (h, w, 4) uint8 RGBA by texture2ddecoder (clamped to [0, 1])."""
    import texture2ddecoder

    bw, bh = math.ceil(w / 4), math.ceil(h / 4)
    bgra = texture2ddecoder.decode_bc6(blocks, 4 * bw, 4 * bh)
    return np.frombuffer(bgra, np.uint8).reshape(4 * bh, 4 * bw, 4)[..., [2, 1, 0, 3]][:h, :w]


def read(path: str | Path) -> dict:
    """Parse a KTX2 file: header fields, DFD basic block, key/values and every mip level decoded
    to (h, w, 4): float16 (RGBA16F), float32 (BC6H and E5B9G9R9, Mesa's decoders) or uint8
    (RGBA8, BC7)."""
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
        elif vk == VK_R8G8B8A8_UNORM:
            assert length == lw * lh * 4 == ulength
            images.append(np.frombuffer(raw, np.uint8).reshape(lh, lw, 4))
        elif vk == VK_BC6H_UFLOAT_BLOCK:
            assert length == math.ceil(lw / 4) * math.ceil(lh / 4) * 16
            images.append(bc6h_float(raw, lw, lh))
        elif vk == VK_E5B9G9R9_UFLOAT_PACK32:
            assert length == lw * lh * 4 == ulength
            images.append(rgb9e5_float(raw, lw, lh))
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
        "raw": [data[off : off + length] for off, length, _ in index],
    }
