"""The reference shader decoders (usdahd/shaders/) run on a real Vulkan implementation and match
the Python decoders (issue 14).

Every model and ratio variant: real baked textures (a small bake of the Cornell box, refitted per
model, 0 rays after the first) are uploaded as GPU textures in their stored formats (EXR half as
rgba16float, PNG as rgba8unorm), sampled by a compute shader at the texel centres of the lightmap
UVs, decoded and evaluated at random upper-hemisphere normals (with and without the self-bounce
albedo), and compared with ``usdahd.models`` ``decode`` + ``evaluate``. Each shader runs in each
language through a real compiler: WGSL and GLSL through wgpu (naga), GLSL and HLSL through
glslang (``glslangValidator -V``, ``-D`` for HLSL) to SPIR-V, run through wgpu as well. The device
is Mesa's lavapipe on the CPU here (a GPU adapter when present); ``.ci/run`` installs it.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

import usdahd
from usdahd import cli, images, models, shaders
from usdahd.errors import UsageError
from usdahd.preview.gpu import upload_texture
from usdahd.usd.schema import NO_ATLAS

ROOT = Path(__file__).resolve().parents[2]
INSTALL_HINT = (
    "the shader tests need a Vulkan implementation, wgpu and glslang: "
    "apt-get install mesa-vulkan-drivers libvulkan1 glslang-tools; pip install wgpu "
    "(.ci/run does both)"
)
#: float32 shaders against the float64-then-float32 Python decoders: relative tolerance, and an
#: absolute floor relative to the largest magnitude of the terms summed (cancellation in hlsh).
RTOL = 1e-5
ATOL_OF_TERMS = 16 * 2.0**-24
LANGUAGES = ("wgsl", "glsl", "glsl-glslang", "hlsl-glslang")
VARIANTS = [(m, r) for m in models.REGISTRY for r in models.get(m).RATIOS]
WORKGROUP = 64
#: decode-factor buffer order (the ahdLightmap:baked:*Scale names the glue declares).
FACTORS = (
    "izScale",
    "ambientScale",
    "directionalScale",
    "coefficientsScale",
    "l0Scale",
    "ratioScale",
)


# ---------------------------------------------------------------------------------------------
# Which shader functions each variant calls, and the matching Python parameters.


def _spec(model: str, ratio: str):
    """(struct type, decode call, fields, evaluate function) of a variant (usdahd.shaders)."""
    return shaders.calls(model, ratio)


def _reference_fields(model: str, params: dict) -> np.ndarray:
    """Python decode params -> (n, fields, 3) float64 in the order of :func:`_spec`."""
    if model in ("ahd", "hhd", "hlsh"):
        wa = np.broadcast_to(params["ambient_ratio"], params["iz"].shape)
        parts = [params["iz"], params["direction"], wa]
    elif model == "ahd_classic":
        parts = [params["ambient"], params["direction"], params["directional"]]
    elif model == "hemisphere":
        parts = [params["ambient"]]
    else:
        c = params["coefficients"]
        parts = [c[:, k, :] for k in range(c.shape[1])]
    return np.stack([np.asarray(p, np.float64) for p in parts], axis=1)


# ---------------------------------------------------------------------------------------------
# Kernel glue per language: bindings, sampling, the decode/evaluate calls, the output writes.

_WGSL = """
@group(0) @binding(0) var<storage, read> inp: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> outp: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> fac: array<f32>;
@group(0) @binding(3) var samp: sampler;
{textures}
{library}
@compute @workgroup_size({wg})
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {{
    let i = gid.x;
    let uv = usdahd_page_texcoord(inp[3u * i].xy, vec4<f32>(fac[8], fac[9], fac[10], fac[11]));
    let n = inp[3u * i + 1u].xyz;
    let albedo = inp[3u * i + 2u].xyz;
{factors}
{samples}
    let p = {decode};
{writes}
    let e = {evaluate}(p, n);
    let ez = {iz_wgsl};
    outp[{k} * i + {f}u] = vec4<f32>(e, 0.0);
    outp[{k} * i + {f}u + 1u] = vec4<f32>(e + usdahd_self_bounce(ez, n, albedo), 0.0);
}}
"""

_GLSL = """#version 450
layout(local_size_x = {wg}) in;
layout(std430, set = 0, binding = 0) readonly buffer Inp {{ vec4 inp[]; }};
layout(std430, set = 0, binding = 1) buffer Outp {{ vec4 outp[]; }};
layout(std430, set = 0, binding = 2) readonly buffer Fac {{ float fac[]; }};
layout(set = 0, binding = 3) uniform sampler samp;
{textures}
{library}
void main() {{
    uint i = gl_GlobalInvocationID.x;
    vec2 uv = usdahd_page_texcoord(inp[3u * i].xy, vec4(fac[8], fac[9], fac[10], fac[11]));
    vec3 n = inp[3u * i + 1u].xyz;
    vec3 albedo = inp[3u * i + 2u].xyz;
{factors}
{samples}
    {struct} p = {decode};
{writes}
    vec3 e = {evaluate}(p, n);
    vec3 ez = {iz_glsl};
    outp[{k} * i + {f}u] = vec4(e, 0.0);
    outp[{k} * i + {f}u + 1u] = vec4(e + usdahd_self_bounce(ez, n, albedo), 0.0);
}}
"""

_HLSL = """
[[vk::binding(0, 0)]] StructuredBuffer<float4> inp;
[[vk::binding(1, 0)]] RWStructuredBuffer<float4> outp;
[[vk::binding(2, 0)]] StructuredBuffer<float> fac;
[[vk::binding(3, 0)]] SamplerState samp;
{textures}
{library}
[numthreads({wg}, 1, 1)]
void main(uint3 gid : SV_DispatchThreadID) {{
    uint i = gid.x;
    float2 uv = usdahd_page_texcoord(inp[3u * i].xy, float4(fac[8], fac[9], fac[10], fac[11]));
    float3 n = inp[3u * i + 1u].xyz;
    float3 albedo = inp[3u * i + 2u].xyz;
{factors}
{samples}
    {struct} p = {decode};
{writes}
    float3 e = {evaluate}(p, n);
    float3 ez = {iz_hlsl};
    outp[{k} * i + {f}u] = float4(e, 0.0);
    outp[{k} * i + {f}u + 1u] = float4(e + usdahd_self_bounce(ez, n, albedo), 0.0);
}}
"""


def kernel(language: str, model: str, ratio: str, n_textures: int) -> str:
    """Compute-shader source (``wgsl``, ``glsl`` or ``hlsl``) running the variant's decode and
    evaluate per sample. Per sample i: inp[3i] = lightmap st, inp[3i+1] = normal, inp[3i+2] =
    albedo; out[k i + j] = field j, then I(n), then I(n) + self-bounce."""
    struct, call, fields, evaluate = _spec(model, ratio)
    k = len(fields) + 2
    fmt = dict(
        wg=WORKGROUP, library=shaders.source(language, model), decode=call, struct=struct,
        evaluate=evaluate, k=f"{k}u", f=len(fields),
    )  # fmt: skip
    # I_z of the self-bounce: the stored I_z for IrradZ models, else the model's I(z)
    irradz = model in ("ahd", "hhd", "hlsh")
    for lang, vec3 in (("wgsl", "vec3<f32>"), ("glsl", "vec3"), ("hlsl", "float3")):
        fmt[f"iz_{lang}"] = "p.iz" if irradz else f"{evaluate}(p, {vec3}(0.0, 0.0, 1.0))"
    if language == "wgsl":
        fmt["textures"] = "\n".join(
            f"@group(0) @binding({4 + j}) var tex{j}: texture_2d<f32>;" for j in range(n_textures)
        )
        fmt["factors"] = "\n".join(f"    let {f} = fac[{j}];" for j, f in enumerate(FACTORS))
        fmt["samples"] = "\n".join(
            f"    let s{j} = textureSampleLevel(tex{j}, samp, uv, 0.0);" for j in range(n_textures)
        )
        vec4 = "vec4<f32>"
        template = _WGSL
    elif language == "glsl":
        fmt["textures"] = "\n".join(
            f"layout(set = 0, binding = {4 + j}) uniform texture2D tex{j};"
            for j in range(n_textures)
        )
        fmt["factors"] = "\n".join(f"    float {f} = fac[{j}];" for j, f in enumerate(FACTORS))
        fmt["samples"] = "\n".join(
            f"    vec4 s{j} = textureLod(sampler2D(tex{j}, samp), uv, 0.0);"
            for j in range(n_textures)
        )
        vec4 = "vec4"
        template = _GLSL
    else:
        fmt["textures"] = "\n".join(
            f"[[vk::binding({4 + j}, 0)]] Texture2D<float4> tex{j};" for j in range(n_textures)
        )
        fmt["factors"] = "\n".join(f"    float {f} = fac[{j}];" for j, f in enumerate(FACTORS))
        fmt["samples"] = "\n".join(
            f"    float4 s{j} = tex{j}.SampleLevel(samp, uv, 0.0);" for j in range(n_textures)
        )
        vec4 = "float4"
        template = _HLSL
    fmt["writes"] = "\n".join(
        f"    outp[{k}u * i + {j}u] = {vec4}(p.{name}, 0.0);" for j, name in enumerate(fields)
    )
    return template.format(**fmt)


def glslang(source: str, language: str, tmp: Path) -> bytes:
    """SPIR-V of a compute shader compiled by glslangValidator (HLSL with ``-D``)."""
    exe = shutil.which("glslangValidator")
    if exe is None:
        pytest.fail(f"glslangValidator not found; {INSTALL_HINT}")
    ext = {"glsl": "comp", "hlsl": "hlsl"}[language]
    src = tmp / f"kernel.{ext}"
    src.write_text(source, encoding="utf-8")
    out = tmp / "kernel.spv"
    cmd = [exe, "-V", "-S", "comp", "-e", "main", "-o", str(out), str(src)]
    if language == "hlsl":
        cmd.insert(1, "-D")
    run = subprocess.run(cmd, capture_output=True, text=True)
    assert run.returncode == 0, f"glslang rejected the {language} shader:\n{run.stdout}{run.stderr}"
    return out.read_bytes()


# ---------------------------------------------------------------------------------------------
# The device and the baked textures.


@pytest.fixture(scope="module")
def device():
    """One wgpu device for the module (lavapipe on the CPU here)."""
    try:
        import wgpu
    except ImportError:
        pytest.fail(f"wgpu is not installed; {INSTALL_HINT}")
    adapter = wgpu.gpu.request_adapter_sync(power_preference="high-performance")
    if adapter is None:
        pytest.fail(f"no Vulkan adapter; {INSTALL_HINT}")
    return adapter.request_device_sync()


class Bakes:
    """The Cornell box baked once (16 x 16 texels per mesh, 16 samples, 1 bounce, atlas pages:
    the default), then refitted per variant from the SH sidecar: {(model, ratio): [Record]}."""

    def __init__(self, tmp: Path):
        self.stage = tmp / "cornell_box.usda"
        shutil.copy(ROOT / "samples" / "cornell_box.usda", self.stage)
        self.layer = tmp / "cornell_box.lightmaps.usda"
        self.cache: dict = {}
        self.current = None  # the (model, ratio) the layer holds now

    def __call__(self, model: str, ratio: str):
        key = (model, ratio)
        if key not in self.cache or self.current != key:
            argv = ["bake", str(self.stage), "--resolution", "16", "--samples", "16"]
            argv += ["--bounces", "1", "--model", model, "--ratio", ratio, "--quiet"]
            assert cli.main(argv) == 0
            self.current = key
            self.cache[key] = self._read(model, ratio)
        return self.cache[key]

    def _read(self, model, ratio):
        from pxr import Sdf, Usd

        from usdahd.usd import schema

        held = Sdf.Layer.Find(str(self.layer))
        if held is not None:  # a stage still holds the layer: read the refit from disk
            held.Reload()
        stage = Usd.Stage.Open(str(self.layer))
        out = []
        for prim in schema.prims_with_api(stage):
            res = schema.read_results(prim)
            if res is None:
                continue
            assert (res.model, res.ratio) == (model, ratio)
            pages = {
                t.role: images.read(res.textures[t.role], channels=t.channels).pixels
                for t in models.get(model).layout(ratio)
            }
            out.append(Record(str(prim.GetPath()), pages, dict(res.factors), res))
        assert out, "the bake wrote no prim"
        return out


class Record:
    """One baked prim: its page textures (role -> (H, W, c) stored pixels, the whole page),
    decode factors and BakeResults (resolution, scale_offset)."""

    def __init__(self, prim, pages, factors, results):
        self.prim, self.pages, self.factors, self.results = prim, pages, factors, results

    def rect(self):
        page = next(iter(self.pages.values()))
        return schema_rect(self.results, (page.shape[1], page.shape[0]))


def schema_rect(results, page):
    from usdahd.usd import schema

    return schema.record_rect(results, page)


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    return Bakes(tmp_path_factory.mktemp("shaders_bake"))


# ---------------------------------------------------------------------------------------------
# Running a kernel.


def run_kernel(
    device, module, textures, inputs: np.ndarray, factors: dict, k: int, scale_offset=NO_ATLAS
) -> np.ndarray:
    """Dispatch ``main`` of a compiled module; inputs (n, 3, 4) float32 (n a multiple of the
    workgroup); ``scale_offset`` the record's ahdLightmap:atlas:scaleOffset in its page (the
    textures). returns (n, k, 3) float32."""
    import wgpu

    n = inputs.shape[0]
    assert n % WORKGROUP == 0
    # an explicit layout: binding 2 stays when a kernel reads no factor (naga drops it, glslang
    # keeps it, so "auto" layouts would differ between the languages)
    stage = wgpu.ShaderStage.COMPUTE
    layout_entries = [
        {"binding": b, "visibility": stage, "buffer": {"type": kind}}
        for b, kind in ((0, "read-only-storage"), (1, "storage"), (2, "read-only-storage"))
    ]
    layout_entries.append({"binding": 3, "visibility": stage, "sampler": {"type": "filtering"}})
    layout_entries += [
        {"binding": 4 + j, "visibility": stage, "texture": {"sample_type": "float"}}
        for j in range(len(textures))
    ]
    bgl = device.create_bind_group_layout(entries=layout_entries)
    pipe = device.create_compute_pipeline(
        layout=device.create_pipeline_layout(bind_group_layouts=[bgl]),
        compute={"module": module, "entry_point": "main"},
    )
    storage = wgpu.BufferUsage.STORAGE
    inb = device.create_buffer_with_data(data=inputs.astype(np.float32).tobytes(), usage=storage)
    outb = device.create_buffer(size=n * k * 16, usage=storage | wgpu.BufferUsage.COPY_SRC)
    sampler = device.create_sampler(mag_filter="linear", min_filter="linear")
    fac = [factors.get(f, 1.0) for f in FACTORS] + [0.0, 0.0] + [float(v) for v in scale_offset]
    fac = np.array(fac, np.float32)
    facb = device.create_buffer_with_data(data=fac.tobytes(), usage=storage)
    entries = [
        {"binding": 0, "resource": {"buffer": inb}},
        {"binding": 1, "resource": {"buffer": outb}},
        {"binding": 2, "resource": {"buffer": facb}},
        {"binding": 3, "resource": sampler},
    ]
    entries += [{"binding": 4 + j, "resource": t.create_view()} for j, t in enumerate(textures)]
    group = device.create_bind_group(layout=pipe.get_bind_group_layout(0), entries=entries)
    enc = device.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipe)
    cp.set_bind_group(0, group)
    cp.dispatch_workgroups(n // WORKGROUP)
    cp.end()
    device.queue.submit([enc.finish()])
    out = np.frombuffer(device.queue.read_buffer(outb), np.float32).reshape(n, k, 4)
    return out[..., :3]


def compile_module(device, language: str, model: str, ratio: str, n_tex: int, tmp: Path):
    """A wgpu shader module of the variant's kernel, through the language's compiler."""
    lang = language.split("-")[0]
    src = kernel(lang, model, ratio, n_tex)
    if language.endswith("-glslang"):
        return device.create_shader_module(label="compute", code=glslang(src, lang, tmp))
    return device.create_shader_module(label="compute", code=src)


def upper_normals(rng, n: int) -> np.ndarray:
    """(n, 3) float64 unit normals uniform on the upper hemisphere, with z, a grazing and a
    diagonal normal first."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[0] = (0.0, 0.0, 1.0)
    v[1] = (1.0, 0.0, 0.0)
    v[2] = np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)
    return v


