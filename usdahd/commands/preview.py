"""``usdahd preview``: render the baked lighting of a stage as an engine would (issue 14).

Rasterises every baked mesh through wgpu (Vulkan: Mesa's lavapipe on the CPU, or a GPU) with the
shipped WGSL decoders (``usdahd/shaders/``, :mod:`usdahd.preview.gpu`) from a UsdGeomCamera or
an automatic framing (:mod:`usdahd.preview.camera`). The result is normalized
irradiance (a white Lambertian surface's radiance times pi); the PNG is tone-mapped (auto
exposure on the 99th percentile, sRGB), ``--json`` prints linear statistics.

Back faces are culled (closed rooms open towards the camera). Without a Vulkan adapter
``--backend auto`` falls back to Embree primary rays + the numpy decoders
(:mod:`usdahd.preview.raytrace`, which culls the same faces); one stderr line says what to install.

``--compare`` traces a reference of the same view with the baker's integrator at each pixel's
visible point and writes preview | reference | error heat map side by side
(:mod:`usdahd.preview.compare`).

``--atlas`` writes a contact sheet of the textures instead (:mod:`usdahd.preview.atlas`).

``--model-view`` shades as an engine's diffuse pass: albedo (UsdPreviewSurface
``diffuseColor``) times the irradiance evaluated at the material's normal-mapped normal
(``inputs:normal``), :mod:`usdahd.preview.surface`.

``--ahd-classic`` imports an ahd/hhd/ahd_classic bake as classic AHD textures (C_a, d, C_d at
the texel centres, filtered independently), the naive import whose lit-to-shadowed overshoot the
2018 IrradZ paper fixes (:mod:`usdahd.preview.classic`).

This module is the command only (arguments, usage errors, the report); the rendering lives in
:mod:`usdahd.preview`.
"""

from __future__ import annotations

import sys
from pathlib import Path

from usdahd.commands.output import emit
from usdahd.errors import StageError, UsageError
from usdahd.preview.camera import auto_camera, usd_camera, view_projection
from usdahd.preview.gpu import device, render, request_adapter
from usdahd.preview.meshes import baked_meshes, draw_items, render_view, vertex_data
from usdahd.preview.tonemap import stats, tonemap, tonemap_with

#: The rendering lives in usdahd.preview; these names stay importable from the command.
__all__ = [
    "add_parser",
    "auto_camera",
    "baked_meshes",
    "device",
    "render",
    "request_adapter",
    "run",
    "usd_camera",
    "vertex_data",
]

