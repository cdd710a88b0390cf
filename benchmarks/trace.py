"""Ray-tracing throughput: end-to-end bake rays/s vs raw Embree trace-only rays/s, same run.

Usage: PYTHONPATH=. python benchmarks/trace.py [--samples 64] [--bounces 2] [--texels 4096]
       [--repeat 3] [--no-reference]

For each scene (a small procedural room, a ~100k-triangle procedural scene, and
../shared/scenes/classroom when present) it prints, per tracer backend (``native`` = libembree4
called from numba, the default; ``embreex`` = the pure-embreex numpy reference): triangles, BVH
build time (and per million triangles), raw INTERSECT and OCCLUDED rates (both threads, the same
random cosine rays from the texel points for both backends), the end-to-end ``bake_texels`` rate
(all rays traced / wall time, including sampling, shading and SH accumulation) and the ratios
end-to-end / raw INTERSECT of the same backend (``ratio``) and of embreex (``vs_ex``), each
ratio from raw rates measured right before and after its bake (the machine may be shared).
The raw rays are cosine-distributed; ``isect_u``/``ratio_u`` repeat the raw INTERSECT rate with
uniform-hemisphere rays, the distribution of the bake's own primary rays (grazing rays cost
more on bumpy geometry). The raw rates are single-ray queries (``rtcIntersect1``, embreex's own
batches); the native bake traces 16-ray packets, so ``pk16``/``ratio_pk`` repeat the raw cosine
INTERSECT rate through the same packet call (``embree.intersect_rays``, both threads).
Medians of ``--repeat`` runs; JIT kernels are warmed up (loaded from numba's cache) first.
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
from usdahd.bake.kernels import embree  # noqa: E402
from usdahd.bake.trace import Tracer  # noqa: E402
from usdahd.bake.types import Texels  # noqa: E402
from usdahd.numerics.sampling import (  # noqa: E402
    cosine_hemisphere,
    orthonormal_basis,
    to_world,
    uniform_hemisphere,
)
from usdahd.usd.reader import load_scene  # noqa: E402

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


def raw_rates(tr, o, d):
    """Raw INTERSECT and OCCLUDED rays/s of ``tr`` on rays (o, d) (float32)."""
    tf = np.full(len(o), np.inf, np.float32)
    t0 = time.perf_counter()
    tr._raw_intersect(o, d, tf.copy())
    t1 = time.perf_counter()
    tr._raw_occluded(o, d, tf.copy())
    t2 = time.perf_counter()
    return len(o) / (t1 - t0), len(o) / (t2 - t1)


def packet_rate(tr, rays):
    """Raw INTERSECT rays/s through 16-ray packets (native backend; ``rays`` (m,7) float64),
    both threads over halves of the batch."""

    def run(r):
        hits = np.empty((len(r), 7))
        pk, rec = embree.new_packet(), embree.new_scratch()
        embree.intersect_rays(tr.native_handle, pk, rec, r, len(r), hits)

    t0 = time.perf_counter()
    tr._split(run, len(rays), rays)
    return len(rays) / (time.perf_counter() - t0)


def test_rays(tr, tex, n_rays, rng, sampler=cosine_hemisphere):
    """Random rays from the texel points: cosine-distributed (the headline raw rate) or
    uniform over the hemisphere (``uniform_hemisphere``: the bake's own primary rays)."""
    idx = rng.integers(len(tex), size=n_rays)
    p = tex.position[idx].astype(np.float64)
    ng = tex.geom_normal[idx].astype(np.float64)
    d = to_world(sampler(rng.random((n_rays, 2)))[0], tex.frame[idx].astype(np.float64))
    o = np.ascontiguousarray(tr.offset(p, ng, d), np.float32)
    return o, np.ascontiguousarray(d, np.float32)


def bench(name, stage, args):
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    scene = load_scene(stage)
    t_load = time.perf_counter() - t0
    backends = ["native"] + ([] if args.no_reference else ["embreex"])
    keys = ("build", "isect", "occl", "e2e", "ratio", "vs_ex", "isect_u", "ratio_u", "pk16",
            "ratio_pk")  # fmt: skip
    res = {b: {k: [] for k in keys} for b in ("native", "embreex")}
    for _ in range(args.repeat):
        tex = random_texels(scene, args.texels, rng)
        trs = {b: Tracer(scene, backend=b) for b in ("native", "embreex")}
        o, d = test_rays(trs["native"], tex, 1 << 20, rng)
        rays = np.c_[o.astype(np.float64), d.astype(np.float64), np.full(len(o), np.inf)]
        ou, du = test_rays(trs["native"], tex, 1 << 20, rng, uniform_hemisphere)
        for b, tr in trs.items():
            res[b]["build"].append(tr.build_time)
            raw_rates(tr, o[:1000], d[:1000])  # warm up (JIT cache load, thread pool)
            bake_texels(scene, tr, _head(tex, 8), samples=4, bounces=1)
        packet_rate(trs["native"], rays[:1000])
        # raw and end-to-end back to back, so each ratio sees the same machine load
        for b in backends:
            tr = trs[b]
            ri, ro = raw_rates(tr, o, d)
            t1 = time.perf_counter()
            _, stats = bake_texels(scene, tr, tex, samples=args.samples, bounces=args.bounces)
            e2e = stats["rays"] / (time.perf_counter() - t1)
            ri2, ro2 = raw_rates(tr, o, d)
            ru = raw_rates(tr, ou, du)[0]
            rx = raw_rates(trs["embreex"], o, d)[0] if b == "native" else ri
            raw = 0.5 * (ri + ri2)
            rp = packet_rate(tr, rays) if b == "native" else float("nan")
            vals = (raw, 0.5 * (ro + ro2), e2e, e2e / raw, e2e / rx, ru, e2e / ru, rp, e2e / rp)
            for k, v in zip(keys[1:], vals):
                res[b][k].append(v)
        if args.no_reference:
            res["embreex"]["isect"].append(raw_rates(trs["embreex"], o, d)[0])
        for tr in trs.values():
            tr.close()
    med = statistics.median
    ntri = scene.triangle_count
    for b in backends + (["embreex"] if args.no_reference else []):
        r = {k: med(v) if v else float("nan") for k, v in res[b].items()}
        print(
            f"{name:10s} {b:8s} {ntri:9d} {t_load:7.2f} {r['build']:8.3f} "
            f"{r['build'] / ntri * 1e6:7.2f} {r['isect'] / 1e6:7.2f} {r['occl'] / 1e6:7.2f} "
            f"{r['e2e'] / 1e6:7.2f} {r['ratio']:6.2f} {r['vs_ex']:6.2f} "
            f"{r['isect_u'] / 1e6:7.2f} {r['ratio_u']:7.2f} {r['pk16'] / 1e6:7.2f} "
            f"{r['ratio_pk']:8.2f}"
        )


def _head(tex, n):
    n = min(n, len(tex))
    return Texels(
        (n, 1), tex.xy[:n], tex.position[:n], tex.geom_normal[:n], tex.frame[:n],
        tex.triangle[:n], tex.center_inside[:n],
    )  # fmt: skip


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--bounces", type=int, default=2)
    ap.add_argument("--texels", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-reference", action="store_true", help="skip the embreex bake")
    args = ap.parse_args(argv)
    print(
        f"samples={args.samples} bounces={args.bounces} texels={args.texels} "
        f"repeat={args.repeat} (medians; Mrays/s)"
    )
    print(
        f"{'scene':10s} {'backend':8s} {'tris':>9s} {'load_s':>7s} {'build_s':>8s} "
        f"{'s/Mtri':>7s} {'isect':>7s} {'occl':>7s} {'e2e':>7s} {'ratio':>6s} {'vs_ex':>6s} "
        f"{'isect_u':>7s} {'ratio_u':>7s} {'pk16':>7s} {'ratio_pk':>8s}"
    )
    bench("room", room_stage(), args)
    bench("100k", big_stage(), args)
    if os.path.isfile(CLASSROOM):
        bench("classroom", CLASSROOM, args)
    else:
        print("classroom: skipped (../shared/scenes/classroom absent)")


if __name__ == "__main__":
    main()
