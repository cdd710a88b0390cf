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

The Cycles truth is a DIFFUSE bake, I_z only; what a directional lightmap adds (the light
seen by a normal-mapped surface) is judged against usdahd's own converged bake instead
(``--direction-spp``, default 4096, two independent seeds whose difference gives its noise;
the integrator is unbiased against Cycles, issue 17, so what is judged is the denoiser):
the irradiance at normals tilted 45 degrees from the texel's at 4 azimuths, from the SH
sidecar, per RGB channel on every covered texel. ``--direction-spp 0`` skips it.
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
#: Normals 45 degrees off the texel normal at 4 azimuths, in the SH's tangent frame (z is
#: the texel normal): what a normal map asks of a directional lightmap.
TILTED = np.array([[1, 0, 1], [-1, 0, 1], [0, 1, 1], [0, -1, 1]]) / np.sqrt(2.0)
#: Seeds of the two converged usdahd bakes the directional error is judged against.
DIRECTION_SEEDS = (1000, 1001)
#: The two bakes compared, each with its flag spelled out (denoising is the default).
RUNS = (("plain", ["--no-denoise"]), ("denoised", ["--denoise"]))


def stage_path(name: str) -> Path:
    """A stage file, or a sample's name (``cornell_box`` -> samples/cornell_box.usda)."""
    p = Path(name)
    if not p.suffix:
        p = C.REPO / SAMPLE_STAGES.format(name)
    return p.resolve()


def tilted_irradiance(sidecar: str) -> tuple[np.ndarray, np.ndarray]:
    """(h, w, 3, 4) float64 irradiance / pi at the ``TILTED`` normals (cosine-convolved SH)
    and coverage (h, w) bool, from a bake's SH sidecar."""
    from usdahd import sidecar as sc
    from usdahd.numerics import sh as shm

    sh, covered = sc.split(np.asarray(sc.read(sidecar), np.float64))
    e = np.stack([shm.irradiance(sh, n) for n in TILTED], axis=-1)
    return e, covered


def sidecars(layer: Path) -> dict[str, str]:
    """{mesh path: SH sidecar path} of a bake's layer."""
    return {p: r["sidecar"] for p, r in C.usdahd_results(layer).items() if r.get("sidecar")}


def direction_reference(baker, stage: Path, work: Path, args) -> dict:
    """{mesh path: (mean (h, w, 3, 4), noise variance of the mean (scalar), covered (h, w))}
    of the tilted irradiance of two converged ``--no-denoise`` bakes (``DIRECTION_SEEDS``)."""
    halves = []
    for seed in DIRECTION_SEEDS:
        layer = work / f"direction_{seed}.lightmaps.usda"
        flags = ["--samples", str(args.direction_spp), "--seed", str(seed), "--force",
                 "--no-denoise"]  # fmt: skip
        baker.bake(stage, layer, args.resolution, flags)
        halves.append({m: tilted_irradiance(f) for m, f in sidecars(layer).items()})
    out = {}
    for m, (a, cov) in halves[0].items():
        b = halves[1][m][0]
        out[m] = ((a + b) / 2, float(np.mean(((a - b)[cov]) ** 2)) / 4, cov)
    return out


def direction_error(layer: Path, ref: dict) -> float:
    """relRMSE of the tilted irradiance of a bake against ``ref``
    (:func:`direction_reference`) over every covered texel, the reference's noise taken out
    in quadrature."""
    se, ss, var, n = 0.0, 0.0, 0.0, 0
    for m, f in sidecars(layer).items():
        if m not in ref:
            continue
        mean, v, cov = ref[m]
        e, ucov = tilted_irradiance(f)
        both = cov & ucov
        k = int(both.sum()) * 12
        se += float(np.sum((e - mean)[both] ** 2))
        ss += float(np.sum(mean[both] ** 2))
        var += v * k
        n += k
    return float(np.sqrt(max(se - var, 0.0) / ss)) if ss > 0 else float("nan")


