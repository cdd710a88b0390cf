"""Regenerate docs/benchmarks.md and its plots from scratch on this machine.

    python benchmarks/run.py            # full run: ~62 min on 2 cores (2026-12-05) before
                                        # the 32^2 half, of which the reference section
                                        # (usdahd vs Cycles at 128^2) took ~52 with Cycles'
                                        # truths cached; its 32^2 half (issue 43) adds ~15;
                                        # each stage's uncached truths add minutes to ~45 min
                                        # (Cornell boxes at 128^2): they are read from
                                        # benchmarks/reference/truths/ when kept there
                                        # (`reference_bench.py --truths-only --store`)
    python benchmarks/run.py --reference-stages cornell_box floor_lamp   # a subset of stages
    python benchmarks/run.py --quick    # ~2-3 min: fewer samples, texels and repeats
    usdahd bench [--quick]              # the same (or usdahd-bench): pip install -e benchmarks/

Sections (issue 7): 1 bake run time against error, 2 fit speed and error per model x solver,
3 encodings side by side after quantization, 4 what skipping saves, and a soak of random and
adversarial texels through every model. Converged reference bakes are cached in
benchmarks/cache/ (gitignored); ``--fresh`` recomputes them.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bake_sweep  # noqa: E402
import common  # noqa: E402
import encoding_bench as encodings  # noqa: E402
import soak  # noqa: E402
from common import (  # noqa: E402
    CACHE,
    DOCS,
    log,
    machine_facts,
    md_table,
    sample_scenes,
)

from usdahd.errors import UsageError  # noqa: E402


@dataclass(frozen=True)
class Plan:
    """How much of everything to run (see PLANS)."""

    resolution: int  # bake sweep lightmap side
    spps: tuple[int, ...]  # samples per texel swept
    ref_samples: int  # per reference seed
    repeats: int  # bakes per point (medians)
    enc_resolution: int  # bakes used for the encodings and the "baked samples" fit family
    enc_samples: int
    fit_texels: int  # per synthetic family
    speed_texels: int
    speed_repeats: int
    soak_texels: int
    skip_repeats: int


PLANS = {
    "full": Plan(
        resolution=24,
        spps=(16, 32, 64, 128, 256, 512, 1024),
        ref_samples=8192,
        repeats=3,
        enc_resolution=32,
        enc_samples=512,
        fit_texels=2000,
        speed_texels=200_000,
        speed_repeats=3,
        soak_texels=1_000_000,
        skip_repeats=3,
    ),
    "quick": Plan(
        resolution=16,
        spps=(16, 64, 256),
        ref_samples=2048,
        repeats=1,
        enc_resolution=32,
        enc_samples=256,
        fit_texels=300,
        speed_texels=20_000,
        speed_repeats=1,
        soak_texels=100_000,
        skip_repeats=1,
    ),
}

DEFAULT_SECTIONS = "bake,fit,encodings,skipping,soak,ktx2,reference"

#: Scene and prim whose per-texel error maps are plotted (section 3).
ERROR_MAP_SCENE = "cornell_box"
ERROR_MAP_PRIM = "/World/Geometry/Floor"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(ap)
    return ap.parse_args(argv)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options shared by this script and ``usdahd bench``."""
    ap.add_argument("--quick", action="store_true", help="~2-3 minute run (fewer samples)")
    ap.add_argument(
        "--out",
        default=str(DOCS / "benchmarks.md"),
        help="markdown report to write (plots go to <its folder>/benchmarks/)",
    )
    ap.add_argument(
        "--sections",
        default=DEFAULT_SECTIONS,
        help="comma-separated subset of bake,fit,encodings,skipping,soak,ktx2,reference "
        "(reference: usdahd vs Blender Cycles; needs $USDAHD_BPY_PYTHON, see "
        "benchmarks/reference/README.md)",
    )
    ap.add_argument(
        "--reference-stages",
        nargs="+",
        metavar="STAGE",
        help="the reference section's stages by file stem (default: every lit sample stage and "
        "the shared Cornell boxes), e.g. to leave out one whose Cycles truths are not cached yet",
    )
    ap.add_argument(
        "--fresh", action="store_true", help="delete cached reference bakes first (from scratch)"
    )
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def _encoding_bakes(scenes, plan: Plan) -> dict:
    """One bake per scene at enc_resolution (cached like references, one seed)."""
    out = {}
    for stage in scenes:
        ref = bake_sweep.reference(
            stage, resolution=plan.enc_resolution, samples=plan.enc_samples, seeds=(2001,)
        )
        out[stage.stem] = ref["sh"]
    return out


