"""wgpu rasterisation of ``usdahd preview`` with the shipped WGSL decoders (issue 14).

Per fragment the lightmap tangent frame is rebuilt from the interpolated normal and the
lightmap-UV tangent, the textures are sampled bilinearly at the lightmap UV, decoded and
evaluated at the shading normal (``usdahd/shaders/wgsl``). Back faces are culled
(counter-clockwise front faces). :func:`device` finds a Vulkan adapter (Mesa's lavapipe on the
CPU, or a GPU) or says what to install.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile

import numpy as np

from usdahd.errors import UsageError

__all__ = ["device", "render", "request_adapter", "upload_texture"]

INSTALL_HINT = (
    "usdahd preview renders through wgpu (installed with usdahd) on a Vulkan device; for the "
    "CPU: apt-get install mesa-vulkan-drivers libvulkan1"
)
#: Lines the Vulkan loader and Mesa's window-system code print to stderr while an adapter is
#: found, which say nothing about an offscreen render (``XDG_RUNTIME_DIR`` is a Wayland
#: session's folder; a headless preview needs none). Dropped; every other line is passed on.
NOISE = ("XDG_RUNTIME_DIR is invalid or not set",)


@contextlib.contextmanager
def _filtered_stderr():
    """Run the block with file descriptor 2 captured (native code writes there directly);
    afterwards pass each line on to stderr except the NOISE lines."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2: nothing to filter
        yield
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", errors="replace")
            for line in text.splitlines():
                if line.strip() and not any(n in line for n in NOISE):
                    print(line, file=sys.stderr)


FACTORS = (
    "izScale",
    "ambientScale",
    "directionalScale",
    "coefficientsScale",
    "l0Scale",
    "ratioScale",
)


def request_adapter():
    """The wgpu adapter, or None (no adapter); raises ImportError without wgpu."""
    import wgpu

    try:
        return wgpu.gpu.request_adapter_sync(power_preference="high-performance")
    except Exception:  # wgpu raises when no Vulkan loader/driver is present
        return None


def device(backend: str = "wgpu"):
    """(adapter, device) for wgpu, or None when ``backend`` is "auto" and there is no Vulkan
    adapter (one line on stderr says what to install). UsageError when "wgpu" has none."""
    try:
        with _filtered_stderr():
            adapter = request_adapter()
        why = "no Vulkan adapter found"
    except ImportError:
        adapter, why = None, "wgpu is not installed"
    if adapter is None:
        if backend == "auto":
            print(f"usdahd preview: {why}; {INSTALL_HINT}; falling back to Embree", file=sys.stderr)
            return None
        raise UsageError(f"{why}; {INSTALL_HINT}")
    # float32-filterable: the --model-view material textures keep float32 texels (else half)
    wanted = [f for f in ("float32-filterable",) if f in adapter.features]
    with _filtered_stderr():
        return adapter, adapter.request_device_sync(required_features=wanted)


_SHADER = """
struct U {{
    viewproj: mat4x4<f32>,
    f0: vec4<f32>,
    f1: vec4<f32>,{mv_uniform}{cut_uniform}
}}
@group(0) @binding(0) var<uniform> u: U;
@group(0) @binding(1) var samp: sampler;
{textures}
{library}{cut_library}
struct VOut {{
    @builtin(position) pos: vec4<f32>,
    @location(0) st: vec2<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) tangent: vec4<f32>,{mv_vout}{cut_vout}
}}

@vertex
fn vs(@location(0) p: vec3<f32>, @location(1) st: vec2<f32>, @location(2) n: vec3<f32>,
      @location(3) t: vec4<f32>{mv_vs_in}{cut_vs_in}) -> VOut {{
    return VOut(u.viewproj * vec4<f32>(p, 1.0), st, n, t{mv_vs_out}{cut_vs_out});
}}

@fragment
fn fs(v: VOut) -> @location(0) vec4<f32> {{
    let izScale = u.f0.x;
    let ambientScale = u.f0.y;
    let directionalScale = u.f0.z;
    let coefficientsScale = u.f0.w;
    let l0Scale = u.f1.x;
    let ratioScale = u.f1.y;
    let frame = usdahd_tangent_frame(v.normal, v.tangent);
{shading}
    let uv = usdahd_lightmap_texcoord(v.st);
{samples}
    let p = {decode};{cut_test}
    return vec4<f32>({result}, 1.0);
}}
"""

