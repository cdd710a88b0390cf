"""Two independent Cycles truths of one stage against each other, per mesh: how far is
``compare``'s truth from a better one?

``python -m benchmarks.reference.truth_pair STAGE --resolution 24 --spp 1024,4096 --seeds 1,3``
bakes the stage as ``compare`` does (``--no-denoise``, 1 sample per texel: the unwrap and texels
are the bake's, so the exported scene and its cached truths are ``compare``'s), takes both
point-sampled truths through the cache (``--point`` probes; the first pair is ``compare``'s
truth at ``--truth-spp 1024``) and prints, per mesh on ``compare``'s texel selection of the
first truth, ``mean(Y_a) / mean(Y_b) - 1``: the first truth's error on the mesh's mean as seen by
the second. With the second at higher spp and another seed, a mesh bias that ``compare`` and
``seeds`` show is corrected by it: ``(1 + bias) / (1 + this) - 1`` against the better truth.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.reference import compare, export, runner

__all__ = ["main", "truth_pair"]


def truth_pair(stage, *, resolution: int, spps: list[int], seeds: list[int],
               bpy: str | None = None, quiet: bool = False) -> dict:  # fmt: skip
    """{"meshes": {path: {"texels", "bias"}}, "cached": [bool, bool], ...} (see module doc)."""
    from usdahd.pipeline.run import bake
    from usdahd.pipeline.settings import BakeOptions

    stage = Path(stage).resolve()
    if not stage.is_file():
        raise compare.CompareError(f"{stage}: no such file")
    if len(spps) != 2 or len(seeds) != 2 or min(spps) < 1:
        raise compare.CompareError("--spp and --seeds take two values each (spp >= 1)")
    if (spps[0], seeds[0]) == (spps[1], seeds[1]):
        raise compare.CompareError("the two truths must differ in --spp or --seeds")
    bpy = runner.find_bpy(bpy)  # fail before any long work
    with tempfile.TemporaryDirectory(prefix="usdahd-truths-") as tmp:
        layer = Path(tmp) / f"{stage.stem}.lightmaps.usda"
        bake(stage, BakeOptions(output=str(layer), resolution=resolution, samples=1,
                                denoise=False, quiet=True))  # fmt: skip
        scene = export.export_stage(layer, baked=compare.usdahd_results(layer))
        sf = export.save_scene(scene, Path(tmp) / "reference_scene.npz")
        got = [runner.cached_cycles(scene, sf, n, seed=s, bpy=bpy, quiet=quiet, point=True)
               for n, s in zip(spps, seeds, strict=True)]  # fmt: skip
    a, b = got[0][1], got[1][1]
    lum = np.concatenate([np.nan_to_num(t.reshape(-1, 3)) @ compare.LUMA for t in a.values()])
    p99 = float(np.percentile(lum, 99)) if lum.size else 0.0
    meshes = {}
    for k, m in enumerate(scene.meshes):
        if k not in a or k not in b:
            continue
        t = a[k]
        lit_level = compare.LIT_FRACTION * p99
        bright = np.isfinite(t[..., 0]) & (np.nan_to_num(t) @ compare.LUMA > lit_level)
        ok = compare.interior(bright) & np.isfinite(b[k][..., 0])
        if ok.any():
            ya, yb = t[ok] @ compare.LUMA, b[k][ok] @ compare.LUMA
            meshes[m["path"]] = {"texels": int(ok.sum()),
                                 "bias": float(ya.mean() / yb.mean() - 1.0)}  # fmt: skip
    return {"stage": str(stage), "resolution": resolution, "spp": spps, "seeds": seeds,
            "cached": [bool(g[2]) for g in got], "meshes": meshes}  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reference.truth_pair")
    p.add_argument("stage")
    p.add_argument("--resolution", type=int, required=True, help="as compare's")
    p.add_argument("--spp", default="1024,4096", help="the two truths' spp")
    p.add_argument("--seeds", default="1,3", help="the two truths' Cycles seeds")
    p.add_argument("--bpy-python")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    try:
        from benchmarks.reference.seeds import _parse_list

        res = truth_pair(a.stage, resolution=a.resolution, spps=_parse_list(a.spp, "spp"),
                         seeds=_parse_list(a.seeds, "seeds"), bpy=a.bpy_python,
                         quiet=a.quiet)  # fmt: skip
    except (runner.ReferenceUnavailable, compare.CompareError, export.ExportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(res, indent=1))
    else:
        (sa, sb), (da, db) = res["spp"], res["seeds"]
        print(f"| mesh | texels | truth {sa} spp (seed {da}) vs {sb} spp (seed {db}) |")
        print("|---|---|---|")
        for path, m in res["meshes"].items():
            print(f"| {path} | {m['texels']} | {compare._pct(m['bias'])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
