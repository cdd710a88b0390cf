"""A large stage with many small lightmap charts, for timing seam stitching (issues 37 / 43).

    python -m benchmarks.seams make OUT.usda [--prims 17] [--triangles 1400000] [--chart 8]
    python -m benchmarks.seams time STAGE [--resolution 256] [--prims N]  # find_seams + stitch
    python -m benchmarks.seams step STAGE.lightmaps.usda   # brightness step across seams

``make`` writes a stage of ``--prims`` tori in a row (about ``--triangles`` triangles in all,
smooth vertex normals), lit by a DomeLight and a DistantLight. Each torus's ``primvars:st``
is a lightmap atlas of square charts of ``--chart`` x ``--chart`` quads, each chart rotated by
a multiple of 90 degrees in its atlas cell, so every chart border is a UV seam whose two sides
are sampled on different texel grids, as an unwrapper's charts are.

``time`` reads the stage's meshes and times the seam step of a bake alone on a Monte
Carlo-like SH input (noisy, seeded): ``post.find_seams`` over the first ``--prims`` meshes,
then ``post.stitch``.

The seams' share of a whole bake comes from the bake itself (its stderr status lines
``denoised in``, ``seams: stitched in``; ``--json`` holds the total ``seconds``) and
``/usr/bin/time -v`` for its CPU, e.g. ``usdahd bake tori.usdc --resolution 256 --samples 16
--json``; ``time`` over all prims gives the seam step's CPU alone (docs/texels.md, "Seams").

``step`` measures what a viewer sees across the seams of a baked stage: for every seam sample
(``post.find_seams`` on the baked meshes at their baked resolution), the absolute difference of
the decoded irradiance I_z (Rec. 709 luminance, the model's own decoder on the written
textures, bilinear lookups at the sample's UV on each side), as a mean and relative to the mean
I_z of the samples.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def torus(nu: int, nv: int, chart: int, major=1.0, minor=0.35, gutter=0.25):
    """Points (v, 3), quads (q, 4) vertex indices, per-corner UVs (q, 4, 2), normals (v, 3)."""
    u = np.arange(nu) * 2 * np.pi / nu
    v = np.arange(nv) * 2 * np.pi / nv
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = major + minor * np.cos(vv)
    pts = np.stack([ring * np.cos(uu), minor * np.sin(vv), ring * np.sin(uu)], -1).reshape(-1, 3)
    nrm = np.stack([np.cos(vv) * np.cos(uu), np.sin(vv), np.cos(vv) * np.sin(uu)], -1)
    nrm = nrm.reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()

    def vid(a, b):
        return (a % nu) * nv + (b % nv)

    # counter-clockwise seen from outside (normal = d/dv x d/du direction)
    quads = np.stack([vid(i, j), vid(i, j + 1), vid(i + 1, j + 1), vid(i + 1, j)], 1)
    # charts: chart x chart quads, laid out in a square atlas grid, rotated k * 90 degrees
    cu, cv = -(-nu // chart), -(-nv // chart)
    n_charts = cu * cv
    side = int(np.ceil(np.sqrt(n_charts)))
    cell = 1.0 / side
    gutter = gutter * cell
    ci, cj = i // chart, j // chart
    cid = ci * cv + cj
    corner_ij = np.stack(
        [np.stack([i, j], 1), np.stack([i, j + 1], 1), np.stack([i + 1, j + 1], 1),
         np.stack([i + 1, j], 1)], 1)  # fmt: skip
    local = (corner_ij - np.stack([ci * chart, cj * chart], 1)[:, None, :]) / chart  # [0, 1]
    rot = cid % 4
    x, y = local[..., 0], local[..., 1]
    rx = np.select([rot[:, None] == k for k in range(4)], [x, 1 - y, 1 - x, y])
    ry = np.select([rot[:, None] == k for k in range(4)], [y, x, 1 - y, 1 - x])
    ox, oy = (cid % side) * cell + gutter, (cid // side) * cell + gutter
    span = cell - 2 * gutter
    uv = np.stack([ox[:, None] + span * rx, oy[:, None] + span * ry], -1)
    return pts, quads, uv, nrm


def _arr(values, fmt) -> str:
    return "[" + ", ".join(fmt(v) for v in values) + "]"


def write_stage(path: Path, prims: int, triangles: int, chart: int, gutter: float = 0.25) -> dict:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

    quads_per = max(triangles // (2 * prims), 64)
    nv = max(int(np.sqrt(quads_per / 3)) // chart * chart, chart)
    nu = max(quads_per // nv // chart * chart, chart)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    pts, quads, uv, nrm = torus(nu, nv, chart, gutter=gutter)
    total = 0
    for k in range(prims):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Torus{k:02d}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel().astype(np.int32)))
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(nrm.astype(np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
        )
        st.Set(Vt.Vec2fArray.FromNumpy(uv.reshape(-1, 2).astype(np.float32)))
        UsdGeom.XformCommonAPI(mesh).SetTranslate(Gf.Vec3d(2.8 * (k - (prims - 1) / 2), 0, 0))
        total += 2 * len(quads)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateIntensityAttr(0.5)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateNormalizeAttr(True)  # intensity = illuminance
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(-50, 30, 0))
    stage.GetRootLayer().Save()
    return {"stage": str(path), "prims": prims, "triangles": total, "grid": [nu, nv]}


def time_seams(stage: Path, resolution: int, prims: int | None, seed: int = 0) -> dict:
    from usdahd.bake import post
    from usdahd.bake.texels import rasterize
    from usdahd.usd.reader import load_scene

    scene = load_scene(stage)
    meshes = scene.meshes[: prims or None]
    res = (resolution, resolution)
    txs = [rasterize(m, res) for m in meshes]
    rng = np.random.default_rng(seed)
    vals = []
    for t in txs:
        sh = rng.normal(0.0, 0.05, size=(len(t), 3, 9)).astype(np.float32)
        sh[:, :, 0] += 1.0
        sh[:, :, 2] += 0.5
        vals.append(sh)
    t0, c0 = time.perf_counter(), time.process_time()
    seams = post.find_seams(meshes, [t.resolution for t in txs])
    t1, c1 = time.perf_counter(), time.process_time()
    out = post.stitch(vals, txs, seams)
    t2, c2 = time.perf_counter(), time.process_time()
    before = np.abs(post.seam_mismatch(vals, txs, seams)).mean()
    after = np.abs(post.seam_mismatch(out, txs, seams)).mean()
    return {
        "meshes": len(meshes),
        "triangles": int(sum(len(m.triangles) for m in meshes)),
        "texels": int(sum(len(t) for t in txs)),
        "seam_edges": int(seams.edges),
        "seam_samples": len(seams),
        "find_seconds": round(t1 - t0, 3),
        "stitch_seconds": round(t2 - t1, 3),
        "find_cpu_seconds": round(c1 - c0, 3),  # all threads of this process
        "stitch_cpu_seconds": round(c2 - c1, 3),
        "mismatch_before": float(before),
        "mismatch_after": float(after),
    }


def _decoded_iz(results) -> tuple[np.ndarray, np.ndarray]:
    """Decoded I_z luminance (h, w) over the whole (dilated) texture, as a viewer samples it,
    and the sidecar's (undecoded SH) I_z luminance (h, w) (NaN outside the covered texels)."""
    from usdahd import models, sidecar
    from usdahd.numerics import sh as shmod
    from usdahd.usd import schema
    from usdahd.validate.loading import FORMAT_DTYPES, decode_factors, read_image, record_image

    mod = models.get(results.model)
    w, h = results.resolution
    ys, xs = np.mgrid[0:h, 0:w]
    channels = {}
    for lay in mod.layout(results.ratio):
        img = record_image(results, read_image(results.textures[lay.role]))
        channels[lay.role] = img.channels(lay.channels)[ys.ravel(), xs.ravel()].astype(
            FORMAT_DTYPES[lay.format]
        )
    params = mod.decode(channels, ratio=results.ratio, factors=decode_factors(results))
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0], np.float32), (w * h, 3))
    rgb = np.asarray(mod.evaluate(params, z), np.float64)
    decoded = (rgb @ shmod.LUMINANCE).reshape(h, w)
    side = record_image(results, read_image(results.textures[schema.SIDECAR_ROLE]))
    sh, cov = sidecar.split(side.channels(sidecar.CHANNELS).astype(np.float64))
    raw = np.where(cov, (sh[..., 2] * shmod.IZ_FROM_L10) @ shmod.LUMINANCE, np.nan)
    return decoded, raw