#: --model-view additions to _SHADER: the material's texcoord and tangent per vertex, its
#: albedo (uniform constant x texture) and normal map (usdahd_apply_normal_map in the material
#: frame, then usdahd_to_tangent in the lightmap frame, docs/schema.md).
_MODEL_VIEW = {
    "mv_uniform": "\n    albedo: vec4<f32>,",
    "mv_vout": "\n    @location(3) mst: vec2<f32>,\n    @location(4) mtangent: vec4<f32>,",
    "mv_vs_in": ",\n      @location(4) mst: vec2<f32>, @location(5) mt: vec4<f32>",
    "mv_vs_out": ", mst, mt",
    "shading": """    let mframe = usdahd_tangent_frame(v.normal, v.mtangent);
    let mtc = usdahd_lightmap_texcoord(v.mst); // row 0 is v = 1, as for UsdUVTexture
    let albedo = u.albedo.rgb * textureSample(albedo_tex, albedo_samp, mtc).rgb;
    let N = usdahd_apply_normal_map(textureSample(normal_tex, normal_samp, mtc).rgb, mframe);
    let n = usdahd_to_tangent(frame, N);""",
}
#: Cut-out additions to _SHADER (:mod:`usdahd.preview.cutout`): the material's texcoord per
#: vertex, the opacity (constant or texture channel) and threshold, and the tracer's rule:
#: discard below a threshold > 0, else with probability 1 - opacity (a per-pixel hash).
_CUTOUT = {
    "cut_uniform": "\n    cut: vec4<f32>, // opacity, threshold, textured, 0",
    "cut_vout": "\n    @location(5) cst: vec2<f32>,",
    "cut_vs_in": ",\n      @location(6) cst: vec2<f32>",
    "cut_vs_out": ", cst",
    "cut_library": """
fn usdahd_preview_noise(p: vec2<f32>) -> f32 {
    var h = u32(p.x) * 1973u + u32(p.y) * 9277u + 26699u;
    h = (h ^ 61u) ^ (h >> 16u);
    h = h * 9u;
    h = h ^ (h >> 4u);
    h = h * 0x27d4eb2du;
    h = h ^ (h >> 15u);
    return f32(h >> 8u) / 16777216.0;
}
""",
    "cut_test": """
    let op_tex = textureSample(cut_tex, cut_samp, usdahd_lightmap_texcoord(v.cst)).r;
    let op = select(u.cut.x, op_tex, u.cut.z > 0.5);
    let threshold = u.cut.y;
    let below = (op < threshold);
    let fractional = (op < 1.0) && (usdahd_preview_noise(v.pos.xy) >= op);
    let cut = (threshold > 0.0);
    if (select(fractional, below, cut)) {
        discard;
    }""",
}
_NO_CUTOUT = {k: "" for k in _CUTOUT}
_FLAT_SHADING = {
    "mv_uniform": "",
    "mv_vout": "",
    "mv_vs_in": "",
    "mv_vs_out": "",
    "shading": "    let n = usdahd_to_tangent(frame, frame.n); // the interpolated normal",
}


def shader_source(
    model: str, ratio: str, n_textures: int, model_view: bool = False, cutout: bool = False
) -> str:
    """WGSL vertex + fragment shader of one model variant (the shipped decoders); with
    ``model_view`` times the albedo, at the normal-mapped normal (bindings 2 + n_textures..:
    albedo texture, normal texture, their sampler); with ``cutout`` the opacity test of
    :mod:`usdahd.preview.cutout` (the next two bindings: opacity texture, its sampler)."""
    from usdahd import shaders

    _, call, _, evaluate = shaders.calls(model, ratio)
    textures = [
        f"@group(0) @binding({2 + j}) var tex{j}: texture_2d<f32>;" for j in range(n_textures)
    ]
    b = 2 + n_textures
    if model_view:
        textures += [
            f"@group(0) @binding({b}) var albedo_tex: texture_2d<f32>;",
            f"@group(0) @binding({b + 1}) var normal_tex: texture_2d<f32>;",
            f"@group(0) @binding({b + 2}) var albedo_samp: sampler;",
            f"@group(0) @binding({b + 3}) var normal_samp: sampler;",
        ]
        b += 4
    if cutout:
        textures += [
            f"@group(0) @binding({b}) var cut_tex: texture_2d<f32>;",
            f"@group(0) @binding({b + 1}) var cut_samp: sampler;",
        ]
    return _SHADER.format(
        textures="\n".join(textures),
        samples="\n".join(
            f"    let s{j} = textureSample(tex{j}, samp, uv);" for j in range(n_textures)
        ),
        library=shaders.source("wgsl", model),
        decode=call,
        result=f"albedo * {evaluate}(p, n)" if model_view else f"{evaluate}(p, n)",
        **(_MODEL_VIEW if model_view else _FLAT_SHADING),
        **(_CUTOUT if cutout else _NO_CUTOUT),
    )


