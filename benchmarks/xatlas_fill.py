"""How much of its own atlas xatlas's charts cover, on every mesh of a stage, with xatlas alone
(independent of usdahd's unwrap): each mesh is triangulated from the layer with pxr (fan
triangulation of its faceVertexCounts, in the mesh's local space) and packed by xatlas at a
fixed texel density; the chart area is the packed UV triangles' area in texels.

    python benchmarks/xatlas_fill.py STAGE --texels-per-unit 8 16 --padding 2 [--brute-force]

Prints one line per (density, padding): meshes, atlas texels (sum of the per-mesh atlases),
chart area in texels and their ratio (docs/scenes.md, "Atlas fill at the default density").
Texel densities are per stage unit (Sponza's metersPerUnit is 1).
"""

from __future__ import annotations

import argparse

import numpy as np


def mesh_triangles(mesh):
    points = np.asarray(mesh.GetPointsAttr().Get(), np.float32)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
    tris, o = [], 0
    for n in counts:
        for k in range(1, n - 1):
            tris.append((idx[o], idx[o + k], idx[o + k + 1]))
        o += n
    return points, np.asarray(tris, np.uint32)


def chart_fill(points, tris, texels_per_unit, padding, brute_force):
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(points, tris)
    pack = xatlas.PackOptions()
    pack.texels_per_unit = float(texels_per_unit)
    pack.padding = int(padding)
    pack.bilinear = True
    pack.resolution = 0
    pack.bruteForce = bool(brute_force)
    atlas.generate(xatlas.ChartOptions(), pack)
    _, ix, uv = atlas.get_mesh(0)
    q = (np.asarray(uv) * [atlas.width, atlas.height])[np.asarray(ix)]
    e1, e2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    return atlas.width * atlas.height, float(area)


def main(argv=None) -> int:
    from pxr import Usd, UsdGeom

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stage")
    ap.add_argument("--texels-per-unit", type=float, nargs="+", default=[8.0])
    ap.add_argument("--padding", type=int, nargs="+", default=[2])
    ap.add_argument("--brute-force", action="store_true")
    a = ap.parse_args(argv)
    stage = Usd.Stage.Open(a.stage)
    meshes = [mesh_triangles(UsdGeom.Mesh(p)) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    for tpu in a.texels_per_unit:
        for pad in a.padding:
            total = covered = 0.0
            for points, tris in meshes:
                t, c = chart_fill(points, tris, tpu, pad, a.brute_force)
                total += t
                covered += c
            print(
                f"texels/unit {tpu:g} padding {pad} bruteForce {a.brute_force}: {len(meshes)} "
                f"meshes, atlas texels {total:.0f}, chart area {covered:.0f} texels, "
                f"{100 * covered / total:.1f} %",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