def _lookup(img: np.ndarray, taps: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Bilinear lookups (s,) of ``img (h, w)`` with the seam samples' taps and weights."""
    return (img[taps[..., 1], taps[..., 0]] * weights).sum(axis=-1)


def seam_step(layer: Path) -> dict:
    """Brightness step across the seams of a baked layer (see the module doc)."""
    from usdahd.bake import post
    from usdahd.usd import schema
    from usdahd.usd.reader import load_scene
    from usdahd.usd.stage import open_stage

    stage = open_stage(layer)
    baked = {}
    for prim in stage.Traverse():
        results = schema.read_results(prim, validate=False) if prim.IsA(_mesh_type()) else None
        if results is not None:
            baked[str(prim.GetPath())] = results
    if not baked:
        raise SystemExit(f"{layer}: no baked prims")
    uv = next(iter(baked.values())).uv_primvar
    scene = load_scene(stage, uv_name=uv)
    meshes = [m for m in scene.meshes if m.path in baked]
    res = [tuple(baked[m.path].resolution) for m in meshes]
    seams = post.find_seams(meshes, res)
    dec, raw = zip(*(_decoded_iz(baked[m.path]) for m in meshes), strict=True)
    sides, raws = [], []
    for side in range(2):
        look = np.zeros(len(seams))
        rlook = np.zeros(len(seams))
        for mi in range(len(meshes)):
            rows = seams.mesh[:, side] == mi
            tp, wt = seams.taps[rows, side], seams.weights[rows, side]
            look[rows] = _lookup(dec[mi], tp, wt)
            r = raw[mi][tp[..., 1], tp[..., 0]]
            ok = np.isfinite(r) & (wt > 0)
            wn = np.where(ok, wt, 0.0)
            rlook[rows] = (np.where(ok, r, 0.0) * wn).sum(-1) / np.maximum(wn.sum(-1), 1e-30)
        sides.append(look)
        raws.append(rlook)
    step = np.abs(sides[0] - sides[1])
    rstep = np.abs(raws[0] - raws[1])
    level = 0.5 * (sides[0] + sides[1]).mean()
    return {
        "layer": str(layer),
        "prims": len(meshes),
        "seam_edges": int(seams.edges),
        "seam_samples": len(seams),
        "mean_iz": float(level),
        "step_mean": float(step.mean()),
        "step_mean_relative": float(step.mean() / level),
        "step_p95_relative": float(np.percentile(step, 95) / level),
        "sidecar_step_mean_relative": float(rstep.mean() / level),
    }


def _mesh_type():
    from pxr import UsdGeom

    return UsdGeom.Mesh


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.seams", description=__doc__.split("\n")[0]
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("out", type=Path)
    m.add_argument("--prims", type=int, default=17)
    m.add_argument("--triangles", type=int, default=1_400_000)
    m.add_argument("--chart", type=int, default=8)
    m.add_argument("--gutter", type=float, default=0.25, help="gap around a chart, of its cell")
    t = sub.add_parser("time")
    t.add_argument("stage", type=Path)
    t.add_argument("--resolution", type=int, default=256)
    t.add_argument("--prims", type=int, default=None)
    s = sub.add_parser("step")
    s.add_argument("layer", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "make":
        out = write_stage(args.out, args.prims, args.triangles, args.chart, args.gutter)
    elif args.cmd == "time":
        out = time_seams(args.stage, args.resolution, args.prims)
    else:
        out = seam_step(args.layer)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