def check_args(args) -> set[str]:
    """The sections ``args`` selects; UsageError for an unknown section or reference stage, or
    ``--reference-stages`` without the reference section (before any work starts)."""
    sections = {s.strip() for s in args.sections.split(",") if s.strip()}
    unknown = sections - set(DEFAULT_SECTIONS.split(","))
    if unknown:
        raise UsageError(
            f"unknown --sections {', '.join(sorted(unknown))}; "
            f"choose from {DEFAULT_SECTIONS.replace(',', ', ')}"
        )
    ref_stages = getattr(args, "reference_stages", None)
    if ref_stages and "reference" not in sections:
        raise UsageError(
            "--reference-stages picks the reference section's stages, but --sections "
            f"{args.sections} leaves that section out; add reference to --sections"
        )
    if "reference" in sections:
        import reference_bench

        reference_bench.section_stages(ref_stages)  # an unknown name raises
    return sections


def run(args) -> Path:
    """Run the selected sections and write the report; returns its path."""
    plan_name = "quick" if args.quick else "full"
    plan = PLANS[plan_name]
    sections = check_args(args)
    ref_stages = getattr(args, "reference_stages", None)
    common.VERBOSE = not getattr(args, "quiet", False)
    out = Path(args.out)
    plots = out.parent / "benchmarks"
    if args.fresh and CACHE.is_dir():
        shutil.rmtree(CACHE)
    t_start = time.perf_counter()
    facts = machine_facts()
    scenes = sample_scenes()
    timings = {}
    results = {}
    md = []

    def timed_section(name, fn):
        t0 = time.perf_counter()
        log(f"section {name} ...")
        value = fn()
        timings[name] = time.perf_counter() - t0
        log(f"section {name}: {timings[name]:.0f}s")
        return value

    configs = list(bake_sweep.CONFIGS)
    no_denoise = bake_sweep.denoise_available()
    if no_denoise:
        configs = [c for c in configs if not c.denoise]

    if "bake" in sections or "skipping" in sections:
        results["bake"] = timed_section(
            "bake",
            lambda: bake_sweep.sweep(
                scenes,
                resolution=plan.resolution,
                spps=plan.spps,
                configs=configs,
                repeats=plan.repeats,
                ref_samples=plan.ref_samples,
            ),
        )
        bake_sweep.pareto_plot(results["bake"], plots_dir=plots)
    baked = None
    if {"fit", "encodings"} & sections:
        baked = timed_section("encoding bakes", lambda: _encoding_bakes(scenes, plan))
    if "fit" in sections:

        def fit_section():
            fams = encodings.synthetic_families(plan.fit_texels)
            fams["baked samples"] = encodings.baked_family(baked, max(plan.fit_texels, 1000))
            return encodings.fit_table(
                fams, speed_texels=plan.speed_texels, repeats=plan.speed_repeats
            )

        results["fit"] = timed_section("fit", fit_section)
    if "encodings" in sections:
        results["encodings"] = timed_section("encodings", lambda: encodings.encodings_table(baked))
        encodings.encodings_plot(results["encodings"], plots_dir=plots)
        if ERROR_MAP_SCENE in baked and ERROR_MAP_PRIM in baked[ERROR_MAP_SCENE]:
            img, mask = baked[ERROR_MAP_SCENE][ERROR_MAP_PRIM]
            ref_iz = bake_sweep.lum_iz({ERROR_MAP_PRIM: (img, mask)})
            ref_img = mask.astype(float) * 0.0
            ref_img[mask] = ref_iz
            ref_img[~mask] = float("nan")
            encodings.error_maps_plot(
                results["encodings"],
                ERROR_MAP_SCENE,
                ERROR_MAP_PRIM,
                ref_img,
                "encoding_errors.png",
                plots_dir=plots,
            )
    if "skipping" in sections:
        results["skipping"] = timed_section(
            "skipping",
            lambda: [
                bake_sweep.incremental(
                    s,
                    resolution=plan.enc_resolution,
                    samples=plan.spps[-1] // 4,
                    repeats=plan.skip_repeats,
                )
                for s in scenes
            ],
        )
    if "soak" in sections:
        results["soak"] = timed_section("soak", lambda: soak.soak(plan.soak_texels))
    if "ktx2" in sections:
        import ktx2_bench

        results["ktx2"] = timed_section("ktx2", ktx2_bench.run)
    if "reference" in sections:
        import reference_bench

        results["reference"] = timed_section(
            "reference", lambda: reference_bench.run_section(plan_name, plots, stages=ref_stages)
        )
    total = time.perf_counter() - t_start

    md.append(report_header(facts, plan_name, plan, total, timings, no_denoise, command(args)))
    md.append(section_summary(results))
    if "bake" in results:
        md.append(section_bake(results["bake"], plan, no_denoise))
    if "fit" in results:
        md.append(section_fit(results["fit"], plan))
    if "encodings" in results:
        md.append(section_encodings(results["encodings"], plan))
    if "skipping" in results:
        md.append(section_skipping(results, plan))
    if "soak" in results:
        md.append(section_soak(results["soak"]))
    if "ktx2" in results:
        import ktx2_bench

        md.append(ktx2_bench.section(results["ktx2"]))
    if "reference" in results:
        import reference_bench

        md.append(reference_bench.section(results["reference"]))
    out.parent.mkdir(parents=True, exist_ok=True)
    md += kept_blocks(out.read_text() if out.exists() else "")
    out.write_text("\n\n".join(md).rstrip() + "\n")
    raw = CACHE / f"results-{plan_name}.json"
    CACHE.mkdir(parents=True, exist_ok=True)
    raw.write_text(json.dumps(_jsonable(results), indent=1))
    log(f"wrote {out} and {plots}/*.png in {total:.0f}s (raw numbers: {raw})")
    return out


