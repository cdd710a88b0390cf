"""``usdahd preview --compare`` statistics split by mesh: the same view, preview image and
path-traced reference as the command (embree backend, usdahd/commands/preview.py ``run``), then
``usdahd.preview.compare.error_stats`` over the sub-pixel points where each baked mesh is the
visible surface (the preview's own primary rays, ``compare.visible_points``), averaged over each
pixel's footprint (``compare.footprint_stats``; ``--footprint``, default the command's).

    python benchmarks/compare_per_mesh.py BAKED.lightmaps.usda [--camera PATH] [--size W H]
        [--samples N] [--seed S] [--footprint S] [--json]

Prints the squared error split into edge pixels, interior pixels on a lighting step of the
reference and smooth interior pixels (``kinds``), then one line per mesh with >= 1 pixel,
largest first: pixels, relRMSE, bias, the reference's noise on that mesh; then the whole view
(the numbers ``preview --compare --json`` reports for the same arguments). docs/scenes.md,
"Production assets".
"""

from __future__ import annotations

import argparse
import json
import warnings

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
    b, r, whole = compare.footprint_stats(image, ref, fp)
    edge = compare.edge_pixels(ref.owner, fp)
    return {"all": whole, "info": ref.info, "meshes": rows, "kinds": kinds(b, r, edge)}


#: A reference pixel differing from a 3 x 3 neighbour by this share of the view's mean
#: luminance is on a *lighting step* (a shadow boundary, a crease, a groove).
STEP = 0.15


def kinds(b, r, edge):
    """The squared error split three ways over the pixels both images cover: ``edge``
    (:func:`usdahd.preview.compare.edge_pixels`), ``step`` (interior pixels on a lighting step
    in the reference: a 3 x 3 neighbour's luminance differs by more than STEP x the mean) and
    ``smooth`` (the rest). Per kind: pixels, relRMSE over them, share of the squared error and
    the view's relRMSE without them."""
    luma = np.array([0.2126, 0.7152, 0.0722])
    cov = (b[..., 3] > 0) & (r[..., 3] > 0)
    lr = r[..., :3].astype(np.float64) @ luma
    h, w = lr.shape
    pad = np.pad(np.where(cov, lr, np.nan), 1, constant_values=np.nan)
    with warnings.catch_warnings():  # pixels with no covered neighbour: NaN, no step
        warnings.simplefilter("ignore", RuntimeWarning)
        diff = np.nanmax(
            [np.abs(pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] - lr)
             for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0,
        )  # fmt: skip
    step = cov & ~edge & (np.nan_to_num(diff) > STEP * float(lr[cov].mean()))
    d2 = ((b[..., :3] - r[..., :3]).astype(np.float64) ** 2).sum(-1)
    r2 = (r[..., :3].astype(np.float64) ** 2).sum(-1)
    total, rtotal = float(d2[cov].sum()), float(r2[cov].sum())
    out = {}
    for name, sel in (("edge", cov & edge), ("step", step), ("smooth", cov & ~edge & ~step)):
        e = float(d2[sel].sum())
        out[name] = {
            "pixels": int(sel.sum()),
            "relrmse": float(np.sqrt(e / r2[sel].sum())) if sel.any() else None,
            "error_share": e / total if total > 0 else None,
            "relrmse_without": float(np.sqrt((total - e) / rtotal)) if rtotal > 0 else None,
        }
    return out


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
    for name, k in out["kinds"].items():
        if k["relrmse"] is None:
            continue
        print(
            f"({name} pixels): {k['pixels']} px, relRMSE {k['relrmse']:.3f}, share of the "
            f"squared error {k['error_share']:.2f}, the view without them "
            f"{k['relrmse_without']:.3f}"
        )
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
