"""``usdahd preview --compare`` statistics split by mesh: the same view, preview image and
path-traced reference as the command (embree backend, usdahd/commands/preview.py ``run``), then
``usdahd.preview.compare.error_stats`` over the pixels where each baked mesh is the visible
surface (the preview's own primary rays, ``compare.visible_points``).

    python benchmarks/compare_per_mesh.py BAKED.lightmaps.usda [--camera PATH] [--size W H]
        [--samples N] [--seed S] [--json]

Prints one line per mesh with >= 1 pixel, largest first: pixels, relRMSE, bias, the
reference's noise on that mesh; then the whole view (the numbers ``preview --compare --json``
reports for the same arguments). docs/scenes.md, "Production assets".
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def per_mesh(layer, camera=None, size=(240, 180), samples=64, seed=0):
    from usdahd.preview import compare
    from usdahd.preview.camera import view_projection
    from usdahd.preview.meshes import baked_meshes, draw_items, preview_scene, render_view

    w, h = size
    stage, meshes, up = baked_meshes(str(layer))
    viewproj = view_projection(stage, meshes, up, camera, w / h)
    image = render_view(stage, meshes, draw_items(meshes), viewproj, (w, h), None)
    ref, var, info = compare.reference(
        stage, meshes, viewproj, (w, h), samples=samples, seed=seed, bounces=None
    )
    pix, which, _ = compare.visible_points(
        meshes, viewproj, (w, h), preview_scene(stage, meshes[0][1].uv_primvar)
    )
    owner = np.full(w * h, -1, np.int64)
    owner[pix] = which
    owner = owner.reshape(h, w)
    rows = []
    for k, (mesh, *_rest) in enumerate(meshes):
        sel = owner == k
        if not sel.any():
            continue
        mask = sel[..., None].astype(np.float32)
        st = compare.error_stats(image * mask, ref * mask, var)
        rows.append({"mesh": mesh.path, **st})
    rows.sort(key=lambda r: -r["pixels"])
    return {"all": compare.error_stats(image, ref, var), "info": info, "meshes": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("layer")
    ap.add_argument("--camera")
    ap.add_argument("--size", type=int, nargs=2, default=(240, 180))
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    out = per_mesh(a.layer, a.camera, tuple(a.size), a.samples, a.seed)
    if a.json:
        print(json.dumps(out, indent=1))
        return 0
    for r in [*out["meshes"], {"mesh": "(whole view)", **out["all"]}]:
        if r.get("relrmse") is None:
            continue
        print(
            f"{r['mesh']}: {r['pixels']} px, relRMSE {r['relrmse']:.3f}, bias "
            f"{100 * r['bias']:+.1f} %, reference noise {r['reference_noise']:.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
