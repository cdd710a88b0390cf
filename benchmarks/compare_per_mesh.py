"""``usdahd preview --compare`` statistics split by mesh: the same view, preview image and
path-traced reference as the command (embree backend, usdahd/commands/preview.py ``run``), then
``usdahd.preview.compare.error_stats`` over the sub-pixel points where each baked mesh is the
visible surface (the preview's own primary rays, ``compare.visible_points``), averaged over each
pixel's footprint (``compare.footprint_stats``; ``--footprint``, default the command's).

    python benchmarks/compare_per_mesh.py BAKED.lightmaps.usda [--camera PATH] [--size W H]
        [--samples N] [--seed S] [--footprint S] [--json]

Prints one line per mesh with >= 1 pixel, largest first: pixels, relRMSE, bias, the
reference's noise on that mesh; then the whole view (the numbers ``preview --compare --json``
reports for the same arguments). docs/scenes.md, "Production assets".
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def per_mesh(layer, camera=None, size=(240, 180), samples=64, seed=0, footprint=None):
    from usdahd.preview import compare
    from usdahd.preview.camera import view_projection
    from usdahd.preview.meshes import baked_meshes, draw_items, render_view

    fp = compare.FOOTPRINT if footprint is None else int(footprint)
    w, h = size
    stage, meshes, up = baked_meshes(str(layer))
    viewproj = view_projection(stage, meshes, up, camera, w / h)
    sub = (w * fp, h * fp)
    image = render_view(stage, meshes, draw_items(meshes), viewproj, sub, None)
    ref = compare.reference(
        stage,
        meshes,
        viewproj,
        sub,
        samples=compare.points_per_pixel(samples, fp),
        seed=seed,
        bounces=None,
    )
    rows = []
    for k, (mesh, *_rest) in enumerate(meshes):
        sel = ref.owner == k
        if not sel.any():
            continue
        mask = sel[..., None].astype(np.float32)
        part = ref._replace(image=ref.image * mask)
        _, _, st = compare.footprint_stats(image * mask, part, fp)
        rows.append({"mesh": mesh.path, **st})
    rows.sort(key=lambda r: -r["pixels"])
    _, _, whole = compare.footprint_stats(image, ref, fp)
    return {"all": whole, "info": ref.info, "meshes": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("layer")
    ap.add_argument("--camera")
    ap.add_argument("--size", type=int, nargs=2, default=(240, 180))
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--footprint", type=int, help="sub-pixel points per side (default: the CLI's)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    out = per_mesh(a.layer, a.camera, tuple(a.size), a.samples, a.seed, a.footprint)
    if a.json:
        print(json.dumps(out, indent=1))
        return 0
    for r in [*out["meshes"], {"mesh": "(whole view)", **out["all"]}]:
        if r.get("relrmse") is None:
            continue
        print(
            f"{r['mesh']}: {r['pixels']} px, relRMSE {r['relrmse']:.3f}, bias "
            f"{100 * r['bias']:+.1f} %, reference noise {r['reference_noise']:.3f}, point by "
            f"point {r['relrmse_subsamples']:.3f}, edge share {r['edge_error_share'] or 0:.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