def _jsonable(obj):
    if isinstance(obj, dict):
        return {
            (k if isinstance(k, str) else " ".join(map(str, k))): _jsonable(v)
            for k, v in obj.items()
            if k not in ("maps", "sh", "layer")
        }
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "item"):
        return obj.item()
    return obj


# ----------------------------------------------------------------------------------- report


def command(args) -> str:
    """The command line that reproduces this run's report (the options that change it)."""
    cmd = ["python benchmarks/run.py"]
    if args.quick:
        cmd.append("--quick")
    if args.sections != DEFAULT_SECTIONS:
        cmd.append(f"--sections {args.sections}")
    if getattr(args, "reference_stages", None):
        cmd.append("--reference-stages " + " ".join(args.reference_stages))
    return " ".join(cmd)


def report_header(facts, plan_name, plan, total, timings, no_denoise, cmd=None) -> str:
    rows = [[k, str(v)] for k, v in facts.items()]
    rows.append(["run", f"{plan_name} ({total / 60:.1f} min)"])
    rows.append(["section wall times", ", ".join(f"{k} {v:.0f}s" for k, v in timings.items())])
    if cmd is None:
        cmd = "python benchmarks/run.py" + (" --quick" if plan_name == "quick" else "")
    return "\n".join(
        [
            "# Benchmarks: run time against error",
            "",
            f"Generated by `{cmd}` (or `usdahd bench`) on {facts['date']}; every number below "
            "was measured in that one run on the machine described here. Regenerate with the "
            "same command (`--quick` for a ~2-3 minute run, `--fresh` to recompute the cached "
            "reference bakes too). The machine is shared, so wall times are medians over "
            "repeats and comparisons are ratios measured in the same run.",
            "",
            md_table(["machine", ""], rows),
        ]
    )


