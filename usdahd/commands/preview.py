"""``usdahd preview``: render the baked lighting of a stage as an engine would (issue 14).

Rasterises every baked mesh through wgpu (Vulkan: Mesa's lavapipe on the CPU, or a GPU) with the
shipped WGSL decoders (``usdahd/shaders/``): per fragment the lightmap tangent frame is rebuilt
from the interpolated normal and the lightmap-UV tangent, the textures are sampled bilinearly at
the lightmap UV, decoded and evaluated at the shading normal. The result is normalized
irradiance (a white Lambertian surface's radiance times pi); the PNG is tone-mapped (auto
exposure on the 99th percentile, sRGB), ``--json`` prints linear statistics.

Back faces are culled (closed rooms open towards the camera). Without a Vulkan adapter
``--backend auto`` falls back to Embree primary rays + the numpy decoders
(:mod:`usdahd.preview.raytrace`, which culls the same faces); one stderr line says what to install.

``--compare`` traces a reference of the same view with the baker's integrator at each pixel's
visible point and writes preview | reference | error heat map side by side
(:mod:`usdahd.preview.compare`).

Not yet: albedo and normal maps (``--model-view``), ``--atlas``.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from usdahd.errors import StageError, UsageError

INSTALL_HINT = (
    "usdahd preview renders through wgpu on a Vulkan device; install one: "
    "pip install wgpu, and for the CPU apt-get install mesa-vulkan-drivers libvulkan1"
)
#: Vertical field of view of the automatic framing (degrees).
AUTO_FOV = 40.0
#: Tangent of the automatic framing's elevation above the horizon (0.5: ~27 degrees).
ELEVATION = 0.5
#: Rec. 709 luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Default reference samples per pixel of --compare.
COMPARE_SAMPLES = 256
FACTORS = (
    "izScale",
    "ambientScale",
    "directionalScale",
    "coefficientsScale",
    "l0Scale",
    "ratioScale",
)


def add_parser(sub):
    p = sub.add_parser(
        "preview",
        help="render the baked lighting of a baked stage to a PNG (wgpu, the shipped shaders)",
        description=(
            "Render the baked irradiance of every baked mesh of STAGE (a layer written by "
            "usdahd bake) from a UsdGeomCamera or an automatic framing, by rasterising with the "
            "reference WGSL decoders through wgpu (CPU Vulkan by default, a GPU when present). "
            "Writes a tone-mapped PNG; --json prints the image statistics."
        ),
    )
    p.add_argument("stage", help="baked layer (STAGE.lightmaps.usda)")
    p.add_argument("-o", "--output", required=True, help="PNG to write")
    p.add_argument("--camera", metavar="PATH", help="UsdGeomCamera prim to render from")
    p.add_argument(
        "--size", nargs=2, type=int, metavar=("W", "H"), help="image size (default 640 480)"
    )
    p.add_argument(
        "--exposure", type=float, default=0.0, help="stops added to the automatic exposure"
    )
    p.add_argument(
        "--backend",
        choices=("auto", "wgpu", "embree"),
        default="auto",
        help="wgpu (the shipped shaders on Vulkan), embree (primary rays + the numpy decoders), "
        "or auto: wgpu, falling back to embree when there is no Vulkan adapter",
    )
    p.add_argument(
        "--atlas",
        action="store_true",
        help="instead of a view: a contact sheet of every lightmap texture (one row per baked "
        "prim, tone-mapped, chart outlines in white, texels flagged by usdahd validate in "
        "magenta); --json lists the tiles and the flagged texels",
    )
    c = p.add_argument_group("--compare (path-traced reference of the same view)")
    c.add_argument(
        "--compare",
        action="store_true",
        help="add a path-traced reference (the baker's integrator at each pixel's visible point) "
        "and an error heat map beside the preview; --json reports relRMSE, bias and the "
        "reference's noise",
    )
    c.add_argument(
        "--compare-samples",
        type=int,
        metavar="N",
        help=f"reference samples per pixel (default {COMPARE_SAMPLES}, in 8 batches)",
    )
    c.add_argument(
        "--compare-bounces",
        type=int,
        metavar="N",
        help="the reference's bounce cap (default: the bake's recorded --bounces)",
    )
    c.add_argument("--seed", type=int, help="seed of the reference (default 0)")
    p.set_defaults(func=run)
    return p


# ---------------------------------------------------------------------------------------------
# Camera


def look_at(eye, target, up) -> np.ndarray:
    """View matrix (4, 4) float64, column vectors, camera looking down -z (right-handed)."""
    f = np.asarray(target, float) - np.asarray(eye, float)
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, float)
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """Projection (4, 4) float64 to WebGPU clip space (z in [0, 1])."""
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = far / (near - far), near * far / (near - far)
    m[3, 2] = -1.0
    return m


def auto_camera(points: np.ndarray, up_axis: str, aspect: float) -> np.ndarray:
    """View-projection (4, 4) framing the bounding sphere of points (n, 3) from the front
    (+z for a Y-up stage, -y for Z-up) and above; back-face culling opens closed rooms (their
    front wall and ceiling face away from the camera)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    c = 0.5 * (lo + hi)
    r = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "Y" else np.array([0.0, 0.0, 1.0])
    front = np.array([0.0, 0.0, 1.0]) if up_axis == "Y" else np.array([0.0, -1.0, 0.0])
    back = front + ELEVATION * up  # from the front and above: floors and planes are not edge-on
    back /= np.linalg.norm(back)
    half = math.radians(AUTO_FOV) / 2.0
    fit = min(half, math.atan(math.tan(half) * aspect))
    dist = r / math.sin(fit)
    eye = c + back * dist
    near, far = max(dist - 1.5 * r, 1e-3 * dist), dist + 1.5 * r
    return perspective(AUTO_FOV, aspect, near, far) @ look_at(eye, c, up)


