"""``usdahd bake STAGE``: bake lightmaps and author AhdLightmapAPI in an override layer."""

from __future__ import annotations

import argparse
import sys

from usdahd import models
from usdahd.commands.output import emit
from usdahd.errors import UsageError


def add_parser(sub):
    p = sub.add_parser(
        "bake",
        help="bake directional lightmaps for a USD stage",
        description=(
            "Bake per-texel SH radiance for the meshes of a USD stage with Embree, fit a "
            "directional lightmap model, write the textures under lightmaps/ beside the output "
            "layer, and author AhdLightmapAPI on each mesh in an override layer that sublayers "
            "the stage (the source layer is never modified). Meshes carrying the API with bake "
            "enabled are baked; if none carry it, every visible mesh is. Re-running skips prims "
            "whose inputs did not change. Everything that can fail is checked before tracing "
            "(--dry-run runs the checks and reports the texel total). Textures get new "
            "content-addressed names and the layer's atomic replace commits the bake, so a "
            "killed or failed bake leaves the previous one valid; a second bake of the same "
            "output waits for the first, up to --lock-timeout (lock file .LAYER.lock beside "
            "the layer while a bake runs)."
        ),
    )
    a = p.add_argument
    a("stage", help="USD stage to bake (.usda/.usdc/.usd)")
    a("-o", "--output", help="override layer to write (default STAGE_STEM.lightmaps.usda)")
    a("--prim", action="append", metavar="PATH", help="bake only this prim (repeatable)")
    a("--model", choices=list(models.REGISTRY), help="lighting model (default hhd)")
    a("--ratio", help="luminance|rgb (IrradZ models); linear|nonlinear|8bit (sh_l1)")
    a("--solver", help="solver (default: the model's)")
    a("--uv", metavar="PRIMVAR", help="lightmap UV primvar name (default st)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resolution", type=int, metavar="N", help="lightmap size N x N per mesh")
    g.add_argument(
        "--texel-density",
        type=float,
        metavar="T",
        help="texels per metre for every prim (default: automatic, from --texel-budget)",
    )
    a(
        "--texel-budget",
        type=int,
        metavar="N",
        help="texels the automatic density spreads over the stage by surface area (default "
        "1048576 = 1024^2; at most 16 texels/m, or 128 texels across a stage under 8 m; each "
        "map at least 32x32; docs/texels.md)",
    )
    a("--samples", type=int, metavar="N", help="hemisphere samples per texel (default 256)")
    a(
        "--bounces",
        type=int,
        metavar="N",
        help="cap on reflections per path (default 64; paths end by unbiased Russian roulette, "
        "so the default is converged; a small N truncates indirect light)",
    )
    a("--seed", type=int, default=0, help="random seed (default 0)")
    a(
        "--time",
        metavar="T",
        help="time code every attribute is read at, or 'default' (default: the stage's "
        "startTimeCode when anything the bake reads is animated, else the default time)",
    )
    a(
        "--scenario",
        metavar="NAME",
        help="bake the lighting scenario selected by a variant of the stage: NAME, SET=NAME or "
        "/Prim{SET=NAME}; writes STAGE.NAME.lightmaps.usda, which selects the same variant "
        "(docs/schema.md, 'Lighting scenarios')",
    )
    a("--padding", type=int, metavar="N", help="gutter dilation in texels (default 4)")
    a("--adaptive", action="store_true", help="stop sampling texels whose SH converged")
    a(
        "--denoise",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="denoise the SH with Intel Open Image Denoise, trusted only as far as the "
        "integrator's own noise estimate allows (default; docs/texels.md); --no-denoise "
        "writes the integrator's estimate as it is",
    )
    a(
        "--container",
        choices=["files", "ktx2", "ktx2-bc"],
        help="files: EXR/PNG textures (default); ktx2: also a KTX2 per texture with a "
        "chart-aware mip chain, lossless (RGBA8 / RGBA16F); ktx2-bc: the same compressed where it "
        "holds: BC6H for HDR within 1.5 %% of the values (else E5B9G9R9), BC7 for 8-bit data "
        "except direction / ratio codes (RGBA8) (needs usdahd[ktx2]; docs/schema.md, error per "
        "model in docs/benchmarks.md)",
    )
    a(
        "--atlas",
        choices=["on", "off"],
        default="on",
        help="on (default): pack every prim's lightmap into shared power-of-two atlas pages, "
        "each record authoring its page and a UV scale/offset (docs/schema.md, 'Atlas'); "
        "off: one set of textures per prim",
    )
    a(
        "--atlas-size",
        type=int,
        metavar="N",
        help="largest atlas page side, a power of two (default 2048); a page shrinks to the "
        "smallest power of two holding its rectangles",
    )
    a(
        "--atlas-padding",
        type=int,
        metavar="N",
        help="texels between two rectangles of a page, >= 2 (default: --padding, else 4)",
    )
    a(
        "--no-unwrap",
        action="store_true",
        help="fail on meshes without the UV set instead of unwrapping them with xatlas",
    )
    d = p.add_mutually_exclusive_group()
    d.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="trace in tiles on a local Dask cluster of N worker processes; the outputs are "
        "identical to a plain bake (needs usdahd[distributed]; docs/scaling.md)",
    )
    d.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="trace in tiles on the existing Dask cluster whose scheduler is at ADDRESS "
        "(tcp://HOST:8786); workers need the same usdahd version (docs/scaling.md)",
    )
    a(
        "--lock-timeout",
        type=float,
        metavar="SECONDS",
        help="give up (exit 2) when another bake of the same output still holds its lock "
        "after SECONDS (default 3600: 3x the longest real-scene bake measured, so a healthy "
        "bake is waited for and a hung or stopped one frees a farm slot within the hour; 0: "
        "do not wait; inf: wait as long as it takes)",
    )
    a("--force", action="store_true", help="re-bake prims even if unchanged")
    a("--dry-run", action="store_true", help="report what would be baked; write nothing")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from usdahd.pipeline import BakeOptions, bake

    for flag, low in (("samples", 1), ("resolution", 1), ("bounces", 0), ("padding", 0)):
        v = getattr(args, flag)
        if v is not None and v < low:
            raise UsageError(f"--{flag} must be >= {low}, got {v}")
    from usdahd.pipeline import MAX_RESOLUTION

    if args.resolution is not None and args.resolution > MAX_RESOLUTION:
        raise UsageError(
            f"--resolution {args.resolution} exceeds the maximum {MAX_RESOLUTION} "
            f"({args.resolution}^2 texels of SH would need "
            f"{args.resolution**2 * 27 * 4 / 2**30:.0f} GiB); bake at most {MAX_RESOLUTION}"
        )
    if args.lock_timeout is not None and not args.lock_timeout >= 0:
        raise UsageError(
            f"--lock-timeout must be >= 0 seconds (inf waits forever), got {args.lock_timeout}"
        )
    if args.texel_density is not None and not args.texel_density > 0:
        raise UsageError(f"--texel-density must be > 0, got {args.texel_density}")
    from usdahd.usd.time import parse_time

    try:
        time = parse_time(args.time)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    opts = BakeOptions(
        time=time,
        scenario=args.scenario,
        output=args.output,
        prims=args.prim,
        model=args.model,
        ratio=args.ratio,
        solver=args.solver,
        uv=args.uv,
        resolution=args.resolution,
        texel_density=args.texel_density,
        texel_budget=args.texel_budget,
        samples=args.samples,
        bounces=args.bounces,
        seed=args.seed,
        padding=args.padding,
        adaptive=args.adaptive,
        denoise=args.denoise,
        container=args.container,
        unwrap=not args.no_unwrap,
        force=args.force,
        dry_run=args.dry_run,
        quiet=args.quiet,
        workers=args.workers,
        scheduler=args.scheduler,
        lock_timeout=args.lock_timeout,
        atlas=args.atlas == "on",
        atlas_size=args.atlas_size,
        atlas_padding=args.atlas_padding,
    )
    report = bake(args.stage, opts)
    quiet = int(args.quiet or 0)
    emit(args, report, lambda: _print_report(report, notes=quiet == 0))
    if not args.json and quiet == 1:
        # --quiet keeps the per-prim results on stdout and hides progress; warnings go to
        # stderr (-qq hides them and the results too).
        for w in _all_warnings(report):
            print(f"warning: {w}", file=sys.stderr)
    # Failures reach stderr even with --quiet or --json: CI logs must show why it exited 1.
    for p in report["prims"]:
        if p.get("status") == "failed":
            kept = "; its previous bake is kept" if p.get("previous_kept") else ""
            print(f"usdahd bake: error: {p['error']}{kept}", file=sys.stderr)
    return report["exit_code"]