def section_summary(results) -> str:
    """The headline numbers of this run, computed from the sections below."""
    lines = ["## Summary (numbers from this run)", ""]
    if "bake" in results:
        rows = results["bake"]["rows"]
        top = max(r["spp"] for r in rows)
        for scene in dict.fromkeys(r["scene"] for r in rows):
            at = {r["config"]: r for r in rows if r["scene"] == scene and r["spp"] == top}
            parts = [f"{c} {at[c]['rel_rmse']:.3g} in {at[c]['seconds']:.2g} s" for c in at]
            noise = results["bake"]["references"][scene]["noise_rel"]
            lines.append(
                f"- Bake `{scene}` at {top} spp, I_z relative RMSE: "
                + "; ".join(parts)
                + f" (reference noise {noise:.2g})."
            )
    if "encodings" in results:
        enc = results["encodings"]["rows"]

        def mean_q(r):
            return sum(r["quantized"].values()) / len(r["quantized"])

        small = [r for r in enc if r["bytes"] <= 12]
        if small:
            best = min(small, key=mean_q)
            lines.append(
                f"- Best encoding at <= 12 bytes/texel on the baked samples: {best['model']} "
                f"{best['ratio']} ({best['bytes']} B), relative hemispherical RMSE "
                "(pooled_rmse_over_rms) "
                f"{mean_q(best):.3g} after quantization."
            )
    if "skipping" in results:
        saved = [1 - r["second_s"] / r["first_s"] for r in results["skipping"]]
        rays = max(r["rays_second"] for r in results["skipping"])
        lines.append(
            f"- Unchanged re-bake: {rays:,.0f} rays traced (largest over the samples), "
            f"{100 * min(saved):.0f}-{100 * max(saved):.0f} % of the first bake's wall time saved."
        )
    if "soak" in results:
        bad = [r for r in results["soak"]["rows"] if r["nonfinite_total"]]
        n = results["soak"]["texels"]
        if bad:
            names = ", ".join(f"{r['model']} {r['ratio']}" for r in bad)
            cats = sorted({c for r in bad for c in r["nonfinite_where"]})
            lines.append(
                f"- **Soak: non-finite outputs (must be 0)** in {names} "
                f"(categories: {', '.join(cats)}); every other model: 0 of {n:,} texels."
            )
        else:
            lines.append(f"- Soak: 0 non-finite values in {n:,} texels through every model.")
    if "reference" in results:
        import reference_bench

        by_size = {
            one["args"]["resolution"]: reference_bench.time_to_quality(one["rows"])
            for one in reference_bench.size_results(results["reference"])
        }
        lines += reference_summary(by_size)
    return "\n".join(lines)


#: Issue 43's time-to-quality targets: usdahd's time to Cycles' 1024-spp error over Cycles'
#: time, per lightmap size per mesh (other sizes: no target).
REFERENCE_TARGETS = {128: 0.1, 32: 0.3}


def reference_summary(by_size: dict[int, list[dict]]) -> list[str]:
    """Summary lines of the reference section, one per usdahd timing (the command, warm): the
    largest ratio of usdahd's time to Cycles' to reach Cycles' 1024-spp error at EACH size, its
    stage, the median, and the size's target where issue 43 sets one; or the stages where
    usdahd does not reach it (``by_size``: {resolution: reference_bench.time_to_quality's
    rows}, in the order the sizes ran)."""
    renderers = dict.fromkeys(t["renderer"] for ttq in by_size.values() for t in ttq)
    lines = []
    for ren in renderers:
        how = "as a call in a running process" if ren.endswith("(warm)") else "as a command"
        flags = ren.removeprefix("usdahd").replace("(warm)", "").strip()
        who = f"usdahd {flags}".strip()
        parts = []
        for res, ttq in by_size.items():
            mine = [t for t in ttq if t["renderer"] == ren]
            if not mine:
                continue
            missed = [t["stage"] for t in mine if t["ratio"] is None]
            reached = [t for t in mine if t["ratio"] is not None]
            target = REFERENCE_TARGETS.get(res)
            goal = f", target <= {target:g}x" if target is not None else ""
            text = f"at {res}²"
            if missed:
                text += f" not reached on {', '.join(missed)}"
                if not reached:
                    parts.append(f"{text}{goal}: **missed**" if goal else text)
                    continue
                text += ";"
            worst = max(reached, key=lambda t: t["ratio"])
            verdict = ""
            if target is not None:
                ok = worst["ratio"] <= target and not missed
                verdict = ": met" if ok else ": **missed**"
            on = f"the {len(reached)} other" if missed else f"{len(reached)}"
            parts.append(
                f"{text} at most {worst['ratio']:.2f}x on {on} stages "
                f"(largest: {worst['stage']}; median "
                f"{statistics.median(t['ratio'] for t in reached):.2f}x{goal}{verdict})"
            )
        if parts:
            lines.append(
                f"- usdahd vs Cycles ({how}), {who}'s time to Cycles' 1024-spp error over "
                "Cycles' time: " + "; ".join(parts) + "."
            )
    return lines


