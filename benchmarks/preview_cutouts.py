"""``preview --compare`` of a baked layer with alpha cut-outs, three renders of one view against
one path-traced reference (issue 37): the Embree backend, the wgpu backend without the cut-out
test (as before the fix) and with it.

    python -m benchmarks.preview_cutouts LAYER [--size 160 120] [--samples 64]

Prints JSON: per render the statistics of ``usdahd preview --compare`` (same reference: seed 0,
the bake's bounce cap), the fraction of pixels where each wgpu render differs from Embree by
more than 1e-3 relative, and the statistics again over the pixels where wgpu (with the test) and
Embree show the same surface (the others are fractional-opacity pixels, where the rasteriser's
per-pixel hash and the tracer's coin flip pick different surfaces).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def run(layer: str, size, samples: int) -> dict:
    from usdahd.preview import compare, gpu
    from usdahd.preview.camera import view_projection
    from usdahd.preview.cutout import cutouts
    from usdahd.preview.meshes import baked_meshes, draw_items, render_view

    w, h = size
    stage, meshes, up = baked_meshes(layer)
    vp = view_projection(stage, meshes, up, None, w / h)
    dev = gpu.device()[1]
    plain = draw_items(meshes)
    cut = draw_items(meshes, cutouts=cutouts(stage, meshes))
    imgs = {
        "embree": render_view(stage, meshes, plain, vp, size, None),
        "wgpu_without_cutouts": render_view(stage, meshes, plain, vp, size, dev),
        "wgpu": render_view(stage, meshes, cut, vp, size, dev),
    }
    ref, var, *_ = compare.reference(
        stage, meshes, vp, size, samples=samples, seed=0, bounces=None,
        progress=lambda s: print(s, file=sys.stderr),
    )  # fmt: skip
    out = {"layer": layer, "size": list(size), "samples": samples}
    out.update({k: compare.error_stats(v, ref, var) for k, v in imgs.items()})

    def differs(a, b):
        a, b = a[..., :3], b[..., :3]
        return np.abs(a - b).max(-1) > 1e-3 * np.maximum(np.maximum(a, b).max(-1), 1e-6)

    cov = imgs["embree"][..., 3] > 0
    for k in ("wgpu_without_cutouts", "wgpu"):
        out[f"{k}_pixels_differing_from_embree"] = float(
            differs(imgs[k], imgs["embree"])[cov].mean()
        )
    same = ~differs(imgs["wgpu"], imgs["embree"])
    for k, v in imgs.items():
        masked = v.copy()
        masked[~same, 3] = 0.0
        out[f"{k}_where_wgpu_and_embree_agree"] = compare.error_stats(masked, ref, var)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.preview_cutouts")
    ap.add_argument("layer")
    ap.add_argument("--size", type=int, nargs=2, default=(160, 120))
    ap.add_argument("--samples", type=int, default=64)
    args = ap.parse_args(argv)
    print(json.dumps(run(args.layer, tuple(args.size), args.samples), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
