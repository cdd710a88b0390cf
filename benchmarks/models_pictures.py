"""The pictures of docs/models.md: AHD vs IrradZ HHD at a sun shadow's edge, from the preview.

With the flat surface normal both models return ``I_z`` exactly, so the plain preview of an
``ahd`` and an ``hhd`` bake are the same picture; they differ where the shading normal tilts
away from the texel normal. This script therefore shades ``samples/exterior_sun_sky.usda``
with a normal map: a wrapper stage beside the output sublayers the sample and binds the ground
to a UsdPreviewSurface whose ``inputs:normal`` reads ``samples/textures/bumps_normal.png``
(the normal_wall sample's dome grid) through the lightmap UVs tiled by a UsdTransform2d. It
bakes the wrapper twice (``python -m usdahd bake --model ahd`` / ``--model hhd``, same seed and
settings) and renders each with ``python -m usdahd preview --model-view`` from the same camera
(a UsdGeomCamera in the wrapper looking at the boxes' shadows), writing
``docs/models/<model>.png`` (or ``--out DIR``).

    python -m benchmarks.models_pictures [--out docs/models] [--size 400 300] [--samples 256]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "exterior_sun_sky.usda"
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "models"), help="PNG directory")
    ap.add_argument("--size", nargs=2, type=int, default=(400, 300), metavar=("W", "H"))
    ap.add_argument("--samples", type=int, default=256, help="bake samples per texel")
    ap.add_argument("--texel-density", type=float, default=16.0, help="bake texels per metre")
    ap.add_argument("--tiles", type=float, default=6.0, help="normal-map tiles across the ground")
    ap.add_argument("--work", help="directory for the wrapper stage and bakes (default: temp)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(args.work or tempfile.mkdtemp(prefix="usdahd-models-"))
    work.mkdir(parents=True, exist_ok=True)
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