def usd_camera(stage, path: str, aspect: float) -> np.ndarray:
    """View-projection (4, 4) of a UsdGeomCamera (its vertical aperture kept, the horizontal
    one fitted to the image aspect), WebGPU clip space."""
    from usdahd.usd.camera import read_camera

    view, fov, near, far = read_camera(stage, path)
    return perspective(fov, aspect, near, far) @ view


# ---------------------------------------------------------------------------------------------
# Scene


def baked_meshes(layer: str):
    """[(MeshData, BakeResults)] of every baked mesh, and the stage's up axis."""
    from usdahd.bake import texels
    from usdahd.usd import schema
    from usdahd.usd.reader import load_scene
    from usdahd.usd.stage import open_stage

    stage = open_stage(layer)  # re-read from disk when this process opened it before
    records = {}
    for prim in schema.prims_with_api(stage):
        res = schema.read_results(prim)
        if res is not None:
            records[str(prim.GetPath())] = res
    if not records:
        raise UsageError(f"{layer}: no baked prim (formatVersion 0); run usdahd bake first")
    out, up = [], "Y"
    for uv in sorted({r.uv_primvar for r in records.values()}):
        sc = load_scene(stage, uv_name=uv)
        up = sc.up_axis
        for mesh in sc.meshes:
            res = records.get(mesh.path)
            if res is None or res.uv_primvar != uv:
                continue
            if mesh.uv is None:
                raise StageError(f"{mesh.path}: the baked UV set {uv!r} is missing")
            tangent, sign = texels.tangent_frames(mesh)
            out.append((mesh, res, tangent, sign))
    if not out:
        raise StageError(f"{layer}: the baked prims are not visible meshes of the stage")
    return stage, out, up


def vertex_data(mesh, tangent, sign) -> np.ndarray:
    """Per-corner vertices (3t, 12) float32: position, lightmap st, normal, tangent + sign."""
    t = len(mesh.triangles)
    pos = np.asarray(mesh.points, np.float64)[mesh.triangles]
    v = np.zeros((t, 3, 12), np.float32)
    v[..., 0:3] = pos
    v[..., 3:5] = mesh.uv
    v[..., 5:8] = mesh.normals
    v[..., 8:11] = tangent
    v[..., 11] = np.asarray(sign)[:, None]
    return v.reshape(-1, 12)