def section_bake(result, plan: Plan, no_denoise) -> str:
    skipped = f"\n\nDenoising was skipped: {no_denoise}" if no_denoise else ""
    return "\n".join(
        [
            "## 1. Bake: run time against error",
            "",
            f"Every sample stage (`samples/*.usda`) baked with `usdahd.pipeline.bake` at "
            f"{plan.resolution} x {plan.resolution} per mesh, default bounces (Russian "
            "roulette, at most 64), for "
            f"{', '.join(map(str, plan.spps))} samples per texel, with and without adaptive "
            f"sampling and OIDN denoising (`--adaptive`, `--denoise`). Each point is the median "
            f"of {plan.repeats} bake(s) with different seeds. *seconds* is the wall time of the "
            "whole `bake()` call (stage, BVH, trace, denoise, stitch, fit, encode, write); "
            "*rays* all rays traced.",
            "",
            "Error: luminance of I_z (normalized irradiance along the normal, from the SH "
            "sidecar) per covered texel against the converged reference of the same scene "
            f"(mean of two bakes at {plan.ref_samples} spp with independent seeds, not denoised), "
            "divided by "
            "the scene's mean reference I_z: relative RMSE, mean (bias) and 99th percentile "
            "of |error|. The reference's own noise (rms of the two seeds' difference / 2, "
            "relative) is listed below and drawn dotted in the plot; errors near it are not "
            "resolved. The reference uses the same integrator, so a bias of the integrator "
            "itself (e.g. the O(1/S) bias of the regression estimator) is not visible here; "
            "the analytic light tests (`tests/bake/test_integrate.py`) cover that.",
            "",
            bake_sweep.sweep_markdown(
                result, resolution=plan.resolution, ref_samples=plan.ref_samples
            ),
            "",
            "![error vs time](benchmarks/bake_pareto.png)" + skipped,
        ]
    )


def section_fit(result, plan: Plan) -> str:
    return "\n".join(
        [
            "## 2. Fit: speed and error per model x solver",
            "",
            f"`usdahd.fit` for every model and solver (the model's default ratio). *Mtexel/s*: "
            f"end-to-end fit of up to {plan.speed_texels:,} tiled sky+sun texels (slow solvers "
            "on fewer, about 2 s per call: *timed on*), median of "
            f"{plan.speed_repeats} after a warm-up, all cores. Other columns: mean over texels "
            "of the relative hemispherical RMSE (`rmse_over_rms` of `usdahd.numerics.stats`: "
            "sqrt of squared error over squared target, per texel) of the fitted model (as "
            "engines evaluate it, "
            "before quantization) against the SH irradiance target, on "
            f"{plan.fit_texels:,} texels of each synthetic family of "
            "`benchmarks/make_sample_sh.py` and on real texels of the baked samples (section "
            "3's bakes); for the black family, the largest |output| (must be 0). "
            "`benchmarks/fit.py` has the SH-domain errors and the issue-2 acceptance ratios.",
            "",
            encodings.fit_markdown(result),
        ]
    )