def _all_warnings(report) -> list[str]:
    out = []
    for p in report["prims"]:
        out += [w if p["path"] in w else f"{p['path']}: {w}" for w in p.get("warnings", [])]
    return out + list(report.get("warnings", []))


def _print_report(report, notes: bool = True) -> None:
    """The result lines; ``notes`` False (-q): without the warnings and notes (stderr has
    the warnings)."""
    planned = 0
    for p in report["prims"]:
        if p["status"] == "skipped":
            print(f"{p['path']}: unchanged, skipped")
        elif p["status"] == "kept":
            print(f"{p['path']}: not selected, previous bake kept")
        elif p["status"] == "failed":
            print(f"{p['path']}: FAILED (see stderr)")
        elif p["status"] == "planned":
            planned += 1
            w, h = p["resolution"]
            print(f"{p['path']}: would bake {w}x{h} = {w * h} texels ({p.get('reason', '')})")
        else:
            print(
                f"{p['path']}: {p['texels']} texels, {p['rays']} rays, {p['seconds']:.2f}s"
                + (
                    f", Iz max rel err {p['iz_max_rel_error']:.2e}"
                    if "iz_max_rel_error" in p
                    else ""
                )
            )
        for w in p.get("warnings", []) if notes else []:
            print(f"  warning: {w}")
        for n in p.get("notes", []) if notes else []:
            print(f"  note: {n}")
    for w in report.get("warnings", []) if notes else []:
        print(f"warning: {w}")
    for n in report.get("notes", []) if notes else []:
        print(f"note: {n}")
    for page in report.get("atlas", {}).get("pages", []) if report.get("dry_run") else []:
        W, H = page["size"]
        print(
            f"atlas: would write a {W}x{H} page of {len(page['records'])} record(s) "
            f"({100 * page['rect_fill']:.0f}% of it rectangles)"
        )
    if planned or "texels_total" in report and report.get("dry_run"):
        total = report.get("texels_total", 0)
        print(
            f"dry run: {planned} prim(s) to bake, {total} texels in total "
            f"(about {report.get('memory_estimate_bytes', 0) / 2**20:.0f} MiB while baking); "
            "every pre-flight check passed"
        )
    if report.get("output"):
        if report.get("dry_run"):
            state = "would be replaced" if report.get("output_exists") else "would be created"
            if not planned:
                state = "unchanged"
        elif report.get("written"):
            state = "written"
        else:
            state = "unchanged"
        print(f"output layer: {report['output']} ({state})")
