"""Polygons and the unwrap (issue 37, row 1): does every polygon corner get one UV?

For each mesh of each stage, unwraps it with this checkout's ``usdahd.bake.unwrap`` and, with
``--old FILE``, with another version of that module (e.g. ``git show f35853e:usdahd/bake/
unwrap.py > /tmp/old_unwrap.py``), at ``--resolution``, and reports per mesh: triangles, the
polygon corners that got two UVs (a faceVarying primvar cannot hold them, so what the layer
authors differs from what the bake traced), the texels whose centre lies in two of the
*traced* triangles, the triangles with zero UV area (they get no texel), the area-weighted
90th/10th percentile texel-density spread (the validator's TexelDensity statistic) and the
unwrap's wall time (in process, no worker).

    python benchmarks/unwrap_polygons.py STAGE [STAGE ...] [--prim PATH ...]
        [--resolution 256] [--old /tmp/old_unwrap.py]
"""

from __future__ import annotations

import argparse
import importlib.util
import time

import numpy as np

from usdahd.bake import texels as tx
from usdahd.bake import unwrap as new_unwrap
from usdahd.usd.reader import load_scene


def spread(mesh, uv, res) -> float:
    p = mesh.points[mesh.triangles]
    world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * res[0] * res[1]
    ok = (area > 1e-12) & (world > 0)
    d = np.sqrt(area[ok] / world[ok])
    order = np.argsort(d)
    cw = np.cumsum(world[ok][order]) / world[ok].sum()
    p10 = d[order][np.searchsorted(cw, 0.1)]
    p90 = d[order][min(np.searchsorted(cw, 0.9), len(cw) - 1)]
    return float(p90 / p10)


def measure(module, mesh, resolution: int) -> str:
    t0 = time.perf_counter()
    try:
        uv, res = module.unwrap(mesh, resolution=resolution, isolate=False)
    except Exception as exc:  # noqa: BLE001 - reported in the table
        return f"error: {exc}"
    dt = time.perf_counter() - t0
    mesh.uv = uv
    t = tx.rasterize(mesh, res)
    split = new_unwrap.unrepresentable_corners(mesh.corner, uv)
    return (
        f"split corners {split}, overlap {t.stats['overlap_texels']}/{len(t)}, "
        f"zero-area {t.stats['degenerate_uv_triangles']}, "
        f"spread {spread(mesh, uv, res):.3f}, {dt:.2f} s"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stages", nargs="+")
    ap.add_argument("--prim", action="append", default=None)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--old", help="another version of usdahd/bake/unwrap.py to compare with")
    args = ap.parse_args()
    old = None
    if args.old:
        spec = importlib.util.spec_from_file_location("old_unwrap", args.old)
        old = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(old)
    for stage in args.stages:
        scene = load_scene(stage, prims=args.prim)
        for mesh in scene.meshes:
            if not mesh.bake:
                continue
            print(f"{stage} {mesh.path} ({len(mesh.triangles)} triangles)", flush=True)
            if old is not None:
                print(f"  old: {measure(old, mesh, args.resolution)}", flush=True)
            print(f"  new: {measure(new_unwrap, mesh, args.resolution)}", flush=True)


if __name__ == "__main__":
    main()
