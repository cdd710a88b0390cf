"""Dark texels along chart borders: one baked prim's I_z texture, texel by texel, against its
own charts (issue 37, the chess board's frame).

    python benchmarks/chart_border_texels.py BAKED.lightmaps.usda PRIM [--ratio 0.7] [--json]

The prim's lightmap UVs are rasterised at its texture's size (:func:`usdahd.bake.texels.rasterize`,
the bake's own coverage: conservative texels included) and each covered texel is labelled by its
chart (:func:`usdahd.bake.texels.chart_ids`). A texel is on a *chart border* when one of its 4
neighbours is uncovered or in another chart. Each texel's I_z (luminance of the ``iz`` texture)
is compared with the median of the *interior* texels of its own chart within 3 texels; a texel
below ``ratio`` x that median is *dark*. Prints, for border and interior texels, how many are
dark, and how many of the dark border texels are conservative (centre outside their UV
triangle: sampled at the triangle's closest point, on the chart's edge); then the largest
charts by surface area with their texels per metre and mean normal (``chart_density``).
Lighting makes some interior texels dark too (shadows, contacts): the comparison is the share,
border against interior. docs/scenes.md, "What the chess set's 0.124 is".
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np


def border_texels(layer: str, prim: str, ratio: float = 0.7) -> dict:
    from usdahd.bake import texels as T
    from usdahd.preview.meshes import baked_meshes
    from usdahd.usd import schema

    _, meshes, _ = baked_meshes(layer)
    found = [m for m in meshes if m[0].path == prim]
    if not found:
        raise SystemExit(f"{prim}: not a baked prim of {layer}")
    mesh, res, *_ = found[0]
    iz = np.asarray(schema.read_record_pixels(res, "iz"), np.float64)
    h, w = iz.shape[:2]
    lum = iz[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    tx = T.rasterize(mesh, (w, h))
    cid = T.chart_ids(mesh)[tx.triangle]
    x, y = tx.xy[:, 0].astype(np.int64), tx.xy[:, 1].astype(np.int64)
    chart = np.full((h, w), -1, np.int64)
    chart[y, x] = cid
    pad = np.pad(chart, 1, constant_values=-1)
    border = np.zeros(len(x), bool)
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        border |= pad[1 + y + dy, 1 + x + dx] != cid
    v = lum[y, x]
    interior = np.full((h, w), np.nan)
    interior[y, x] = np.where(border, np.nan, v)
    padc = np.pad(chart, 3, constant_values=-1)
    padv = np.pad(interior, 3, constant_values=np.nan)
    near = [
        np.where(padc[3 + y + dy, 3 + x + dx] == cid, padv[3 + y + dy, 3 + x + dx], np.nan)
        for dy in range(-3, 4)
        for dx in range(-3, 4)
    ]
    with warnings.catch_warnings():  # texels with no interior texel of their chart near
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(np.stack(near, axis=1), axis=1)
    ok = np.isfinite(med) & (med > 0)
    dark = ok & (v < ratio * med)
    return {
        "charts": chart_density(mesh, (w, h)),
        "prim": prim,
        "size": [w, h],
        "texels": len(x),
        "ratio": ratio,
        "border": int((ok & border).sum()),
        "border_dark": int((dark & border).sum()),
        "border_dark_conservative": int((dark & border & ~tx.center_inside).sum()),
        "interior": int((ok & ~border).sum()),
        "interior_dark": int((dark & ~border).sum()),
    }


def chart_density(mesh, size, top: int = 8) -> list[dict]:
    """The ``top`` charts by 3-D area: area (m^2), share of the prim's UV area, texels per metre
    at ``size`` (sqrt of texel area over surface area) and the area-weighted mean geometric
    normal."""
    from usdahd.bake import texels as T

    w, h = size
    tri = np.asarray(mesh.triangles, np.int64)
    p = np.asarray(mesh.points, np.float64)[tri]
    uv = np.asarray(mesh.uv, np.float64)
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    a3 = 0.5 * np.linalg.norm(cross, axis=1)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    auv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    cid = T.chart_ids(mesh)
    n = int(cid.max()) + 1 if len(cid) else 0
    area = np.bincount(cid, a3, n)
    uva = np.bincount(cid, auv, n)
    nrm = np.stack([np.bincount(cid, 0.5 * cross[:, k], n) for k in range(3)], 1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    out = []
    for c in np.argsort(-area)[:top]:
        out.append(
            {
                "chart": int(c),
                "area_m2": float(area[c]),
                "uv_share": float(uva[c] / max(uva.sum(), 1e-30)),
                "texels_per_m": float(np.sqrt(uva[c] * w * h / max(area[c], 1e-30))),
                "normal": [round(float(x), 3) for x in nrm[c]],
            }
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("layer")
    ap.add_argument("prim")
    ap.add_argument("--ratio", type=float, default=0.7)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    r = border_texels(a.layer, a.prim, a.ratio)
    if a.json:
        print(json.dumps(r, indent=1))
        return 0
    print(
        f"{r['prim']} ({r['size'][0]}x{r['size'][1]}, {r['texels']} texels): dark (< "
        f"{r['ratio']} x the chart's interior median within 3 texels): border "
        f"{r['border_dark']} of {r['border']} ({r['border_dark'] / max(r['border'], 1):.0%}, "
        f"{r['border_dark_conservative']} conservative), interior {r['interior_dark']} of "
        f"{r['interior']} ({r['interior_dark'] / max(r['interior'], 1):.0%})"
    )
    for c in r["charts"]:
        print(
            f"  chart {c['chart']}: {c['area_m2']:.4f} m2, {c['uv_share']:.1%} of the UV area, "
            f"{c['texels_per_m']:.0f} texels/m, mean normal {c['normal']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