def section_encodings(result, plan: Plan) -> str:
    return "\n".join(
        [
            "## 3. Encodings side by side on the baked samples",
            "",
            f"Each sample stage baked at {plan.enc_resolution} x {plan.enc_resolution} per mesh, "
            f"{plan.enc_samples} spp; every encoding fitted (default solver) to each mesh's SH, "
            "quantized as written (`encode` -> `decode`: float16 I_z/colours, 8-bit "
            "directions/ratios, per-texture scale factors) and evaluated as an engine does. "
            "Per scene: relative hemispherical RMSE over all its texels, sqrt(sum of squared "
            "error / sum of squared target) (`pooled_rmse_over_rms` of `usdahd.numerics.stats`) "
            "against the SH irradiance of the bake. "
            "*max I_z error*: largest |I(z) - I_z| / max_c |I_z| of any texel after "
            "quantization (the IrradZ models reproduce I_z up to float16 rounding by "
            "construction; the others do not try to). Bytes per texel count every texture "
            "channel the model writes (not the float32 SH sidecar).",
            "",
            encodings.encodings_markdown(result),
            "",
            "![error vs bytes per texel](benchmarks/encodings.png)",
            "",
            f"Per-texel error after quantization on `{ERROR_MAP_SCENE}` {ERROR_MAP_PRIM} "
            "(false colour, shared log scale; default ratio of each model):",
            "",
            "![error maps](benchmarks/encoding_errors.png)",
        ]
    )


def section_skipping(results, plan: Plan) -> str:
    inc = results["skipping"]
    ada = bake_sweep.adaptive_savings(results["bake"]) if "bake" in results else []
    return "\n".join(
        [
            "## 4. Skipping: incremental re-bake and adaptive sampling",
            "",
            f"Incremental: each sample baked at {plan.enc_resolution} x {plan.enc_resolution}, "
            f"{plan.spps[-1] // 4} spp into a fresh output, then `bake()` again on the "
            "unchanged stage into the same output without `force` (medians of "
            f"{plan.skip_repeats}). Every prim's content hash matches, so nothing is traced; "
            "the re-bake still opens the stage, extracts the scene and hashes it. Any change to "
            "geometry, lights or materials re-bakes every prim (each one's lighting depends on "
            "all of them through shadows and bounces); a change of one prim's authored settings "
            "re-bakes only that prim.",
            "",
            "Adaptive: rays and time of `--adaptive` against plain sampling at the same samples "
            "per texel, from section 1 (same run, same seeds); the error ratio shows what the "
            "saved rays cost.",
            "",
            bake_sweep.skipping_markdown(inc, ada),
        ]
    )


def section_soak(result) -> str:
    cats = ", ".join(f"`{c}`" for c in result["categories"])
    return "\n".join(
        [
            "## Soak: random and adversarial texels through every model",
            "",
            f"{result['texels']:,} texels per model and ratio, in equal shares of {cats} "
            "(see `benchmarks/soak.py` for each), through fit (default solver) -> encode -> "
            "decode -> evaluate at z, 1e-6 above the horizon and a random normal. *non-finite*: "
            "texels with any NaN/Inf among the fitted parameters, decoded parameters or "
            "outputs (must be 0), and where it appeared. *worst I_z error (fit)*: "
            "max |I(z) - I_z| / max_c |I_z| before quantization over the non-negative, "
            "float32-representable categories; *(quantized)*: after encode -> decode on "
            "`physical`. Only the IrradZ models (ahd, hhd, hlsh, and ahd_classic before "
            "quantization) and `hemisphere` reproduce I_z by construction; for the linear "
            "bases the number is their truncation error at z, huge relative to a tiny I_z "
            "under a horizon light.",
            "",
            soak.soak_markdown(result),
        ]
    )


def kept_blocks(text: str) -> list[str]:
    """Hand-run sections of the old file (``<!-- BEGIN kept: ... -->`` to ``<!-- END kept
    -->``, e.g. the Cycles comparison through the atlas): a regeneration keeps them, in order."""
    import re

    return re.findall(r"<!-- BEGIN kept:.*?<!-- END kept -->", text, flags=re.S)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        print(run(args))
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