#: Default reference samples per pixel of --compare.
COMPARE_SAMPLES = 256


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
        "--model-view",
        action="store_true",
        help="shade as an engine would: the material's albedo (UsdPreviewSurface diffuseColor, "
        "constant or texture) times the baked irradiance evaluated at the normal-mapped normal "
        "(inputs:normal connected to a UsdUVTexture); the image is then radiance x pi",
    )
    p.add_argument(
        "--ahd-classic",
        action="store_true",
        help="import the bake as an engine storing classic AHD textures would (ahd, hhd and "
        "ahd_classic bakes): C_a, the unit direction d and C_d decoded at the texel centres, "
        "filtered by the sampler independently, d renormalised (the 2018 paper's interpolation "
        "artefact; default: the IrradZ decode after filtering)",
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
    c.add_argument(
        "--compare-footprint",
        type=int,
        metavar="S",
        help="shade S x S sub-pixel points per pixel in both images and compare pixel averages "
        "(the same footprint, as an anti-aliased render; the samples are split over the points; "
        "default 2; 1: one point at each pixel centre)",
    )
    c.add_argument("--seed", type=int, help="seed of the reference (default 0)")
    p.set_defaults(func=run)
    return p


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
        flags = (
            ("--camera", args.camera),
            ("--size", args.size),
            ("--compare", args.compare or None),
            ("--model-view", args.model_view or None),
            ("--ahd-classic", args.ahd_classic or None),
        )
        given = [f for f, v in flags if v is not None]
        if given:
            raise UsageError(
                f"{given[0]} does not apply to --atlas (a sheet of the textures, not a view); "
                "drop one of them"
            )
    if args.compare and args.model_view:
        raise UsageError(
            "--compare checks the baked irradiance against a path-traced irradiance; "
            "--model-view multiplies it by the albedo and bends it with the normal map, which "
            "the reference does not: drop one of them"
        )
    if not args.compare:
        given = [
            a
            for a in ("compare_samples", "compare_bounces", "compare_footprint", "seed")
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
    if args.compare:
        _footprint(args)
    return out


def _composition_warnings(args, stage) -> None:
    """The stage's composition problems, once each on stderr (not with -qq): the preview
    draws what composed (a broken arc in an unselected variant changes nothing it shows)."""
    if int(args.quiet or 0) >= 2:
        return
    from usdahd.usd.stage import composition_warnings

    def warn(msg):
        print(f"usdahd preview: warning: {msg}", file=sys.stderr)

    composition_warnings(stage, str(args.stage), warn)


def run_atlas(args, out: Path) -> int:
    """``--atlas``: the contact sheet (:mod:`usdahd.preview.atlas`)."""
    from usdahd import images
    from usdahd.preview import atlas
    from usdahd.validate.run import validate_file

    stage, meshes, _ = baked_meshes(args.stage)
    _composition_warnings(args, stage)
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

    def human():
        print(
            f"{out}: {img.shape[1]}x{img.shape[0]} contact sheet, {len(meshes)} prims, "
            f"{len(info['tiles'])} textures, {len(info['flagged'])} texel(s) flagged by validate"
        )

    emit(args, report, human)
    return 0


def _footprint(args) -> int:
    """--compare-footprint (default usdahd.preview.compare.FOOTPRINT), checked against the
    samples before any work."""
    from usdahd.preview import compare

    fp = compare.FOOTPRINT if args.compare_footprint is None else args.compare_footprint
    samples = COMPARE_SAMPLES if args.compare_samples is None else args.compare_samples
    compare.points_per_pixel(samples, fp)  # UsageError: a bad footprint or too few samples
    return fp


def run(args) -> int:
    from usdahd import images

    out = _check(args)
    if args.atlas:
        return run_atlas(args, out)
    w, h = args.size or (640, 480)
    gpu = None if args.backend == "embree" else device(args.backend)  # before any long work
    summary = gpu[0].summary if gpu else "embree (primary rays, numpy decoders)"
    if not args.quiet:
        print(f"usdahd preview: {summary}", file=sys.stderr)
    stage, meshes, up = baked_meshes(args.stage)
    _composition_warnings(args, stage)
    viewproj = view_projection(stage, meshes, up, args.camera, w / h)
    surfaces = None
    if args.model_view:
        from usdahd.preview.surface import surfaces as read_surfaces

        surfaces = read_surfaces(stage, meshes)
    cuts = None
    if gpu:  # the rasteriser needs the opacity the tracer reads (Embree honours it itself)
        from usdahd.preview.cutout import cutouts

        cuts = cutouts(stage, meshes)
    items = draw_items(meshes, surfaces, ahd_classic=args.ahd_classic, cutouts=cuts)
    # --compare shades S x S sub-pixel points per pixel (the pixel centres of an image S times
    # the size) in both images and compares pixel averages (usdahd.preview.compare)
    fp = _footprint(args) if args.compare else 1
    image = render_view(
        stage, meshes, items, viewproj, (w * fp, h * fp), gpu[1] if gpu else None,
        surfaces=surfaces, ahd_classic=args.ahd_classic,
    )  # fmt: skip
    compared = None
    if args.compare:
        from usdahd.preview import compare

        def progress(line):
            if not args.quiet:
                print(f"usdahd preview: {line}", file=sys.stderr)

        samples = COMPARE_SAMPLES if args.compare_samples is None else args.compare_samples
        ref = compare.reference(
            stage,
            meshes,
            viewproj,
            (w * fp, h * fp),
            samples=compare.points_per_pixel(samples, fp),
            seed=args.seed or 0,
            bounces=args.compare_bounces,
            progress=progress,
        )
        image, ref_image, st = compare.footprint_stats(image, ref, fp)
        info = dict(ref.info, samples=ref.info["samples"] * fp * fp)
        info["samples_per_point"] = ref.info["samples"]
        compared = {**info, **st}
        ldr, scale = tonemap(image, args.exposure)
        ldr = compare.side_by_side(
            ldr, tonemap_with(ref_image, scale), compare.heat_map(image, ref_image)
        )  # the reference at the preview's exposure: the two panels compare by eye
    else:
        ldr, scale = tonemap(image, args.exposure)
    images.write(out, ldr, color_space="srgb_rec709_scene")
    report = {
        "stage": str(args.stage),
        "output": str(out),
        "size": [w, h],
        "camera": args.camera or "auto",
        "adapter": summary,
        "backend": "wgpu" if gpu else "embree",
        "meshes": len(meshes),
        "models": sorted({f"{res.model}/{res.ratio}" for _, res, *_ in meshes}),
        "model_view": bool(args.model_view),
        "ahd_classic": bool(args.ahd_classic),
        "exposure_scale": scale,
        **stats(image),
    }
    if compared is not None:
        report["compare"] = compared

    def human():
        lum = report.get("luminance", {})
        print(
            f"{out}: {w}x{h}, {len(meshes)} meshes, covered {report['covered_fraction']:.1%}, "
            f"mean irradiance {lum.get('mean', 0.0):.4g} (p99 {lum.get('p99', 0.0):.4g})"
        )
        if compared is not None and compared["relrmse"] is not None:
            print(
                f"  vs path-traced reference ({compared['samples']} samples, "
                f"{compared['bounces']} bounces): relRMSE {compared['relrmse']:.2%}, bias "
                f"{compared['bias']:+.2%}, reference noise {compared['reference_noise']:.2%}"
            )
            fp = compared["footprint"]
            parts = [f"  {fp}x{fp} points per pixel (point by point: "
                     f"{compared['relrmse_subsamples']:.2%})"]  # fmt: skip
            for name in ("interior", "edge"):
                if compared[f"{name}_relrmse"] is not None:
                    parts.append(
                        f"{name} {compared[f'{name}_pixels']} px {compared[f'{name}_relrmse']:.2%}"
                    )
            if compared["edge_error_share"] is not None:
                parts.append(f"edge share of the squared error {compared['edge_error_share']:.0%}")
            print(", ".join(parts))

    emit(args, report, human)
    return 0
