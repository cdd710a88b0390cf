"""Is a mesh's bias against Cycles the estimator's or one noise draw? Many seeds, several spp.

``python -m benchmarks.reference seeds STAGE --prim PATH --resolution 64 --truth-spp 1024
--spp 64,256,1024,4096 --seeds 8,8,2,2`` bakes the whole stage once as ``compare`` does
(``--no-denoise`` and 1 sample per texel, which changes neither the unwrap nor the texels, so
the exported scene and its cached Cycles truth are ``compare``'s), and inside that bake traces
``PATH``'s texels again with :func:`usdahd.bake.integrate.bake_texels` at every ``--spp`` for
every seed (``seed-base``, ``seed-base + 1``, ... passed to the bake as ``usdahd bake --seed``
does, so seed 0 here is ``usdahd bake --seed 0``'s estimate, bit for bit). Each estimate is
compared with the truth on ``compare``'s texel selection (lit texels whose 8 neighbours are
lit) as ``compare``'s bias, ``mean(Y) / mean(Y_truth) - 1`` of Rec. 709 luminance of I_z.

Printed per spp: the seeds, the mean bias over them and its standard error (the seeds' sample
standard deviation over sqrt(seeds): the usdahd side only; the truth's own error on the
mesh's mean is common to every row, so rows compare with each other at the SE shown), the
per-seed standard deviation and the range. An estimator whose bias shrinks with samples shows
as a trend down the rows; one noise draw as a row mean within a few SE of the converged row's.
The undenoised estimate is what is measured (the denoiser is not run). Also printed: the RMS
over seeds of the bake's own standard-error estimates of the mesh's bias, from the integrator's
per-texel variances as ``compare`` takes them (:func:`benchmarks.reference.compare.bake_mean_error`)
and from seed pairs (``(a - b)^2 / 2`` per texel), to check against the measured per-seed SD.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.reference import compare, export, runner

__all__ = ["main", "seed_rows"]


def seed_rows(biases: dict[int, list[float]], se: dict | None = None) -> list[dict]:
    """Per spp (ascending): seeds, mean bias, its standard error, per-seed SD, min, max; with
    ``se`` ({str(spp): {"integrator": [...], "seed_pairs": [...]}}) also the RMS over seeds of
    the bake's own standard-error estimates (``est_integrator``, ``est_seed_pairs``), which
    should match the measured per-seed SD."""
    rows = []
    for spp in sorted(biases):
        b = np.asarray(biases[spp], np.float64)
        sd = float(b.std(ddof=1)) if len(b) > 1 else float("nan")
        row = {
            "spp": spp, "seeds": len(b), "bias": float(b.mean()),
            "se": sd / np.sqrt(len(b)), "sd": sd, "min": float(b.min()), "max": float(b.max()),
        }  # fmt: skip
        for name, v in ((se or {}).get(str(spp)) or {}).items():
            if name in ("integrator", "seed_pairs") and v:
                row[f"est_{name}"] = float(np.sqrt(np.mean(np.square(v))))
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    pc = compare._pct
    head = "| spp | seeds | mean bias | SE of the mean | SD per seed | min / max "
    head += "| bake SE est. (integrator) | bake SE est. (seed pairs) |\n"
    head += "|---|---|---|---|---|---|---|---|\n"
    return head + "\n".join(
        f"| {r['spp']} | {r['seeds']} | {pc(r['bias'])} | {compare._pct0(r['se'])} | "
        f"{compare._pct0(r['sd'])} | {pc(r['min'])} / {pc(r['max'])} | "
        f"{compare._pct0(r.get('est_integrator'))} | {compare._pct0(r.get('est_seed_pairs'))} |"
        for r in rows
    )


def _parse_list(text: str, what: str) -> list[int]:
    try:
        out = [int(x) for x in text.split(",")]
    except ValueError:
        raise compare.CompareError(
            f"--{what} takes comma-separated integers, got {text!r}"
        ) from None
    if not out or min(out) < 1:
        raise compare.CompareError(f"--{what} values must be >= 1, got {text!r}")
    return out


def run_seeds(stage, prim: str, *, resolution: int, spps: list[int], seeds: list[int],
              seed_base: int = 0, truth_spp: int = 1024, bpy: str | None = None,
              quiet: bool = False) -> dict:  # fmt: skip
    """Per-seed estimates of ``prim`` at each spp against the cached truth (see module doc)."""
    import usdahd.bake.integrate as integ
    from usdahd.pipeline.run import bake
    from usdahd.pipeline.settings import BakeOptions
    from usdahd.pipeline.stages import _job_seed

    stage = Path(stage).resolve()
    if not stage.is_file():
        raise compare.CompareError(f"{stage}: no such file")
    if len(spps) != len(seeds):
        raise compare.CompareError("--spp and --seeds need as many values each")
    bpy = runner.find_bpy(bpy)  # fail before any long work
    orig = integ.bake_texels
    est: dict[int, list[np.ndarray]] = {s: [] for s in spps}
    var: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {s: [] for s in spps}
    found = {}

    def hook(scene, tracer, texels, **kw):
        mesh = kw.get("mesh")
        if mesh is None or scene.meshes[mesh].path != prim:
            return orig(scene, tracer, texels, **kw)
        found["xy"] = texels.xy.copy()
        for spp, n in zip(spps, seeds, strict=True):
            for s in range(seed_base, seed_base + n):
                sh, st = orig(scene, tracer, texels, samples=spp, seed=_job_seed(s, prim),
                              mesh=mesh, bounces=kw["bounces"])  # fmt: skip
                est[spp].append(_iz(sh))
                var[spp].append((np.asarray(st["iz_variance"]),
                                 np.asarray(st["iz_variance_halves"])))  # fmt: skip
                compare._log(f"{prim}: {spp} spp, seed {s} done", quiet)
        return orig(scene, tracer, texels, **kw)

    with tempfile.TemporaryDirectory(prefix="usdahd-seeds-") as tmp:
        layer = Path(tmp) / f"{stage.stem}.lightmaps.usda"
        integ.bake_texels = hook
        try:
            bake(stage, BakeOptions(output=str(layer), resolution=resolution, samples=1,
                                    denoise=False, quiet=True))  # fmt: skip
        finally:
            integ.bake_texels = orig
        if "xy" not in found:
            raise compare.CompareError(f"{prim}: not baked (no such mesh prim in {stage}?)")
        results = compare.usdahd_results(layer)
        scene = export.export_stage(layer, baked=results)
        sf = export.save_scene(scene, Path(tmp) / "reference_scene.npz")
        _, truth, hit = runner.cached_cycles(scene, sf, truth_spp, seed=compare.TRUTH_SEED,
                                             bpy=bpy, quiet=quiet, point=True)  # fmt: skip
    all_lum = np.concatenate([np.nan_to_num(t.reshape(-1, 3)) @ compare.LUMA
                              for t in truth.values()])  # fmt: skip
    p99 = float(np.percentile(all_lum, 99))
    k = next(i for i, m in enumerate(scene.meshes) if m["path"] == prim)
    t = truth[k]
    bright = np.isfinite(t[..., 0]) & (np.nan_to_num(t) @ compare.LUMA > compare.LIT_FRACTION * p99)
    lit = compare.interior(bright)
    xy = found["xy"]
    sel = lit[xy[:, 1], xy[:, 0]]
    yt = t[xy[sel, 1], xy[sel, 0]] @ compare.LUMA
    biases = {s: [float((v[sel] @ compare.LUMA).mean() / yt.mean() - 1.0) for v in est[s]]
              for s in spps}  # fmt: skip
    se = {}
    for spp in spps:  # the bake's own SE estimates (compare.bake_mean_error) per seed
        rows = [compare.bake_mean_error((s2[sel], hv[sel]), np.ones(int(sel.sum()), bool),
                                        float(yt.mean())) for s2, hv in var[spp]]  # fmt: skip
        ys = [v[sel] @ compare.LUMA for v in est[spp]]
        # two seeds' difference: per-texel variance (a - b)^2 / 2, summed, over n^2
        pairs = [float(np.sqrt(np.sum((a - b) ** 2) / 2)) / len(a) / float(yt.mean())
                 for a, b in zip(ys[0::2], ys[1::2], strict=False)]  # fmt: skip
        se[str(spp)] = {
            "integrator": [r["se"] for r in rows], "s2": [r["se_s2"] for r in rows],
            "halves": [r["se_halves"] for r in rows], "seed_pairs": pairs,
        }  # fmt: skip
    return {
        "stage": str(stage), "prim": prim, "resolution": resolution, "truth_spp": truth_spp,
        "truth_cached": bool(hit), "compared": int(sel.sum()), "seed_base": seed_base,
        "biases": {str(s): b for s, b in biases.items()}, "rows": seed_rows(biases, se),
        "bake_se": se,
    }  # fmt: skip


def _iz(sh):
    from usdahd.numerics import sh as shm

    return shm.iz(np.asarray(sh, np.float64))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reference seeds")
    p.add_argument("stage")
    p.add_argument("--prim", required=True, help="the mesh prim to trace at every seed")
    p.add_argument("--resolution", type=int, required=True, help="as compare's")
    p.add_argument("--spp", default="64,256,1024", help="samples per texel, comma-separated")
    p.add_argument("--seeds", default="8,8,2", help="seeds per --spp value, comma-separated")
    p.add_argument("--seed-base", type=int, default=0, help="first seed (usdahd bake --seed)")
    p.add_argument("--truth-spp", type=int, default=1024)
    p.add_argument("--bpy-python")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    try:
        res = run_seeds(a.stage, a.prim, resolution=a.resolution,
                        spps=_parse_list(a.spp, "spp"), seeds=_parse_list(a.seeds, "seeds"),
                        seed_base=a.seed_base, truth_spp=a.truth_spp, bpy=a.bpy_python,
                        quiet=a.quiet)  # fmt: skip
    except (runner.ReferenceUnavailable, compare.CompareError, export.ExportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(res, indent=1))
    else:
        print(f"{res['prim']}: {res['compared']} texels compared, truth {res['truth_spp']} spp")
        print(table(res["rows"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
