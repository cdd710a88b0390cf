"""``usdahd export gltf``: a baked stage as glTF 2.0 with directional lightmaps (issue 42).

The export itself lives in :mod:`usdahd.export.gltf`; docs/gltf.md describes the file and the
``USDAHD_lightmap_directional`` extension, and ``usdahd/web/usdahd-lightmap.js`` is the
reference three.js importer.
"""

from __future__ import annotations

import sys

from usdahd.commands.output import emit


def add_parser(sub):
    p = sub.add_parser(
        "export",
        help="export a baked stage for engines without USD import (glTF 2.0 + lightmaps)",
        description=(
            "Export a baked stage (STAGE.lightmaps.usda) as glTF 2.0: triangulated meshes, "
            "UsdPreviewSurface as PBR, the lightmap UVs as TEXCOORD_1 and the directional "
            "lightmaps in the USDAHD_lightmap_directional extension (docs/gltf.md)."
        ),
    )
    p.add_argument("format", choices=("gltf",), help="output format (gltf: .glb or .gltf)")
    p.add_argument("stage", help="baked layer (STAGE.lightmaps.usda)")
    p.add_argument("-o", "--output", required=True, help=".glb (one file) or .gltf (+ .bin)")
    p.add_argument(
        "--hdr",
        choices=("rgbm", "rgbe"),
        default="rgbm",
        help="8-bit PNG encoding of the float16 lightmap textures (default rgbm; docs/gltf.md "
        "lists the error each adds)",
    )
    p.add_argument(
        "--baked-only",
        action="store_true",
        help="export only the baked meshes (default: also the visible meshes without a bake, "
        "e.g. instances and ahdLightmap:bake = false occluders, as plain meshes)",
    )
    p.add_argument(
        "--instancing",
        choices=("gpu", "nodes"),
        default="gpu",
        help="PointInstancer copies: gpu = EXT_mesh_gpu_instancing nodes with per-instance "
        "lightmap scale/offset and page (default); nodes = one node per copy, for engines "
        "without the extension (copies share one mesh either way; docs/gltf.md)",
    )
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from usdahd.export.gltf import export

    if not args.quiet:
        print(f"usdahd export: reading {args.stage}", file=sys.stderr)
    report = export(
        args.stage,
        args.output,
        hdr=args.hdr,
        unbaked=not args.baked_only,
        instancing=args.instancing,
    )

    def human():
        print(
            f"{report['output']}: {report['nodes']} baked meshes (+{report['unbaked_nodes']} "
            f"without a bake; {report['instances']} of them in {report['instanced_nodes']} "
            f"instanced nodes), {report['meshes']} glTF meshes, {report['pages']} lightmap "
            f"pages ({', '.join(report['models'])}), {report['bytes']} bytes; {report['hdr']} "
            f"adds relRMSE {report['hdr_relrmse']:.3%} to the float16 textures"
        )

    emit(args, report, human)
    return 0
