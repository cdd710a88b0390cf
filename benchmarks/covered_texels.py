"""Covered texels of a baked layer (issue 37, the chess pieces' feet): per baked prim, how many
texels :func:`usdahd.bake.contacts.covered` flags and what the bake stored there.

    python benchmarks/covered_texels.py BAKED.lightmaps.usda [--prim PRIM ...] [--distance D]
                                        [--json]

Each prim's lightmap UVs are rasterised at its texture's size, the sample points pushed off
contacts as the bake does (:func:`usdahd.bake.contacts.push_off_contacts`), and the covered test
run with the probe length ``D`` texels (default ``contacts.COVERED_DISTANCE``). Printed per prim:
the texels, the covered ones, and of those how many the layer stores dark (luminance of the
``iz`` texture < 0.02: a bake before the rule, or filled from dark neighbours) and lit (> 0.3:
candidates for false positives), and the rim texels (points moved out from under a low cover,
:func:`usdahd.bake.contacts.move_off_covers`) with how many of those it stores dark.
docs/texels.md, "Covered texels" and "Rim texels".
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np


def covered_texels(layer: str, prims=None, distance: float | None = None) -> list[dict]:
    from usdahd.bake import contacts as C
    from usdahd.bake import texels as T
    from usdahd.bake.trace import Tracer
    from usdahd.preview.meshes import baked_meshes, preview_scene
    from usdahd.usd import schema

    _, meshes, _ = baked_meshes(layer)
    scene = preview_scene(layer, meshes[0][1].uv_primvar)
    tracer = Tracer(scene)
    if distance is not None:
        C.COVERED_DISTANCE = float(distance)
    index = {m.path: i for i, m in enumerate(scene.meshes)}
    out = []
    for mesh, res, *_ in meshes:
        if prims and mesh.path not in prims:
            continue
        mi = index[mesh.path]
        iz = np.asarray(schema.read_record_pixels(res, "iz"), np.float64)
        h, w = iz.shape[:2]
        lum = iz[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        tx = T.rasterize(scene.meshes[mi], (w, h))
        t1 = time.perf_counter()
        before = tx.position
        tx, stuck = C.push_off_contacts(tx, scene.meshes[mi], tracer)
        push_seconds = time.perf_counter() - t1
        t0 = time.perf_counter()
        size = C.texel_sizes(tx, scene.meshes[mi])
        cov = C.covered(tx.position, tx.geom_normal, tracer.texel_offsets(tx, mi), size, tracer)
        cov &= ~stuck
        seconds = time.perf_counter() - t0
        v = lum[tx.xy[:, 1], tx.xy[:, 0]]
        # rim texels: points moved out from under a low cover (push_off_contacts' last step)
        # (recomputed from the rasterised points, without the contact moves before it)
        rim = C.move_off_covers(replace(tx, position=before), scene.meshes[mi], tracer, stuck)[1]
        out.append(
            {
                "prim": mesh.path,
                "texels": len(tx),
                "texel_size_median": float(np.median(size)),
                "covered": int(cov.sum()),
                "covered_dark": int((cov & (v < 0.02)).sum()),
                "covered_lit": int((cov & (v > 0.3)).sum()),
                "rim": int(rim.sum()),
                "rim_dark": int((rim & (v < 0.02)).sum()),
                "seconds": seconds,
                "push_seconds": push_seconds,
            }
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("layer")
    ap.add_argument("--prim", action="append", default=[])
    ap.add_argument("--distance", type=float, default=None, help="probe length in texels")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    rows = covered_texels(a.layer, a.prim, a.distance)
    if a.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(
            f"{r['prim']}: {r['texels']} texels ({1000 * r['texel_size_median']:.2f} mm), "
            f"covered {r['covered']} (stored dark {r['covered_dark']}, lit {r['covered_lit']}), "
            f"rim {r['rim']} (stored dark {r['rim_dark']})"
        )
    keys = ("texels", "covered", "covered_dark", "rim", "rim_dark", "seconds", "push_seconds")
    tot = {k: sum(r[k] for r in rows) for k in keys}
    print(
        f"total: {tot['texels']} texels, covered {tot['covered']}, stored dark "
        f"{tot['covered_dark']}, covered test {tot['seconds']:.1f} s; rim {tot['rim']} (stored "
        f"dark {tot['rim_dark']}), push_off_contacts {tot['push_seconds']:.1f} s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
