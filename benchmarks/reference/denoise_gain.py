"""What ``--denoise`` does to the error against the converged truth, per stage and mesh.

``python -m benchmarks.reference.denoise_gain --stages S [S ...] [--samples 16 64 256 1024]
[--seeds 0 1] [--resolution 32] [--truth-spp 4096] [--out FILE.json]``

For every stage, sample count and seed, ``usdahd bake`` runs twice in one warm process
(:class:`benchmarks.reference.warm.WarmBaker`), with ``--no-denoise`` and with ``--denoise``
(the default since 2026-12-04; same seed, so
the same traced radiance), and both are judged against the cached point-sampled Cycles truth
(``compare --point``; baked once if missing). Printed: a markdown table of the relRMSE
ratio denoised / not denoised per stage (mean over seeds) and the worst mesh; the JSON keeps
every mesh's figures. Below 1, denoising helped. Cycles is not run at equal
samples here (the ratio needs only usdahd and the truth), which makes it ~10x faster than
``reference_bench.py --variant=--denoise``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.reference import compare as C
from benchmarks.reference import export, runner
from benchmarks.reference.warm import WarmBaker

SAMPLE_STAGES = "samples/{}.usda"
#: The two bakes compared, each with its flag spelled out (denoising is the default).
RUNS = (("plain", ["--no-denoise"]), ("denoised", ["--denoise"]))


def stage_path(name: str) -> Path:
    """A stage file, or a sample's name (``cornell_box`` -> samples/cornell_box.usda)."""
    p = Path(name)
    if not p.suffix:
        p = C.REPO / SAMPLE_STAGES.format(name)
    return p.resolve()


def judge(baker, stage: Path, work: Path, args, spp: int, seed: int, bpy: str) -> dict:
    """{"plain": figures, "denoised": figures} of one stage at ``spp`` / ``seed``; figures
    as :func:`benchmarks.reference.compare.compare_images` gives them (no Cycles rows)."""
    out, truth, scene = {}, None, None
    for name, extra in RUNS:
        layer = work / f"{name}.lightmaps.usda"
        flags = ["--samples", str(spp), "--seed", str(seed), "--force", *extra]
        baked = baker.bake(stage, layer, args.resolution, flags)
        results = C.usdahd_results(baked["layer"])
        if truth is None:
            scene = export.export_stage(baked["layer"], baked=results)
            sf = export.save_scene(scene, work / "reference_scene.npz")
            _, truth, _ = runner.cached_cycles(
                scene, sf, args.truth_spp, seed=C.TRUTH_SEED, bpy=bpy, use_cache=True,
                threads=0, quiet=True, oversample=1, point=True,
            )  # fmt: skip
        ours = {
            k: C.usdahd_iz(results[m["path"]]["sidecar"])
            for k, m in enumerate(scene.meshes)
            if m["baked"] and results.get(m["path"], {}).get("sidecar")
        }
        out[name] = C.compare_images(scene.meshes, truth, {}, ours, spp, args.truth_spp)
    return out


def ratios(row: dict) -> tuple[float, float, str]:
    """(overall relRMSE ratio denoised / plain, worst mesh's ratio, that mesh's path)."""
    p, d = row["plain"], row["denoised"]
    overall = d["overall"]["usdahd"]["rel_rmse"] / p["overall"]["usdahd"]["rel_rmse"]
    worst, where = 0.0, ""
    for mp, md in zip(p["meshes"], d["meshes"], strict=True):
        a, b = mp.get("usdahd", {}).get("rel_rmse"), md.get("usdahd", {}).get("rel_rmse")
        if a and b is not None and b / a > worst:
            worst, where = b / a, mp["path"]
    return overall, worst, where


def table(rows: list[dict], samples: list[int]) -> str:
    """Markdown: per stage, the mean over seeds of the overall ratio at each sample count,
    and the worst mesh ratio over every sample count and seed."""
    stages = list(dict.fromkeys(r["stage"] for r in rows))
    head = "| stage | " + " | ".join(f"{s} spp" for s in samples) + " | worst mesh (spp) |"
    lines = [head, "|---" * (len(samples) + 2) + "|"]
    for st in stages:
        cells, worst = [], (0.0, "", 0)
        for s in samples:
            mine = [r for r in rows if r["stage"] == st and r["spp"] == s]
            cells.append(f"{np.mean([r['ratio'] for r in mine]):.2f}" if mine else "")
            for r in mine:
                if r["worst"] > worst[0]:
                    worst = (r["worst"], r["worst_mesh"], s)
        w = f"{worst[0]:.2f} {worst[1].rsplit('/', 1)[-1]} ({worst[2]})" if worst[1] else ""
        lines.append(f"| {Path(st).stem} | " + " | ".join(cells) + f" | {w} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.reference.denoise_gain",
                                 description=__doc__.split("\n\n")[0])  # fmt: skip
    ap.add_argument("--stages", nargs="+", required=True)
    ap.add_argument("--samples", nargs="+", type=int, default=[16, 64, 256, 1024])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--truth-spp", type=int, default=4096)
    ap.add_argument("--bpy-python")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    stages = [stage_path(s) for s in args.stages]
    missing = [str(s) for s in stages if not s.is_file()]
    if missing:
        print(f"error: no such stage: {', '.join(missing)}", file=sys.stderr)
        return 2
    try:
        bpy = runner.find_bpy(args.bpy_python)  # fail before any long work
    except runner.ReferenceUnavailable as exc:  # its message names the fix
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rows = []
    with WarmBaker() as baker, tempfile.TemporaryDirectory(prefix="usdahd-dngain-") as td:
        for stage in stages:
            for spp in args.samples:
                for seed in args.seeds:
                    figs = judge(baker, stage, Path(td), args, spp, seed, bpy)
                    ratio, worst, where = ratios(figs)
                    rows.append({"stage": str(stage), "spp": spp, "seed": seed, "ratio": ratio,
                                 "worst": worst, "worst_mesh": where, **figs})  # fmt: skip
                    print(f"{stage.stem} {spp} spp seed {seed}: {ratio:.3f} (worst mesh "
                          f"{worst:.2f} {where})", file=sys.stderr, flush=True)  # fmt: skip
    print(table(rows, args.samples))
    if args.out:
        args.out.write_text(json.dumps({"argv": sys.argv[1:], "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