def judge(baker, stage: Path, work: Path, args, spp: int, seed: int, bpy: str,
          direction_ref: dict | None = None) -> dict:  # fmt: skip
    """{"plain": figures, "denoised": figures} of one stage at ``spp`` / ``seed``; figures
    as :func:`benchmarks.reference.compare.compare_images` gives them (no Cycles rows), plus
    ``"direction_rel_rmse"`` (:func:`direction_error`) when ``direction_ref`` is given."""
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
            k: C.usdahd_iz(results[m["path"]]["record"])
            for k, m in enumerate(scene.meshes)
            if m["baked"] and results.get(m["path"], {}).get("sidecar")
        }
        out[name] = C.compare_images(scene.meshes, truth, {}, ours, spp, args.truth_spp)
        if direction_ref is not None:
            out[name]["direction_rel_rmse"] = direction_error(baked["layer"], direction_ref)
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


def direction_ratio(row: dict) -> float | None:
    """Tilted-irradiance relRMSE denoised / plain of a row, None if not measured."""
    p = row.get("plain", {}).get("direction_rel_rmse")
    d = row.get("denoised", {}).get("direction_rel_rmse")
    return d / p if p and d is not None else None


def table(rows: list[dict], samples: list[int]) -> str:
    """Markdown: per stage, the mean over seeds of the overall ratio at each sample count,
    and the worst mesh ratio over every sample count and seed; when the directional error
    was measured, its ratio (mean over seeds) per sample count in a second set of columns."""
    stages = list(dict.fromkeys(r["stage"] for r in rows))
    direction = any(direction_ratio(r) is not None for r in rows)
    head = "| stage | " + " | ".join(f"{s} spp" for s in samples) + " | worst mesh (spp) |"
    if direction:
        head += " direction: " + " | ".join(f"{s}" for s in samples) + " |"
    cols = len(samples) * (2 if direction else 1) + 2
    lines = [head, "|---" * cols + "|"]
    for st in stages:
        cells, dcells, worst = [], [], (0.0, "", 0)
        for s in samples:
            mine = [r for r in rows if r["stage"] == st and r["spp"] == s]
            cells.append(f"{np.mean([r['ratio'] for r in mine]):.2f}" if mine else "")
            dr = [x for x in map(direction_ratio, mine) if x is not None]
            dcells.append(f"{np.mean(dr):.2f}" if dr else "")
            for r in mine:
                if r["worst"] > worst[0]:
                    worst = (r["worst"], r["worst_mesh"], s)
        w = f"{worst[0]:.2f} {worst[1].rsplit('/', 1)[-1]} ({worst[2]})" if worst[1] else ""
        line = f"| {Path(st).stem} | " + " | ".join(cells) + f" | {w} |"
        if direction:
            line += " " + " | ".join(dcells) + " |"
        lines.append(line)
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.reference.denoise_gain",
                                 description=__doc__.split("\n\n")[0])  # fmt: skip
    ap.add_argument("--stages", nargs="+", required=True)
    ap.add_argument("--samples", nargs="+", type=int, default=[16, 64, 256, 1024])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--truth-spp", type=int, default=4096)
    ap.add_argument("--direction-spp", type=int, default=4096,
                    help="samples of each of the two converged usdahd bakes the directional "
                    "error is judged against (0: not judged)")  # fmt: skip
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
            ref = direction_reference(baker, stage, Path(td), args) if args.direction_spp else None
            for spp in args.samples:
                for seed in args.seeds:
                    figs = judge(baker, stage, Path(td), args, spp, seed, bpy, ref)
                    ratio, worst, where = ratios(figs)
                    rows.append({"stage": str(stage), "spp": spp, "seed": seed, "ratio": ratio,
                                 "worst": worst, "worst_mesh": where, **figs})  # fmt: skip
                    dr = direction_ratio(rows[-1])
                    print(f"{stage.stem} {spp} spp seed {seed}: {ratio:.3f} (worst mesh "
                          f"{worst:.2f} {where})" + ("" if dr is None else f", direction "
                          f"{dr:.3f}"), file=sys.stderr, flush=True)  # fmt: skip
    print(table(rows, args.samples))
    if args.out:
        args.out.write_text(json.dumps({"argv": sys.argv[1:], "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
