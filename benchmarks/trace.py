"""Ray-tracing throughput: end-to-end bake rays/s vs raw Embree trace-only rays/s, same run.

Usage: PYTHONPATH=. python benchmarks/trace.py [--samples 64] [--bounces 2] [--texels 4096]

For each scene (a small procedural room, a ~100k-triangle procedural scene, and
../shared/scenes/classroom when present) it prints: triangles, BVH build time, raw INTERSECT
and OCCLUDED rates (the same Tracer, both threads, random rays from the texel points), the
end-to-end `bake_texels` rate (all rays traced / wall time, including sampling, shading and SH
accumulation) and the ratio end-to-end / raw INTERSECT. Medians of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from pxr import Gf, Usd, UsdGeom, UsdLux  # noqa: E402

from usdahd.bake.integrate import bake_texels  # noqa: E402
from usdahd.bake.trace import Tracer  # noqa: E402
from usdahd.bake.types import Texels  # noqa: E402
from usdahd.sampling import cosine_hemisphere, orthonormal_basis, to_world  # noqa: E402
from usdahd.usd.scene import load_scene  # noqa: E402

CLASSROOM = os.path.join(
    os.path.dirname(__file__), "..", "..", "shared", "scenes", "classroom", "classroom.usdc"
)


def room_stage():
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    m = UsdGeom.Mesh.Define(st, "/room")
    s = 2.0
    p = [(x, y, z) for x in (-s, s) for y in (-s, s) for z in (0, 2 * s)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    m.CreatePointsAttr(p)
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([i for q in quads for i in q[::-1]])
    UsdGeom.Cube.Define(st, "/box").AddTranslateOp().Set(Gf.Vec3d(0.5, 0.3, 0.6))
    lt = UsdLux.RectLight.Define(st, "/light")
    UsdGeom.Xformable(lt).AddTranslateOp().Set(Gf.Vec3d(0, 0, 3.9))
    return st


def big_stage(n_tris=100_000):
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    g = UsdGeom.Mesh.Define(st, "/ground")
    g.CreatePointsAttr([(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0)])
    g.CreateFaceVertexCountsAttr([4])
    g.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    # a bumpy grid "terrain" of spheres-ish heights: n_tris triangles
    k = int(np.sqrt(n_tris / 2))
    x, y = np.meshgrid(np.linspace(-10, 10, k + 1), np.linspace(-10, 10, k + 1))
    z = 1.0 + 0.5 * np.sin(x * 1.3) * np.cos(y * 1.7)
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(k)[:, None] * (k + 1) + np.arange(k)[None, :]
    quads = np.stack([i, i + 1, i + k + 2, i + k + 1], -1).reshape(-1, 4)
    m = UsdGeom.Mesh.Define(st, "/terrain")
    m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts.tolist()])
    m.CreateFaceVertexCountsAttr([4] * len(quads))
    m.CreateFaceVertexIndicesAttr(quads.reshape(-1).tolist())
    lt = UsdLux.DistantLight.Define(st, "/sun")
    UsdGeom.Xformable(lt).AddRotateYOp().Set(-30.0)
    UsdLux.DomeLight.Define(st, "/sky").CreateIntensityAttr(0.3)
    return st


def random_texels(scene, n, rng):
    """Points on random baked triangles with geometric-normal frames (benchmark only)."""
    ms = [m for m in scene.meshes if m.bake] or scene.meshes
    pos, nrm = [], []
    for _ in range(n):
        m = ms[rng.integers(len(ms))]
        t = m.triangles[rng.integers(len(m.triangles))]
        a, b, c = m.points[t]
        r1, r2 = rng.random(2)
        if r1 + r2 > 1:
            r1, r2 = 1 - r1, 1 - r2
        pos.append(a + r1 * (b - a) + r2 * (c - a))
        g = np.cross(b - a, c - a)
        nrm.append(g / max(np.linalg.norm(g), 1e-30))
    pos = np.array(pos, np.float32)
    nrm = np.array(nrm, np.float64)
    return Texels(
        (n, 1),
        np.zeros((n, 2), np.int32),
        pos,
        nrm.astype(np.float32),
        orthonormal_basis(nrm).astype(np.float32),
        np.zeros(n, np.int32),
        np.ones(n, bool),
    )


def raw_rates(tr, tex, n_rays, rng):
    idx = rng.integers(len(tex), size=n_rays)
    p = tex.position[idx].astype(np.float64)
    ng = tex.geom_normal[idx].astype(np.float64)
    d = to_world(cosine_hemisphere(rng.random((n_rays, 2)))[0], tex.frame[idx].astype(np.float64))
    o = np.ascontiguousarray(tr.offset(p, ng, d), np.float32)
    d = np.ascontiguousarray(d, np.float32)
    tf = np.full(n_rays, np.inf, np.float32)
    t0 = time.perf_counter()
    tr._raw_intersect(o, d, tf.copy())
    t1 = time.perf_counter()
    tr._raw_occluded(o, d, tf.copy())
    t2 = time.perf_counter()
    return n_rays / (t1 - t0), n_rays / (t2 - t1)


def bench(name, stage, args):
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    scene = load_scene(stage)
    t_load = time.perf_counter() - t0
    builds, isect, occl, e2e = [], [], [], []
    for _ in range(args.repeat):
        tr = Tracer(scene)
        builds.append(tr.build_time)
        tex = random_texels(scene, args.texels, rng)
        ri, ro = raw_rates(tr, tex, 1 << 20, rng)
        isect.append(ri)
        occl.append(ro)
        t1 = time.perf_counter()
        _, stats = bake_texels(scene, tr, tex, samples=args.samples, bounces=args.bounces)
        e2e.append(stats["rays"] / (time.perf_counter() - t1))
        tr.close()
    med = statistics.median
    ntri = scene.triangle_count
    print(
        f"{name:10s} {ntri:9d} {t_load:7.2f} {med(builds):8.3f} {med(builds) / ntri * 1e6:9.2f} "
        f"{med(isect) / 1e6:8.2f} {med(occl) / 1e6:8.2f} {med(e2e) / 1e6:8.2f} "
        f"{med(e2e) / med(isect):6.2f}"
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=2)
    ap.add_argument("--texels", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    print(
        f"samples={args.samples} bounces={args.bounces} texels={args.texels} "
        f"repeat={args.repeat} (medians; Mrays/s)"
    )
    print(
        f"{'scene':10s} {'tris':>9s} {'load_s':>7s} {'build_s':>8s} {'s/Mtri':>9s} "
        f"{'isect':>8s} {'occl':>8s} {'e2e':>8s} {'ratio':>6s}"
    )
    bench("room", room_stage(), args)
    bench("100k", big_stage(), args)
    if os.path.isfile(CLASSROOM):
        bench("classroom", CLASSROOM, args)
    else:
        print("classroom: skipped (../shared/scenes/classroom absent)")


if __name__ == "__main__":
    main()