def _inputs(rng, res):
    """Every texel of a (w, h) texture at its centre, padded to the workgroup size: returns
    (inputs (n, 3, 4) float32, xy (n, 2) int)."""
    w, h = res
    ys, xs = np.divmod(np.arange(w * h), w)
    pad = (-len(xs)) % WORKGROUP
    xs = np.concatenate([xs, xs[:pad]])
    ys = np.concatenate([ys, ys[:pad]])
    n = len(xs)
    inp = np.zeros((n, 3, 4), np.float32)
    inp[:, 0, 0] = (xs + 0.5) / w
    inp[:, 0, 1] = 1.0 - (ys + 0.5) / h
    inp[:, 1, :3] = upper_normals(rng, n)
    inp[:, 2, :3] = rng.uniform(0.0, 1.0, size=(n, 3))
    return inp, np.stack([xs, ys], axis=1)


#: Codes and values written into the top row of every texture (the extremes a real bake rarely
#: has: direction corners at 2/254 where d_z = 1/126, the clamp at 1 and 255, half extremes).
EDGE_CODES = np.array([0, 1, 2, 64, 127, 128, 129, 200, 253, 254, 255], np.uint8)
EDGE_HALVES = np.array([0.0, 6.1e-5, 1e-3, 0.5, 1.0, 7.5, 1000.0, 65504.0], np.float16)


