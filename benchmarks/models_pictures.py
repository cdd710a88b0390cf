"""The pictures of docs/models.md, from the preview.

**The 2018 interpolation artefact** (default): ``samples/pillar_room.usda`` (the paper's Figure 1
situation: a SphereLight 25 cm above the floor shadowed by a pillar) seen through a
UsdGeomCamera of a wrapper stage, baked once with ``python -m usdahd bake --model ahd``
(coarse: ``--texel-density 6``, so the shadow edges span a few texels) and rendered twice by
``python -m usdahd preview --camera /World/Shot``: as is (the IrradZ decode after filtering,
``docs/models/irradz_decode.png``) and with ``--ahd-classic`` (classic C_a, d, C_d textures
filtered independently, ``docs/models/ahd_classic_import.png``, at the first picture's
exposure). The script then renders both views again in-process (the same functions the
command calls, linear float32) and measures the overshoot of the classic import's I_z over the
IrradZ I_z, ``(classic - irradz) / irradz`` of the luminance, in the *transition pixels* and
elsewhere. Transition pixels are chosen from the bake, not from the classic picture: those whose
bilinear footprint holds a texel whose 3 x 3 lightmap neighbourhood spans an I_z ratio above
``TRANSITION_RATIO`` and turns the direction by more than ``TRANSITION_ANGLE`` (a lit-to-shadowed
edge: the lit texel's d points at the lamp, the shadowed one's at the bounce light), found by
rendering each texel's flag through the same pipeline;
``docs/models/ahd_classic_overshoot.png`` is the heat map (red: overshoot, full at
+50 %; blue: undershoot; green: the IrradZ luminance, dimmed).

**AHD vs HHD under a normal map** (``--normal-map``): ``samples/exterior_sun_sky.usda`` with a
normal-mapped ground (a wrapper binds a UsdPreviewSurface whose ``inputs:normal`` reads
``samples/textures/bumps_normal.png``), baked ``--model ahd`` and ``--model hhd`` and rendered
with ``--model-view``: ``docs/models/{ahd,hhd}.png``.

    python -m benchmarks.models_pictures [--out docs/models] [--size 400 300] [--normal-map]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "exterior_sun_sky.usda"
PILLAR = ROOT / "samples" / "pillar_room.usda"
#: A texel is a transition texel when the I_z luminance of its 3 x 3 lightmap neighbourhood
#: spans more than this ratio (max / min) and a neighbour's direction is more than this angle
#: (degrees) from its own; a pixel is a transition pixel when its bilinear footprint holds one.
TRANSITION_RATIO = 1.5
TRANSITION_ANGLE = 30.0
#: The heat map's full red / blue.
HEAT_FULL = 0.5
NORMAL_MAP = ROOT / "samples" / "textures" / "bumps_normal.png"
MODELS = ("ahd", "hhd")

WRAPPER = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
    subLayers = [@{sample}@]
)

over "World"
{{
    over "Geometry"
    {{
        over "Ground" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {{
            rel material:binding = </World/Looks/Bumps>
        }}
    }}

    def Camera "Shot"
    {{
        float focalLength = 30
        float horizontalAperture = 36
        float verticalAperture = 27
        float3 xformOp:rotateXYZ = (-42, 20, 0)
        double3 xformOp:translate = (1.4, 2.6, 3.4)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}

    over "Looks"
    {{
        def Material "Bumps"
        {{
            token outputs:surface.connect = </World/Looks/Bumps/PreviewSurface.outputs:surface>

            def Shader "PreviewSurface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.5, 0.5, 0.5)
                normal3f inputs:normal.connect = </World/Looks/Bumps/NormalTexture.outputs:rgb>
                token outputs:surface
            }}

            def Shader "TexCoordReader"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}

            def Shader "Tile"
            {{
                uniform token info:id = "UsdTransform2d"
                float2 inputs:in.connect = </World/Looks/Bumps/TexCoordReader.outputs:result>
                float2 inputs:scale = ({tiles}, {tiles})
                float2 outputs:result
            }}

            def Shader "NormalTexture"
            {{
                uniform token info:id = "UsdUVTexture"
                float4 inputs:bias = (-1, -1, -1, 0)
                asset inputs:file = @{normal_map}@
                float4 inputs:scale = (2, 2, 2, 1)
                token inputs:sourceColorSpace = "raw"
                float2 inputs:st.connect = </World/Looks/Bumps/Tile.outputs:result>
                token inputs:wrapS = "repeat"
                token inputs:wrapT = "repeat"
                float3 outputs:rgb
            }}
        }}
    }}
}}
"""