# ---------------------------------------------------------------------------------------------
# Rendering


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
        adapter = request_adapter()
        why = "no Vulkan adapter found"
    except ImportError:
        adapter, why = None, "wgpu is not installed"
    if adapter is None:
        if backend == "auto":
            print(f"usdahd preview: {why}; {INSTALL_HINT}; falling back to Embree", file=sys.stderr)
            return None
        raise UsageError(f"{why}; {INSTALL_HINT}")
    return adapter, adapter.request_device_sync()


_SHADER = """
struct U {{
    viewproj: mat4x4<f32>,
    f0: vec4<f32>,
    f1: vec4<f32>,
}}
@group(0) @binding(0) var<uniform> u: U;
@group(0) @binding(1) var samp: sampler;
{textures}
{library}
struct VOut {{
    @builtin(position) pos: vec4<f32>,
    @location(0) st: vec2<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) tangent: vec4<f32>,
}}

@vertex
fn vs(@location(0) p: vec3<f32>, @location(1) st: vec2<f32>, @location(2) n: vec3<f32>,
      @location(3) t: vec4<f32>) -> VOut {{
    return VOut(u.viewproj * vec4<f32>(p, 1.0), st, n, t);
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
    let n = usdahd_to_tangent(frame, frame.n); // the shading normal (no normal map yet)
    let uv = usdahd_lightmap_texcoord(v.st);
{samples}
    let p = {decode};
    return vec4<f32>({evaluate}(p, n), 1.0);
}}
"""


def shader_source(model: str, ratio: str, n_textures: int) -> str:
    """WGSL vertex + fragment shader of one model variant (the shipped decoders)."""
    from usdahd import shaders

    _, call, _, evaluate = shaders.calls(model, ratio)
    return _SHADER.format(
        textures="\n".join(
            f"@group(0) @binding({2 + j}) var tex{j}: texture_2d<f32>;" for j in range(n_textures)
        ),
        samples="\n".join(
            f"    let s{j} = textureSample(tex{j}, samp, uv);" for j in range(n_textures)
        ),
        library=shaders.source("wgsl", model),
        decode=call,
        evaluate=evaluate,
    )


def _texture(dev, pixels: np.ndarray):
    import wgpu

    h, w, c = pixels.shape
    if pixels.dtype == np.float16:
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