def upload_texture(dev, pixels: np.ndarray):
    """A sampled wgpu texture of ``pixels`` (h, w, c <= 4): float32 as rgba32float (rgba16float
    when the device cannot filter float32), float16 as rgba16float, uint8 as rgba8unorm; missing
    channels are 1 (alpha opaque). Row 0 is the top of the image."""
    import wgpu

    h, w, c = pixels.shape
    if pixels.dtype == np.float32 and "float32-filterable" not in dev.features:
        pixels = pixels.astype(np.float16)
    if pixels.dtype == np.float32:
        fmt, one = wgpu.TextureFormat.rgba32float, np.float32(1.0)
    elif pixels.dtype == np.float16:
        fmt, one = wgpu.TextureFormat.rgba16float, np.float16(1.0)
    else:
        fmt, one = wgpu.TextureFormat.rgba8unorm, np.uint8(255)
    rgba = np.full((h, w, 4), one, pixels.dtype)
    rgba[..., :c] = pixels
    tex = dev.create_texture(
        size=(w, h, 1),
        format=fmt,
        usage=wgpu.TextureUsage.TEXTURE_BINDING | wgpu.TextureUsage.COPY_DST,
    )
    dev.queue.write_texture(
        {"texture": tex},
        np.ascontiguousarray(rgba).tobytes(),
        {"bytes_per_row": w * 4 * rgba.itemsize, "rows_per_image": h},
        (w, h, 1),
    )
    return tex


#: UsdUVTexture wrap mode -> wgpu address mode ("black" is clamped, as Texture.sample does).
ADDRESS = {"repeat": "repeat", "mirror": "mirror-repeat", "clamp": "clamp-to-edge",
           "black": "clamp-to-edge"}  # fmt: skip