def run(argv):
    print("+", " ".join(map(str, argv)), file=sys.stderr)
    proc = subprocess.run([sys.executable, "-m", "usdahd", *map(str, argv)], capture_output=True,
                          text=True, cwd=ROOT)  # fmt: skip
    if proc.returncode != 0:
        sys.exit(f"usdahd {argv[0]} failed:\n{proc.stderr}")
    return proc.stdout


PILLAR_WRAPPER = """#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
    subLayers = [@{sample}@]
)

over "World"
{{
    def Camera "Shot"
    {{
        float focalLength = 20
        float horizontalAperture = 36
        float verticalAperture = 27
        float3 xformOp:rotateXYZ = (-34, 90, 0)
        double3 xformOp:translate = (3.4, 1.9, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
}}
"""


def transition_texels(iz, d, ratio: float = TRANSITION_RATIO, angle: float = TRANSITION_ANGLE):
    """(h, w) bool: texels of a lightmap (texel-centre I_z (h, w, 3), unit d (h, w, 3)) whose
    3 x 3 neighbourhood spans an I_z luminance ratio (max / min) above ``ratio`` and holds a
    direction more than ``angle`` degrees from the texel's (zero texels ignored)."""
    import numpy as np
    from numpy.lib.stride_tricks import sliding_window_view as windows

    lum = np.asarray(iz, np.float64).mean(-1)
    x = np.pad(np.where(lum > 0, lum, np.nan), 1, constant_values=np.nan)
    w = windows(x, (3, 3)).reshape(lum.shape + (9,))
    hi = np.max(np.where(np.isnan(w), -np.inf, w), axis=-1)
    lo = np.min(np.where(np.isnan(w), np.inf, w), axis=-1)
    dp = np.pad(np.asarray(d, np.float64), ((1, 1), (1, 1), (0, 0)))
    dw = windows(dp, (3, 3), axis=(0, 1)).reshape(lum.shape + (3, 9))
    cos = np.einsum("hwc,hwck->hwk", np.asarray(d, np.float64), dw)
    cos = np.where(np.isnan(w), 1.0, cos)
    turns = cos.min(-1) < np.cos(np.radians(angle))
    return (lum > 0) & (hi > ratio * lo) & turns


def transition_pixels(dev, classic_items, viewproj, size):
    """(H, W) bool: the pixels whose bilinear footprint holds a transition texel, found by
    rendering each texel's flag through the same pipeline (a classic item with C_a = flag,
    d = z, C_d = 0: the image is the filtered flag)."""
    import numpy as np

    from usdahd.preview.gpu import render

    items = []
    for verts, model, variant, (ca, d, cd), factors in classic_items:
        iz = ca + d[..., 2:3] * cd  # AHD at the normal: the texel's I_z
        flag = np.repeat(transition_texels(iz, d)[..., None], 3, -1).astype(np.float32)
        z = np.zeros_like(d)
        z[..., 2] = 1.0
        items.append((verts, model, variant, [flag, z, np.zeros_like(cd)], factors))
    img = render(dev, items, viewproj, size)
    return (img[..., 3] > 0) & (img[..., 0] > 0)


def overshoot(irradz, classic, mask):
    """Statistics of (classic - irradz) / irradz of the luminance over ``mask`` pixels."""
    import numpy as np

    a = irradz[..., :3].mean(-1)[mask]
    b = classic[..., :3].mean(-1)[mask]
    r = (b - a) / np.maximum(a, 1e-12)
    if not r.size:
        return {"pixels": 0}
    return {
        "pixels": int(r.size),
        "max": float(r.max()),
        "mean": float(r.mean()),
        "p95": float(np.percentile(r, 95)),
        "min": float(r.min()),
        "above_10_percent": float((r > 0.1).mean()),
    }


def heat(irradz, classic, covered):
    """(H, W, 3) uint8: red overshoot, blue undershoot (full at HEAT_FULL), green the IrradZ
    luminance at a third of the 99th-percentile exposure."""
    import numpy as np

    a = irradz[..., :3].mean(-1)
    r = (classic[..., :3].mean(-1) - a) / np.maximum(a, 1e-12)
    ref = float(np.percentile(a[covered], 99)) if covered.any() else 1.0
    img = np.zeros(a.shape + (3,))
    img[..., 0] = np.clip(r / HEAT_FULL, 0, 1)
    img[..., 2] = np.clip(-r / HEAT_FULL, 0, 1)
    img[..., 1] = np.clip(a / max(ref, 1e-12), 0, 1) / 3.0
    img[~covered] = 0.0
    return np.rint(255 * img).astype(np.uint8)