def render(dev, items, viewproj: np.ndarray, size) -> np.ndarray:
    """Rasterise [(vertices (3t, 12), model, ratio, textures [(h, w, c)], factors)] ->
    (H, W, 4) float32: normalized irradiance RGB, alpha 1 where a mesh covers the pixel."""
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
    pipelines = {}
    draws = []
    for verts, model, ratio, textures, factors in items:
        key = (model, ratio, len(textures))
        if key not in pipelines:
            module = dev.create_shader_module(code=shader_source(*key))
            pipelines[key] = dev.create_render_pipeline(
                layout="auto",
                vertex={
                    "module": module,
                    "entry_point": "vs",
                    "buffers": [{"array_stride": 48, "step_mode": "vertex", "attributes": attrs}],
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
        uni = np.zeros(24, np.float32)
        uni[:16] = viewproj.T.reshape(-1)  # WGSL matrices are column-major
        uni[16:22] = [factors.get(f, 1.0) for f in FACTORS]
        ubuf = dev.create_buffer_with_data(data=uni.tobytes(), usage=wgpu.BufferUsage.UNIFORM)
        vbuf = dev.create_buffer_with_data(
            data=np.ascontiguousarray(verts).tobytes(), usage=wgpu.BufferUsage.VERTEX
        )
        entries = [
            {"binding": 0, "resource": {"buffer": ubuf}},
            {"binding": 1, "resource": sampler},
        ]
        entries += [
            {"binding": 2 + j, "resource": _texture(dev, t).create_view()}
            for j, t in enumerate(textures)
        ]
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


def tonemap(image: np.ndarray, exposure_stops: float = 0.0) -> tuple[np.ndarray, float]:
    """(H, W, 4) linear -> (H, W, 3) uint8 sRGB and the scale applied (99th percentile of the
    covered luminance -> 0.9, times 2^stops)."""
    covered = image[..., 3] > 0
    lum = image[..., :3] @ LUMA
    ref = float(np.percentile(lum[covered], 99)) if covered.any() else 0.0
    scale = (0.9 / ref if ref > 0 else 1.0) * 2.0**exposure_stops
    return tonemap_with(image, scale), scale


def tonemap_with(image: np.ndarray, scale: float) -> np.ndarray:
    """(H, W, 4) linear -> (H, W, 3) uint8 sRGB at a given linear scale (uncovered: black)."""
    x = np.clip(image[..., :3] * scale, 0.0, 1.0)
    x = np.where(image[..., 3:] > 0, x, 0.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(255.0 * srgb).astype(np.uint8)


def stats(image: np.ndarray) -> dict:
    """Linear statistics of the covered pixels (normalized irradiance, Rec. 709 luminance)."""
    covered = image[..., 3] > 0
    lum = (image[..., :3] @ LUMA)[covered]
    rgb = image[..., :3][covered]
    if not lum.size:
        return {"covered_fraction": 0.0}
    return {
        "covered_fraction": float(covered.mean()),
        "mean_rgb": [float(v) for v in rgb.mean(axis=0)],
        "luminance": {
            "mean": float(lum.mean()),
            "min": float(lum.min()),
            "p50": float(np.percentile(lum, 50)),
            "p99": float(np.percentile(lum, 99)),
            "max": float(lum.max()),
        },
        "non_finite": int((~np.isfinite(image[..., :3][covered])).sum()),
    }


def _check(args) -> Path:
    """Usage errors before any work; returns the output path."""
    if args.size is not None:
        w, h = args.size
        if w < 1 or h < 1 or w > 16384 or h > 16384:
            raise UsageError(f"--size {w} {h}: width and height must be 1..16384")
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise UsageError(f"-o {out}: the preview is a PNG (use a .png name)")
    if not Path(args.stage).exists():
        raise StageError(f"{args.stage}: no such file")
    if args.atlas:
        given = [f for f, v in (("--camera", args.camera), ("--size", args.size),
                                ("--compare", args.compare or None)) if v is not None]  # fmt: skip
        if given:
            raise UsageError(
                f"{given[0]} does not apply to --atlas (a sheet of the textures, not a view); "
                "drop one of them"
            )
    if not args.compare:
        given = [
            a
            for a in ("compare_samples", "compare_bounces", "seed")
            if getattr(args, a) is not None
        ]
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise UsageError(f"{flag} is an option of --compare; add --compare")
    samples = COMPARE_SAMPLES if args.compare_samples is None else args.compare_samples
    if samples < 2:
        raise UsageError(
            f"--compare-samples {samples}: the reference needs at least 2 samples per pixel "
            "(its noise estimate comes from the scatter of independent batches); give 2 or more"
        )
    if args.compare_bounces is not None and args.compare_bounces < 0:
        raise UsageError(
            f"--compare-bounces {args.compare_bounces}: bounces must be >= 0 (0: direct light)"
        )
    return out


def run_atlas(args, out: Path) -> int:
    """``--atlas``: the contact sheet (:mod:`usdahd.preview.atlas`)."""
    from usdahd import images
    from usdahd.preview import atlas
    from usdahd.validate.run import validate_file

    _, meshes, _ = baked_meshes(args.stage)
    findings = validate_file(str(args.stage)).findings
    img, info = atlas.contact_sheet(meshes, findings)
    images.write(out, img, color_space="srgb_rec709_scene")
    report = {
        "stage": str(args.stage),
        "output": str(out),
        "size": [int(img.shape[1]), int(img.shape[0])],
        "meshes": len(meshes),
        **info,
    }
    if args.json:
        print(json.dumps(report, indent=2))
    elif not args.quiet:
        print(
            f"{out}: {img.shape[1]}x{img.shape[0]} contact sheet, {len(meshes)} prims, "
            f"{len(info['tiles'])} textures, {len(info['flagged'])} texel(s) flagged by validate"
        )
    return 0


def run(args) -> int:
    from usdahd import images, models

    out = _check(args)
    if args.atlas:
        return run_atlas(args, out)
    w, h = args.size or (640, 480)
    gpu = None if args.backend == "embree" else device(args.backend)  # before any long work
    summary = gpu[0].summary if gpu else "embree (primary rays, numpy decoders)"
    print(f"usdahd preview: {summary}", file=sys.stderr)
    stage, meshes, up = baked_meshes(args.stage)
    aspect = w / h
    if args.camera:
        viewproj = usd_camera(stage, args.camera, aspect)
    else:
        pts = np.concatenate([np.asarray(m.points) for m, *_ in meshes])
        viewproj = auto_camera(pts, up, aspect)
    items = []
    for mesh, res, tangent, sign in meshes:
        layout = models.get(res.model).layout(res.ratio)
        textures = [images.read(res.textures[t.role], channels=t.channels).pixels for t in layout]
        items.append(
            (vertex_data(mesh, tangent, sign), res.model, res.ratio, textures, res.factors)
        )
    if gpu:
        image = render(gpu[1], items, viewproj, (w, h))
    else:
        from usdahd.preview import raytrace
        from usdahd.usd.reader import load_scene

        scene = load_scene(stage, uv_name=meshes[0][1].uv_primvar)  # the materials
        traced = [(mesh,) + it[1:] for (mesh, *_), it in zip(meshes, items)]
        image = raytrace.render(scene, traced, viewproj, (w, h))
    ldr, scale = tonemap(image, args.exposure)
    compared = None
    if args.compare:
        from usdahd.preview import compare

        def progress(line):
            if not args.quiet:
                print(f"usdahd preview: {line}", file=sys.stderr)

        ref, var, info = compare.reference(
            stage,
            meshes,
            viewproj,
            (w, h),
            samples=COMPARE_SAMPLES if args.compare_samples is None else args.compare_samples,
            seed=args.seed or 0,
            bounces=args.compare_bounces,
            progress=progress,
        )
        compared = {**info, **compare.error_stats(image, ref, var)}
        ldr = compare.side_by_side(
            ldr, tonemap_with(ref, scale), compare.heat_map(image, ref)
        )  # the reference at the preview's exposure: the two panels compare by eye
    images.write(out, ldr, color_space="srgb_rec709_scene")
    report = {
        "stage": str(args.stage),
        "output": str(out),
        "size": [w, h],
        "camera": args.camera or "auto",
        "adapter": summary,
        "backend": "wgpu" if gpu else "embree",
        "meshes": len(items),
        "models": sorted({f"{m}/{r}" for _, m, r, _, _ in items}),
        "exposure_scale": scale,
        **stats(image),
    }
    if compared is not None:
        report["compare"] = compared
    if args.json:
        print(json.dumps(report, indent=2))
    elif not args.quiet:
        lum = report.get("luminance", {})
        print(
            f"{out}: {w}x{h}, {len(items)} meshes, covered {report['covered_fraction']:.1%}, "
            f"mean irradiance {lum.get('mean', 0.0):.4g} (p99 {lum.get('p99', 0.0):.4g})"
        )
        if compared is not None and compared["relrmse"] is not None:
            print(
                f"  vs path-traced reference ({compared['samples']} samples, "
                f"{compared['bounces']} bounces): relRMSE {compared['relrmse']:.2%}, bias "
                f"{compared['bias']:+.2%}, reference noise {compared['reference_noise']:.2%}"
            )
    return 0