def render(dev, items, viewproj: np.ndarray, size) -> np.ndarray:
    """Rasterise [(vertices (3t, 12), model, ratio, textures [(h, w, c)], factors)] ->
    (H, W, 4) float32: normalized irradiance RGB, alpha 1 where a mesh covers the pixel.

    ``--model-view`` items carry a 6th element, a :class:`usdahd.preview.surface.Surface`, and
    vertices (3t, 18) (:func:`usdahd.preview.meshes.vertex_data` with the material's texcoord
    and tangent): the image is then albedo x irradiance at the normal-mapped normal.
    Items of a transmissive material carry a 7th, a :class:`usdahd.preview.cutout.Cutout`
    (the 6th None without --model-view), and 2 more floats per vertex (its texcoord): their
    fragments are discarded by the tracer's opacity rule (alpha cut-outs)."""
    import wgpu

    w, h = size
    color = dev.create_texture(
        size=(w, h, 1),
        format=wgpu.TextureFormat.rgba32float,
        usage=wgpu.TextureUsage.RENDER_ATTACHMENT | wgpu.TextureUsage.COPY_SRC,
    )
    depth = dev.create_texture(
        size=(w, h, 1),
        format=wgpu.TextureFormat.depth32float,
        usage=wgpu.TextureUsage.RENDER_ATTACHMENT,
    )
    sampler = dev.create_sampler(
        mag_filter="linear", min_filter="linear", address_mode_u="clamp-to-edge",
        address_mode_v="clamp-to-edge",
    )  # fmt: skip
    attrs = [
        {"format": wgpu.VertexFormat.float32x3, "offset": 0, "shader_location": 0},
        {"format": wgpu.VertexFormat.float32x2, "offset": 12, "shader_location": 1},
        {"format": wgpu.VertexFormat.float32x3, "offset": 20, "shader_location": 2},
        {"format": wgpu.VertexFormat.float32x4, "offset": 32, "shader_location": 3},
    ]
    mv_attrs = attrs + [
        {"format": wgpu.VertexFormat.float32x2, "offset": 48, "shader_location": 4},
        {"format": wgpu.VertexFormat.float32x4, "offset": 56, "shader_location": 5},
    ]
    pipelines = {}
    draws = []
    for verts, model, ratio, textures, factors, *rest in items:
        surf = rest[0] if rest else None
        cut = rest[1] if len(rest) > 1 else None
        key = (model, ratio, len(textures), surf is not None, cut is not None)
        if key not in pipelines:
            stride = 72 if surf is not None else 48
            vattrs = mv_attrs if surf is not None else attrs
            if cut is not None:
                vattrs = vattrs + [
                    {"format": wgpu.VertexFormat.float32x2, "offset": stride, "shader_location": 6}
                ]
                stride += 8
            # key[3], key[4]: model_view, cutout
            module = dev.create_shader_module(code=shader_source(*key))
            pipelines[key] = dev.create_render_pipeline(
                layout="auto",
                vertex={
                    "module": module,
                    "entry_point": "vs",
                    "buffers": [
                        {
                            "array_stride": stride,
                            "step_mode": "vertex",
                            "attributes": vattrs,
                        }
                    ],
                },
                primitive={"topology": "triangle-list", "front_face": "ccw", "cull_mode": "back"},
                depth_stencil={
                    "format": wgpu.TextureFormat.depth32float,
                    "depth_write_enabled": True,
                    "depth_compare": "less",
                },
                fragment={
                    "module": module,
                    "entry_point": "fs",
                    "targets": [{"format": wgpu.TextureFormat.rgba32float}],
                },
            )
        pipe = pipelines[key]
        n_uni = 24 + (4 if surf is not None else 0)
        uni = np.zeros(n_uni + (4 if cut is not None else 0), np.float32)
        uni[:16] = viewproj.T.reshape(-1)  # WGSL matrices are column-major
        uni[16:22] = [factors.get(f, 1.0) for f in FACTORS]
        if surf is not None:
            uni[24:27] = surf.albedo
        if cut is not None:
            uni[n_uni : n_uni + 4] = cut.uniform()
        ubuf = dev.create_buffer_with_data(data=uni.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        vbuf = dev.create_buffer_with_data(
            data=np.ascontiguousarray(verts).tobytes(), usage=wgpu.BufferUsage.VERTEX
        )
        entries = [
            {"binding": 0, "resource": {"buffer": ubuf}},
            {"binding": 1, "resource": sampler},
        ]
        entries += [
            {"binding": 2 + j, "resource": upload_texture(dev, t).create_view()}
            for j, t in enumerate(textures)
        ]
        if surf is not None:
            white = np.ones((1, 1, 3), np.float32)
            flat = np.array([[[0.5, 0.5, 1.0]]], np.float32)
            albedo = white if surf.albedo_tex is None else surf.albedo_tex
            normal = flat if surf.normal_tex is None else surf.normal_tex
            samplers = [
                dev.create_sampler(
                    mag_filter="linear",
                    min_filter="linear",
                    address_mode_u=ADDRESS[w[0]],
                    address_mode_v=ADDRESS[w[1]],
                )  # fmt: skip
                for w in (surf.albedo_wrap, surf.normal_wrap)
            ]
            b = 2 + len(textures)
            entries += [
                {"binding": b, "resource": upload_texture(dev, albedo).create_view()},
                {"binding": b + 1, "resource": upload_texture(dev, normal).create_view()},
                {"binding": b + 2, "resource": samplers[0]},
                {"binding": b + 3, "resource": samplers[1]},
            ]
        if cut is not None:
            b = 2 + len(textures) + (4 if surf is not None else 0)
            opacity = np.ones((1, 1, 1), np.float32) if cut.texture is None else cut.texture
            entries += [
                {"binding": b, "resource": upload_texture(dev, opacity).create_view()},
                {"binding": b + 1, "resource": dev.create_sampler(
                    mag_filter="linear", min_filter="linear", address_mode_u=ADDRESS[cut.wrap[0]],
                    address_mode_v=ADDRESS[cut.wrap[1]])},
            ]  # fmt: skip
        group = dev.create_bind_group(layout=pipe.get_bind_group_layout(0), entries=entries)
        draws.append((pipe, group, vbuf, len(verts)))
    enc = dev.create_command_encoder()
    rp = enc.begin_render_pass(
        color_attachments=[
            {
                "view": color.create_view(),
                "clear_value": (0.0, 0.0, 0.0, 0.0),
                "load_op": "clear",
                "store_op": "store",
            }
        ],
        depth_stencil_attachment={
            "view": depth.create_view(),
            "depth_clear_value": 1.0,
            "depth_load_op": "clear",
            "depth_store_op": "store",
        },
    )
    for pipe, group, vbuf, n in draws:
        rp.set_pipeline(pipe)
        rp.set_bind_group(0, group)
        rp.set_vertex_buffer(0, vbuf)
        rp.draw(n)
    rp.end()
    dev.queue.submit([enc.finish()])
    data = dev.queue.read_texture(
        {"texture": color}, {"bytes_per_row": w * 16, "rows_per_image": h}, (w, h, 1)
    )
    return np.frombuffer(data, np.float32).reshape(h, w, 4).copy()