def with_edge_texels(channels: dict, rng) -> dict:
    """A copy of the stored channels with the top row replaced by random edge codes/values."""
    out = {}
    for role, px in channels.items():
        px = px.copy()
        pool = EDGE_CODES if px.dtype == np.uint8 else EDGE_HALVES
        px[0] = rng.choice(pool, size=px[0].shape)
        out[role] = px
    return out


def _close(got, ref, scale, what):
    """|got - ref| <= RTOL |ref| + ATOL_OF_TERMS * scale, elementwise; scale broadcasts."""
    err = np.abs(got - ref)
    tol = RTOL * np.abs(ref) + ATOL_OF_TERMS * scale
    bad = err > tol
    if bad.any():
        i = np.argwhere(bad)[0]
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} values differ; first at {tuple(i)}: "
            f"shader {got[tuple(i)]!r}, Python {ref[tuple(i)]!r}, max |err| {err.max():.3g}"
        )


def _term_scale(model: str, ratio: str, fields, factors: dict, normals) -> np.ndarray:
    """(n, 1) scale of the float32 rounding error an evaluation can have (the tolerance is
    about 16 float32 ulp of it): the magnitude of the terms it sums, times their condition.

    IrradZ: C_d = I_z (1 - w_a) / d_z with d_z = 1 - |p_x| - |p_y| cancelling near the horizon
    (relative error ~ ulp / d_z), and w_a from a UNORM8 sample q/255 rounded to float32 (255 t
    off by 255 ulp, w_a by 2 ulp x ratioScale), which moves C_a and C_d against each other by
    I_z / d_z. Non-linear L1: q^p with p = 1 + 2r amplifies the error of q by p."""
    if model in ("ahd", "hhd", "hlsh"):
        iz, d, wa = fields[:, 0], fields[:, 1], fields[:, 2]
        dz = np.maximum(d[:, 2:3], 1.0 / 127.0)
        rs = factors.get("ratioScale", 1.0) if model == "hlsh" else 1.0
        ca, cd = np.abs(iz * wa), np.abs(iz * (1.0 - wa) / dz)
        terms = ca + cd * (1.0 + 1.0 / dz) + np.abs(iz) * 2.0 * rs / dz
    elif model == "ahd_classic":
        dz = np.maximum(fields[:, 1, 2:3], 1.0 / 127.0)
        terms = np.abs(fields[:, 0]) + np.abs(fields[:, 2]) * (1.0 + 1.0 / dz)
    elif model == "sh_l1" and ratio == "nonlinear":
        from usdahd.models.sh_l1 import to_enlighten

        l0, l1 = to_enlighten(fields)
        l0 = np.abs(l0)
        mod = np.linalg.norm(l1, axis=-1)
        r = np.where(l0 > 0, mod / np.where(l0 > 0, l0, 1.0), 0.0)
        p = 1.0 + 2.0 * r
        a = (1.0 - r) / (1.0 + r)
        q = np.clip(
            0.5 + 0.5 * np.einsum("nk,nck->nc", normals, l1) / np.where(mod > 0, mod, 1), 0, 1
        )
        qp = np.power(q, p)
        qp1 = np.power(q, np.maximum(p - 1.0, 0.0))
        terms = l0 * (1.0 + np.abs(a) + np.abs(1.0 - a) * (1.0 + p) * (qp + p * qp1) * (1.0 + p))
    else:
        terms = np.abs(fields).sum(axis=1)
    return terms.max(axis=1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# Tests.


@pytest.mark.parametrize("language", LANGUAGES)
@pytest.mark.parametrize(("model", "ratio"), VARIANTS)
def test_shader_decode_and_evaluate_match_python(device, bakes, model, ratio, language, tmp_path):
    mod = models.get(model)
    rng = np.random.default_rng(zlib.crc32(f"{model}/{ratio}/{language}".encode()))
    prims = bakes(model, ratio)[:3]
    n_tex = len(mod.layout(ratio))
    module = compile_module(device, language, model, ratio, n_tex, tmp_path)
    _, _, names, _ = _spec(model, ratio)
    assert len({r.results.textures[mod.layout(ratio)[0].role] for r in prims}) < len(prims)
    for rec in prims:
        prim, factors, res = rec.prim, rec.factors, rec.results.resolution
        roles = [t.role for t in mod.layout(ratio)]
        # the whole page is uploaded; the record's own texels (its rectangle) get the edge
        # codes, and the Python reference reads that rectangle
        x0, y0, w, h = rec.rect()
        pages = with_edge_texels({r: p[y0:] for r, p in rec.pages.items()}, rng)
        pages = {r: np.concatenate([rec.pages[r][:y0], p]) for r, p in pages.items()}
        channels = {r: p[y0 : y0 + h, x0 : x0 + w] for r, p in pages.items()}
        textures = [upload_texture(device, pages[r]) for r in roles]
        inp, xy = _inputs(rng, res)
        so = rec.results.scale_offset
        # the bake's factors, then all doubled (exercises every scale's plumbing)
        for fac in (factors, {k: 2.0 * v for k, v in factors.items()}):
            got = run_kernel(device, module, textures, inp, fac, len(names) + 2, so)
            texels = {r: c[xy[:, 1], xy[:, 0]] for r, c in channels.items()}
            params = mod.decode(texels, ratio=ratio, factors=fac)
            ref = _reference_fields(model, params)
            normals = inp[:, 1, :3].astype(np.float64)
            albedo = inp[:, 2, :3].astype(np.float64)
            e = mod.evaluate(params, normals).astype(np.float64)
            eb = mod.evaluate(params, normals, albedo=albedo).astype(np.float64)
            what = f"{language} {model}/{ratio} {prim}"
            field_scale = np.abs(ref).max(axis=(1, 2))[:, None, None]
            _close(got[:, : len(names)], ref, field_scale, f"{what} decode ({', '.join(names)})")
            scale = _term_scale(model, ratio, ref, fac, normals)
            _close(got[:, -2], e, scale, f"{what} evaluate")
            z = np.broadcast_to([0.0, 0.0, 1.0], normals.shape)
            scale_b = scale + _term_scale(model, ratio, ref, fac, z)  # + albedo x I(z)'s error
            _close(got[:, -1], eb, scale_b, f"{what} +albedo")


# ---------------------------------------------------------------------------------------------
# The common functions: direction codes, texture coordinates, tangent frame, normal maps.

_COMMON_BODY = {
    "wgsl": """
    let a = inp[4u * i];
    let f = usdahd_tangent_frame(inp[4u * i + 1u].xyz, inp[4u * i + 2u]);
    let m = usdahd_apply_normal_map(inp[4u * i + 3u].xyz, f);
    outp[7u * i] = vec4<f32>(usdahd_hemioct_decode(a.xy), 0.0);
    outp[7u * i + 1u] = vec4<f32>(f.t, 0.0);
    outp[7u * i + 2u] = vec4<f32>(f.b, 0.0);
    outp[7u * i + 3u] = vec4<f32>(f.n, 0.0);
    outp[7u * i + 4u] = vec4<f32>(usdahd_lightmap_texcoord(a.zw), 0.0, 0.0);
    outp[7u * i + 5u] = vec4<f32>(m, 0.0);
    outp[7u * i + 6u] = vec4<f32>(usdahd_to_tangent(f, m), 0.0);""",
    "glsl": """
    vec4 a = inp[4u * i];
    UsdahdFrame f = usdahd_tangent_frame(inp[4u * i + 1u].xyz, inp[4u * i + 2u]);
    vec3 m = usdahd_apply_normal_map(inp[4u * i + 3u].xyz, f);
    outp[7u * i] = vec4(usdahd_hemioct_decode(a.xy), 0.0);
    outp[7u * i + 1u] = vec4(f.t, 0.0);
    outp[7u * i + 2u] = vec4(f.b, 0.0);
    outp[7u * i + 3u] = vec4(f.n, 0.0);
    outp[7u * i + 4u] = vec4(usdahd_lightmap_texcoord(a.zw), 0.0, 0.0);
    outp[7u * i + 5u] = vec4(m, 0.0);
    outp[7u * i + 6u] = vec4(usdahd_to_tangent(f, m), 0.0);""",
}
_COMMON_BODY["hlsl"] = (
    _COMMON_BODY["glsl"].replace("vec4(", "float4(").replace("vec4 ", "float4 ")
    .replace("vec3 ", "float3 ")
)  # fmt: skip

_COMMON_KERNEL = {
    "wgsl": """
@group(0) @binding(0) var<storage, read> inp: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> outp: array<vec4<f32>>;
{library}
@compute @workgroup_size({wg})
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {{
    let i = gid.x;{body}
}}
""",
    "glsl": """#version 450
layout(local_size_x = {wg}) in;
layout(std430, set = 0, binding = 0) readonly buffer Inp {{ vec4 inp[]; }};
layout(std430, set = 0, binding = 1) buffer Outp {{ vec4 outp[]; }};
{library}
void main() {{
    uint i = gl_GlobalInvocationID.x;{body}
}}
""",
    "hlsl": """
[[vk::binding(0, 0)]] StructuredBuffer<float4> inp;
[[vk::binding(1, 0)]] RWStructuredBuffer<float4> outp;
{library}
[numthreads({wg}, 1, 1)]
void main(uint3 gid : SV_DispatchThreadID) {{
    uint i = gid.x;{body}
}}
""",
}


def run_buffers(device, module, inputs: np.ndarray, k: int) -> np.ndarray:
    """Dispatch a kernel with bindings 0 (inputs (n, j, 4) float32) and 1 (out (n, k, 4))."""
    import wgpu

    n = inputs.shape[0]
    pipe = device.create_compute_pipeline(
        layout="auto", compute={"module": module, "entry_point": "main"}
    )
    storage = wgpu.BufferUsage.STORAGE
    inb = device.create_buffer_with_data(data=inputs.astype(np.float32).tobytes(), usage=storage)
    outb = device.create_buffer(size=n * k * 16, usage=storage | wgpu.BufferUsage.COPY_SRC)
    group = device.create_bind_group(
        layout=pipe.get_bind_group_layout(0),
        entries=[
            {"binding": 0, "resource": {"buffer": inb}},
            {"binding": 1, "resource": {"buffer": outb}},
        ],
    )
    enc = device.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipe)
    cp.set_bind_group(0, group)
    cp.dispatch_workgroups(n // WORKGROUP)
    cp.end()
    device.queue.submit([enc.finish()])
    return np.frombuffer(device.queue.read_buffer(outb), np.float32).reshape(n, k, 4)


def _mirrored_sphere():
    """A UV sphere whose lightmap UVs mirror at y = 0 (handedness sign -1 on half of it)."""
    import trimesh

    from usdahd.bake import texels as tx

    m = trimesh.creation.uv_sphere(radius=1.0, count=[12, 12])
    p = m.vertices
    uv = np.stack(
        [
            np.abs(np.arctan2(p[:, 1], p[:, 0])) / np.pi,
            0.5 + np.arcsin(np.clip(p[:, 2], -1, 1)) / np.pi,
        ],
        axis=1,
    )
    return tx.mesh_from_arrays(p, m.faces, uv=uv, normals=m.vertex_normals)


@pytest.mark.parametrize("language", LANGUAGES)
def test_common_functions_match_the_baker(device, language, tmp_path):
    """Every hemi-octahedral code pair (1..255)^2 decodes as usdahd.numerics.encoding does;
    the tangent frame rebuilt from interpolated normal + tangent + sign equals the frame the baker
    traced each texel of a mirrored sphere with (usdahd.bake.texels.rasterize); normal-map
    application and the change into the frame follow docs/schema.md."""
    from usdahd.bake import texels as tx
    from usdahd.numerics import encoding

    lang = language.split("-")[0]
    src = _COMMON_KERNEL[lang].format(
        wg=WORKGROUP, library=shaders.path(lang, "common").read_text(), body=_COMMON_BODY[lang]
    )
    if language.endswith("-glslang"):
        module = device.create_shader_module(label="compute", code=glslang(src, lang, tmp_path))
    else:
        module = device.create_shader_module(label="compute", code=src)

    q = np.stack(np.meshgrid(np.arange(1, 256), np.arange(1, 256), indexing="ij"), -1).reshape(
        -1, 2
    )
    mesh = _mirrored_sphere()
    texels = tx.rasterize(mesh, (48, 48))
    lam = tx.barycentrics(texels, mesh)
    tri = mesh.triangles[texels.triangle]
    nrm = np.asarray(mesh.normals, np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)
    tangent, sign = tx.tangent_frames(mesh)
    n_i = np.einsum("nc,nci->ni", lam, nrm[texels.triangle])
    t_i = np.einsum("nc,nci->ni", lam, tangent[texels.triangle])
    s_i = sign[texels.triangle]
    assert tri.shape[0] == len(n_i) and (s_i < 0).any() and (s_i > 0).any()

    n = len(q) + (-len(q)) % WORKGROUP
    rng = np.random.default_rng(7)
    inp = np.zeros((n, 4, 4), np.float32)
    inp[: len(q), 0, :2] = q.astype(np.float32) / np.float32(255.0)  # what UNORM8 sampling gives
    inp[:, 0, 2:] = rng.uniform(0, 1, (n, 2))
    reps = -(-n // len(n_i))
    inp[:, 1, :3] = np.tile(n_i, (reps, 1))[:n]
    inp[:, 2, :3] = np.tile(t_i, (reps, 1))[:n]
    inp[:, 2, 3] = np.tile(s_i, reps)[:n]
    inp[:, 3, :3] = rng.integers(0, 256, (n, 3)) / 255.0
    inp[:, 3, 2] = np.maximum(inp[:, 3, 2], 0.6)  # a normal map's z points out of the surface
    out = run_buffers(device, module, inp, 7)[..., :3].astype(np.float64)

    d = encoding.decode_direction_u8(q.astype(np.uint8)).astype(np.float64)
    np.testing.assert_allclose(out[: len(q), 0], d, rtol=0, atol=4e-7)  # a few float32 ulp
    clamped = np.all((q >= 2) & (q <= 254), axis=1)  # the codes the encoder writes
    assert np.all(out[: len(q)][clamped, 0, 2] >= 1.0 / 127.0 - 1e-7)

    frame = np.tile(texels.frame.astype(np.float64), (reps, 1, 1))[:n]
    keep = (
        np.linalg.norm(
            inp[:, 2, :3]
            - inp[:, 1, :3] * np.sum(inp[:, 1, :3] * inp[:, 2, :3], -1, keepdims=True),
            axis=-1,
        )
        > 1e-3
    )
    assert keep.mean() > 0.95
    np.testing.assert_allclose(out[keep, 1:4], frame[keep], rtol=0, atol=2e-6)

    st = inp[:, 0, 2:].astype(np.float64)
    np.testing.assert_allclose(out[:, 4, :2], np.stack([st[:, 0], 1.0 - st[:, 1]], 1), atol=1e-7)

    mm = 2.0 * inp[:, 3, :3].astype(np.float64) - 1.0
    world = np.einsum("nk,nkj->nj", mm, out[:, 1:4])
    world /= np.linalg.norm(world, axis=-1, keepdims=True)
    np.testing.assert_allclose(out[:, 5], world, atol=2e-6)
    # back in the frame: the map's own direction (material frame = lightmap frame here)
    np.testing.assert_allclose(
        out[:, 6], mm / np.linalg.norm(mm, axis=-1, keepdims=True), atol=3e-6
    )


_PAGE_BODY = {
    "wgsl": """
    let a = inp[2u * i];
    outp[2u * i] = vec4<f32>(usdahd_page_texcoord(a.xy, inp[2u * i + 1u]), 0.0, 0.0);
    outp[2u * i + 1u] = vec4<f32>(
        usdahd_page_texcoord_array(a.xy, inp[2u * i + 1u], i32(a.z)), 0.0);""",
    "glsl": """
    vec4 a = inp[2u * i];
    outp[2u * i] = vec4(usdahd_page_texcoord(a.xy, inp[2u * i + 1u]), 0.0, 0.0);
    outp[2u * i + 1u] = vec4(usdahd_page_texcoord_array(a.xy, inp[2u * i + 1u], int(a.z)), 0.0);""",
    "hlsl": """
    float4 a = inp[2u * i];
    outp[2u * i] = float4(usdahd_page_texcoord(a.xy, inp[2u * i + 1u]), 0.0, 0.0);
    outp[2u * i + 1u] = float4(
        usdahd_page_texcoord_array(a.xy, inp[2u * i + 1u], (int)a.z), 0.0);""",
}


@pytest.mark.parametrize("language", LANGUAGES)
def test_page_texcoord_puts_every_record_texel_at_its_page_texel(device, language, tmp_path):
    """usdahd_page_texcoord(st, scaleOffset) (and the texture-array variant with the page as
    layer) maps the centre of texel (x, y) of a record to the centre of page texel (x0 + x,
    y0 + y), the rectangle schema.record_rect gives for ahdLightmap:atlas:scaleOffset (the
    contract's pixel rule); (1, 1, 0, 0) is the record's own texture."""
    from usdahd.usd.schema import BakeResults, record_rect

    lang = language.split("-")[0]
    src = _COMMON_KERNEL[lang].format(
        wg=WORKGROUP, library=shaders.path(lang, "common").read_text(), body=_PAGE_BODY[lang]
    )
    if language.endswith("-glslang"):
        module = device.create_shader_module(label="compute", code=glslang(src, lang, tmp_path))
    else:
        module = device.create_shader_module(label="compute", code=src)
    rng = np.random.default_rng(11)
    cases = []  # (page (W, H), rect (x0, y0, w, h), page index)
    for _ in range(12):
        big_w, big_h = (int(2 ** rng.integers(5, 12)) for _ in range(2))
        w = 4 * int(rng.integers(1, big_w // 4 + 1))
        h = 4 * int(rng.integers(1, big_h // 4 + 1))
        x0 = 4 * int(rng.integers(0, (big_w - w) // 4 + 1))
        y0 = 4 * int(rng.integers(0, (big_h - h) // 4 + 1))
        cases.append(((big_w, big_h), (x0, y0, w, h), int(rng.integers(0, 8))))
    cases.append(((64, 32), (0, 0, 64, 32), 0))  # no atlas: the record is the page
    rows, want = [], []
    for (big_w, big_h), (x0, y0, w, h), page in cases:
        so = (w / big_w, h / big_h, x0 / big_w, 1.0 - (y0 + h) / big_h)
        if (w, h) == (big_w, big_h):
            so = NO_ATLAS
        res = BakeResults("hhd", "luminance", "golden", "st", (w, h), {})
        res.scale_offset, res.atlas = so, so != NO_ATLAS
        assert record_rect(res, (big_w, big_h)) == (x0, y0, w, h)
        xs = rng.integers(0, w, 40)
        ys = rng.integers(0, h, 40)
        st = np.stack([(xs + 0.5) / w, 1.0 - (ys + 0.5) / h], 1)
        for (u, v), x, y in zip(st, xs, ys):
            rows.append([[u, v, page, 0.0], list(so)])
            want.append([(x0 + x + 0.5) / big_w, (y0 + y + 0.5) / big_h, page])
    pad = (-len(rows)) % WORKGROUP
    rows += rows[:pad]
    want += want[:pad]
    out = run_buffers(device, module, np.asarray(rows, np.float32), 2).astype(np.float64)
    want = np.asarray(want, np.float64)
    scale = np.array([[c[0][0], c[0][1]] for c in cases], np.float64).max()
    np.testing.assert_allclose(out[:, 0, :2], want[:, :2], rtol=0, atol=0.01 / scale)
    np.testing.assert_allclose(out[:, 1, :3], want, rtol=0, atol=0.01 / scale)


# ---------------------------------------------------------------------------------------------
# --ahd-classic: the 2018 paper's Figure 2 through the sampler.

#: Figure 2's highlight tilt from the normal (60 degrees: d_z = 1/2) and the sample positions
#: between the two texel centres (multiples of 1/16: exact bilinear weights on any GPU).
FIG2_TILT = np.radians(60.0)
FIG2_T = np.arange(17) / 16.0


def _figure2(device, language, tmp_path, model, ratio, pixels):
    """Sample a 2 x 1 texture set at FIG2_T between its texel centres, decode + evaluate at the
    normal (0, 0, 1); returns (fields (17, k, 3), I_z (17, 3)) float64."""
    module = compile_module(device, language, model, ratio, len(pixels), tmp_path)
    k = len(_spec(model, ratio)[2]) + 2
    inp = np.zeros((WORKGROUP, 3, 4), np.float32)
    inp[:, 0, 0] = 0.25  # the left texel's centre
    inp[: len(FIG2_T), 0, 0] = 0.25 + 0.5 * FIG2_T
    inp[:, 0, 1] = 0.5
    inp[:, 1, 2] = 1.0  # the normal; albedo 0 (no self-bounce)
    got = run_kernel(device, module, [upload_texture(device, p) for p in pixels], inp, {}, k)
    got = got[: len(FIG2_T)].astype(np.float64)
    return got[:, : k - 2], got[:, k - 2]


@pytest.mark.parametrize("language", LANGUAGES)
def test_figure2_classic_interpolation_overshoots_and_irradz_is_linear(device, language, tmp_path):
    """2018 Fig. 2: the left texel has a unit directional light tilted 60 degrees to the left,
    the right one zero light tilted to the right, no ambient. Classic AHD textures (C_a, d, C_d)
    filtered by the sampler (``usdahd_ahd_classic_filtered``, d renormalised) overshoot the
    linear I_z between them, C_d(t) d_z'(t) with d_z' = d_z / |d(t)| > d_z; at the midpoint the
    directions cancel sideways, d' = z and I_z doubles (1/2 instead of 1/4). The IrradZ textures
    of the same two texels (I_z, d, w_a = 0) give exactly the linear I_z. The numpy twin of the
    Embree fallback (:mod:`usdahd.preview.classic` on :func:`raytrace.bilinear` samples) agrees."""
    from usdahd.numerics import encoding
    from usdahd.preview import classic, raytrace

    s, c = np.sin(FIG2_TILT), np.cos(FIG2_TILT)
    d = np.array([[[-s, 0.0, c], [s, 0.0, c]]])
    ca = np.zeros((1, 2, 3), np.float16)
    cd = np.array([[[1.0] * 3, [0.0] * 3]], np.float16)
    d16 = d.astype(np.float16)
    fields, e = _figure2(device, language, tmp_path, "ahd_classic", "filtered", [ca, d16, cd])

    t = FIG2_T[:, None]
    dl, dr = d16[0].astype(np.float64)
    dt = (1 - t) * dl + t * dr
    analytic = (1 - t) * dl[2] / np.linalg.norm(dt, axis=1, keepdims=True)  # C_d(t) d_z'(t)
    uv = np.stack([0.25 + 0.5 * FIG2_T, np.full(len(FIG2_T), 0.5)], -1)
    twin = classic.filtered(*(raytrace.bilinear(px, uv) for px in (ca, d16, cd)))
    z = np.broadcast_to([0.0, 0.0, 1.0], (len(FIG2_T), 3))
    numpy_e = classic.evaluate("filtered", twin, z)
    np.testing.assert_allclose(numpy_e, np.repeat(analytic, 3, 1), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(e, numpy_e, rtol=0, atol=2e-3)  # float16 d, GPU filter weights
    np.testing.assert_allclose(fields[:, 1], twin["direction"], rtol=0, atol=2e-3)
    linear = (1 - t[:, 0]) * numpy_e[0, 0]  # the left texel's I_z (float16 d renormalised)
    assert abs(e[0, 0] - numpy_e[0, 0]) < 1e-6 and abs(e[-1, 0]) < 1e-6  # exact at the centres
    over = e[:, 0] / np.maximum(linear, 1e-30)
    assert np.all(over[1:-1] > 1.05), over  # 1.10 (t = 15/16) to 2.0 (t = 1/2)
    np.testing.assert_allclose(e[8], 0.5, atol=2e-3)  # midpoint: d' = z, I_z = C_d = 1/2

    # IrradZ: I_z (half), direction codes + w_a = 0 in the direction's third byte (luminance)
    iz = np.array([[[c] * 3, [0.0] * 3]], np.float16)
    codes = encoding.encode_direction_u8(d)
    direction = np.concatenate([codes, np.zeros((1, 2, 1), np.uint8)], -1)
    _, e_iz = _figure2(device, language, tmp_path, "ahd", "luminance", [iz, direction])
    lin16 = (1 - t) * float(iz[0, 0, 0])
    np.testing.assert_allclose(e_iz, np.repeat(lin16, 3, 1), rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# The shader files as shipped.


def test_every_model_has_shaders_in_every_language_and_the_wheel_ships_them():
    import fnmatch
    import tomllib

    assert set(shaders.MODEL_FILES) == set(models.REGISTRY)
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    globs = cfg["tool"]["setuptools"]["package-data"]["usdahd"]
    assert "wgpu" in " ".join(cfg["project"]["optional-dependencies"]["test"])
    for lang in shaders.LANGUAGES:
        for model in models.REGISTRY:
            text = shaders.source(lang, model)
            assert f"usdahd_{model}_decode" in text and f"usdahd_{model}_evaluate" in text
        for name in {shaders.COMMON, *shaders.MODEL_FILES.values()}:
            # relative to the package as imported (site-packages in a non-editable install)
            rel = shaders.path(lang, name).relative_to(Path(usdahd.__file__).parent).as_posix()
            assert any(fnmatch.fnmatch(rel, g) for g in globs), f"{rel} is not package data"
    on_disk = {
        p.relative_to(shaders.ROOT).as_posix()
        for lang in shaders.LANGUAGES
        for p in (shaders.ROOT / lang).glob("*.*")
    }
    expected = {
        f"{lang}/{name}.{lang}"
        for lang in shaders.LANGUAGES
        for name in {shaders.COMMON, *shaders.MODEL_FILES.values()}
    }
    assert on_disk == expected


def test_unknown_language_or_model_names_the_choices():
    with pytest.raises(UsageError, match=r"unknown shader language 'msl'; choose glsl, hlsl, wgsl"):
        shaders.source("msl", "hhd")
    with pytest.raises(UsageError, match=r"no shader for model 'vpl'; models: ahd, hhd"):
        shaders.source("glsl", "vpl")
    with pytest.raises(UsageError, match=r"no shader file 'nope'; there are common, "):
        shaders.path("wgsl", "nope")


def test_the_glsl_example_in_docs_schema_compiles(tmp_path):
    """The fragment-shader snippet of docs/schema.md "Reference shaders" is valid GLSL with the
    shipped files (glslang, OpenGL GLSL 4.50 fragment shader)."""
    import re

    text = (ROOT / "docs" / "schema.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```glsl\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1
    src = "\n".join(
        [
            "#version 450",
            shaders.source("glsl", "hhd"),
            "layout(location = 0) in vec3 v_normal;",
            "layout(location = 1) in vec4 v_lightmap_tangent;",
            "layout(location = 2) in vec2 v_uv;",
            "layout(location = 3) in vec2 v_lightmap_st;",
            "layout(location = 4) in vec3 v_material_t;",
            "layout(location = 5) in vec3 v_material_b;",
            "layout(location = 0) out vec4 color;",
            "layout(binding = 0) uniform sampler2D normal_map;",
            "layout(binding = 1) uniform sampler2D iz_tex;",
            "layout(binding = 2) uniform sampler2D direction_tex;",
            "layout(location = 6) uniform float izScale;",
            "layout(location = 7) uniform vec4 scaleOffset;",
            "void main() {",
            "UsdahdFrame material_frame = UsdahdFrame(v_material_t, v_material_b, v_normal);",
            blocks[0],
            "color = vec4(irradiance, 1.0);",
            "}",
        ]
    )
    exe = shutil.which("glslangValidator")
    assert exe, INSTALL_HINT
    f = tmp_path / "example.frag"
    f.write_text(src, encoding="utf-8")
    run = subprocess.run([exe, str(f)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


# ---------------------------------------------------------------------------------------------
# usdahd preview


def _preview(layer, out, *extra):
    return cli.main(["preview", str(layer), "-o", str(out), "--size", "96", "72", *extra])


def test_preview_of_models_that_agree_at_the_normal_gives_the_same_image(bakes, tmp_path, capsys):
    """At the shading normal (no normal map) hhd, hlsh and hemisphere (solver iz) all return the
    stored I_z, which is linear under bilinear filtering (the point of IrradZ), so the rasterised
    previews of the same SH through three different decoders agree per pixel within float16
    quantization. The classic AHD, which interpolates C_a, d and C_d separately, does not (the
    2018 paper's artefact)."""
    imgs, reports = {}, {}
    for model in ("hhd", "hemisphere", "hlsh", "ahd_classic"):
        ratio = models.get(model).RATIOS[0]
        bakes(model, ratio)
        out = tmp_path / f"{model}.png"
        capsys.readouterr()
        assert _preview(bakes.layer, out, "--json") == 0
        reports[model] = json.loads(capsys.readouterr().out)
        assert out.exists()
        from usdahd.commands import preview
        from usdahd.usd import schema

        stage, meshes, up = preview.baked_meshes(str(bakes.layer))
        pts = np.concatenate([np.asarray(m.points) for m, *_ in meshes])
        items = []
        for mesh, res, tangent, sign in meshes:
            lay = models.get(res.model).layout(res.ratio)
            tex = [schema.read_record_pixels(res, t.role, channels=t.channels) for t in lay]
            items.append((preview.vertex_data(mesh, tangent, sign), model, ratio, tex, res.factors))
        _, dev = preview.device()
        imgs[model] = preview.render(dev, items, preview.auto_camera(pts, up, 96 / 72), (96, 72))
    r = reports["hhd"]
    assert r["meshes"] == 7 and r["models"] == ["hhd/luminance"] and r["non_finite"] == 0
    assert 0.2 < r["covered_fraction"] < 0.6 and r["luminance"]["mean"] > 0
    ref = imgs["hhd"]
    cov = ref[..., 3] > 0
    assert np.array_equal(cov, imgs["hemisphere"][..., 3] > 0)
    scale = float(ref[cov, :3].max())
    for model in ("hemisphere", "hlsh"):
        err = np.abs(imgs[model][cov, :3] - ref[cov, :3])
        assert err.max() <= 1e-5 * scale, (model, err.max(), scale)  # the same halves
    classic = np.abs(imgs["ahd_classic"][cov, :3] - ref[cov, :3]).max()
    assert classic > 2.0**-8 * scale  # overshoot between texels of different directions


def test_preview_from_a_usd_camera_and_its_errors(bakes, tmp_path, capsys):
    bakes("hhd", "luminance")
    shot = tmp_path / "shot.usda"
    shot.write_text(
        "#usda 1.0\n(\n    subLayers = [@" + bakes.layer.as_posix() + "@]\n)\n"
        'def Camera "Cam"\n{\n    float focalLength = 35\n    float verticalAperture = 20\n'
        "    float2 clippingRange = (0.01, 100)\n"
        "    double3 xformOp:translate = (0, 1, 4)\n"
        '    uniform token[] xformOpOrder = ["xformOp:translate"]\n}\n'
    )
    capsys.readouterr()
    assert _preview(shot, tmp_path / "cam.png", "--camera", "/Cam", "--json") == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["camera"] == "/Cam" and rep["covered_fraction"] > 0.5

    assert _preview(shot, tmp_path / "x.png", "--camera", "/Nope") == 2
    assert (
        "--camera /Nope: no UsdGeomCamera there; cameras on the stage: /Cam"
        in capsys.readouterr().err
    )
    assert _preview(bakes.layer, tmp_path / "x.jpg") == 2
    assert "the preview is a PNG" in capsys.readouterr().err
    assert _preview(bakes.stage, tmp_path / "x.png") == 2
    assert "no baked prim (formatVersion 0); run usdahd bake first" in capsys.readouterr().err
    assert (
        cli.main(["preview", str(bakes.layer), "-o", str(tmp_path / "x.png"), "--size", "0", "5"])
        == 2
    )
    assert "width and height must be 1..16384" in capsys.readouterr().err
    assert _preview(tmp_path / "missing.usda", tmp_path / "x.png") == 2
    assert "missing.usda: no such file" in capsys.readouterr().err


def test_preview_of_the_open_plane_is_the_analytic_irradiance(tmp_path, capsys):
    """samples/open_plane.usda: a plane under a uniform dome of radiance 1 has I = 1 at every
    point; the rasterised preview (automatic framing from above, so the plane is not edge-on)
    shows exactly that on every covered pixel."""
    stage = tmp_path / "open_plane.usda"
    shutil.copy(ROOT / "samples" / "open_plane.usda", stage)
    argv = ["bake", str(stage), "--resolution", "8", "--samples", "16", "--quiet"]
    assert cli.main(argv) == 0
    capsys.readouterr()
    assert _preview(tmp_path / "open_plane.lightmaps.usda", tmp_path / "v.png", "--json") == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["covered_fraction"] > 0.05
    lum = rep["luminance"]
    assert abs(lum["min"] - 1.0) < 2e-3 and abs(lum["max"] - 1.0) < 2e-3, lum