def interpolation(args, out: Path, work: Path) -> dict:
    """The 2018 interpolation artefact pictures and measurement (module doc)."""

    from usdahd import images
    from usdahd.preview.camera import view_projection
    from usdahd.preview.gpu import device
    from usdahd.preview.meshes import baked_meshes, draw_items, render_view

    stage = work / "pillar_shot.usda"
    stage.write_text(PILLAR_WRAPPER.format(sample=PILLAR.as_posix()), encoding="utf-8")
    layer = work / "pillar_shot.ahd.lightmaps.usda"
    run(["bake", stage, "-o", layer, "--model", "ahd", "--samples", args.pillar_samples,
         "--texel-density", args.pillar_density, "--seed", 1, "--force", "--quiet"])  # fmt: skip
    view = ["--camera", "/World/Shot", "--size", *args.size, "--json"]
    irr_png, cls_png = out / "irradz_decode.png", out / "ahd_classic_import.png"
    rep = json.loads(run(["preview", layer, "-o", irr_png, *view]))
    first = json.loads(run(["preview", layer, "-o", cls_png, "--ahd-classic", *view]))
    stops = math.log2(rep["exposure_scale"] / first["exposure_scale"])
    run(["preview", layer, "-o", cls_png, "--ahd-classic", "--exposure", stops, *view])

    w, h = args.size
    st, meshes, up = baked_meshes(str(layer))
    vp = view_projection(st, meshes, up, "/World/Shot", w / h)
    _, dev = device()
    irradz = render_view(st, meshes, draw_items(meshes), vp, (w, h), dev)
    classic = render_view(
        st, meshes, draw_items(meshes, ahd_classic=True), vp, (w, h), dev, ahd_classic=True
    )
    covered = irradz[..., 3] > 0
    edge = transition_pixels(dev, draw_items(meshes, ahd_classic=True), vp, (w, h))
    heat_png = out / "ahd_classic_overshoot.png"
    images.write(heat_png, heat(irradz, classic, covered), color_space="srgb_rec709_scene")
    return {
        "bake": {
            "model": "ahd",
            "samples": args.pillar_samples,
            "texel_density": args.pillar_density,
        },  # fmt: skip
        "pictures": [str(irr_png), str(cls_png), str(heat_png)],
        "bytes": [p.stat().st_size for p in (irr_png, cls_png, heat_png)],
        "exposure_scale": rep["exposure_scale"],
        "transition_ratio": TRANSITION_RATIO,
        "transition_angle_deg": TRANSITION_ANGLE,
        "overshoot_transition": overshoot(irradz, classic, edge),
        "overshoot_elsewhere": overshoot(irradz, classic, covered & ~edge),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "models"), help="PNG directory")
    ap.add_argument("--size", nargs=2, type=int, default=(400, 300), metavar=("W", "H"))
    ap.add_argument("--samples", type=int, default=256, help="bake samples per texel")
    ap.add_argument("--texel-density", type=float, default=16.0, help="bake texels per metre")
    ap.add_argument("--tiles", type=float, default=6.0, help="normal-map tiles across the ground")
    ap.add_argument("--work", help="directory for the wrapper stage and bakes (default: temp)")
    ap.add_argument("--pillar-samples", type=int, default=1024, help="pillar bake samples")
    ap.add_argument("--pillar-density", type=float, default=6.0, help="pillar texels per metre")
    ap.add_argument(
        "--normal-map",
        action="store_true",
        help="the AHD vs HHD normal-map pictures instead (docs/models/{ahd,hhd}.png)",
    )
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(args.work or tempfile.mkdtemp(prefix="usdahd-models-"))
    work.mkdir(parents=True, exist_ok=True)
    if not args.normal_map:
        print(json.dumps(interpolation(args, out, work), indent=2))
        return 0
    stage = work / "exterior_bumpy.usda"
    stage.write_text(
        WRAPPER.format(sample=SAMPLE.as_posix(), normal_map=NORMAL_MAP.as_posix(),
                       tiles=args.tiles),
        encoding="utf-8",
    )  # fmt: skip
    report = {}
    for model in MODELS:
        layer = work / f"exterior_bumpy.{model}.lightmaps.usda"
        run(["bake", stage, "-o", layer, "--model", model, "--samples", args.samples,
             "--texel-density", args.texel_density, "--seed", 1, "--force", "--quiet"])  # fmt: skip
        png = out / f"{model}.png"
        rep = json.loads(
            run(
                [
                    "preview",
                    layer,
                    "-o",
                    png,
                    "--model-view",
                    "--camera",
                    "/World/Shot",
                    "--size",
                    *args.size,
                    "--json",
                ]
            )  # fmt: skip
        )
        report[model] = {
            "png": str(png),
            "bytes": png.stat().st_size,
            "mean_rgb": rep.get("mean_rgb"),
            "exposure_scale": rep.get("exposure_scale"),
        }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
