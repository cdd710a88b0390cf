"""Point probes: make Cycles sample the irradiance at each texel's *centre*, not over its box.

Cycles' bake jitters every sample but the first uniformly over the texel (in the triangle's
barycentrics, through the pixel's UV differentials) and retries a jitter that leaves the
triangle (``integrator_init_from_bake`` / ``bake_jitter_barycentric``): its texel value is a
box average whose centroid moves off the centre where a triangle edge crosses the texel.
usdahd estimates the value *at* the texel centre (``docs/texels.md``). On steep gradients (a
lamp near a floor, a sun shadow edge) the two differ by more than either renderer's noise.

A probe is a tiny triangle, one per covered texel, that Cycles bakes instead of the mesh:

* in space it sits at the texel's centre point (the point usdahd's rasteriser gives the texel:
  :func:`usdahd.numerics.raster.rasterize_uv`, centre-inside texels only), lifted by
  ``LIFT`` texel widths along the face normal, in the plane perpendicular to the
  interpolated shading normal (the face's plane where that normal tilts more than 1 degree:
  ``TILT_COS``), ``SIZE`` texel widths across: Cycles' jitter can only move the sample inside
  it, i.e. by <= SIZE / 2 of a texel; its custom normals are the shading normal;
* in UV it is a small triangle around the centre of its own pixel of the (w, h) bake image
  (circumradius ``UV_RADIUS`` pixels), so Blender gives it exactly that pixel;
* its object is invisible to every diffuse, glossy, transmission and shadow ray, so
  it does not shade or shadow the scene; the real mesh stays in the scene, unbaked.

The result is a point-sampled truth with the texel layout of the box one and the same cost
(one bake pixel per texel). Texels whose centre lies outside every triangle (usdahd's
conservative edge texels) get no probe and stay NaN.

numpy + usdahd.numerics only (runs in the project's environment; ``cycles_bake.py`` reads the
file it writes).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from benchmarks.reference.npzio import save_npz
from usdahd.numerics.offsets import triangle_offset_scale
from usdahd.numerics.raster import rasterize_uv

#: Probe triangle size, in texel widths (its circumradius is SIZE / 2): bounds how far Cycles'
#: jitter moves a sample off the centre. 1/100 of a texel: the footprint error of a box of
#: width b on a gradient scales with b (edge-clipped) or b^2 (symmetric), so << the noise.
SIZE = 0.01
#: Lift along the face normal, in texel widths: the probe must not be coplanar with the mesh
#: (its rays would hit the mesh at t ~ 0). 1/1000 of a texel moves the irradiance by far less
#: than the truth's noise.
LIFT = 0.001
#: Floors in float32 ulps of the point's magnitude (Cycles stores positions in float32): the
#: size keeps the probe's face normal (it only orients ray offsets; shading uses the custom
#: normal) within ~1/256 rad; the lift keeps the probe off the mesh's plane after rounding. The
#: lift's floor is small on purpose: on a lamp h above a floor the irradiance moves by
#: 2 lift / h (32 ulps at |p| = 2 m, h = 0.15 m: 0.01 %).
SIZE_ULPS = 256.0
LIFT_ULPS = 32.0
#: Caps in float32 terms of the triangle under the probe, for huge texels (the classroom's
#: 221 m ground quad at 24^2 has 9.2 m texels, where 1/1000 and 1/100 of a texel are 9.2 mm
#: and 9.2 cm, and a window's sun penumbra on it is 4.6 cm wide): the lift is at most usdahd's
#: own ray offset there (:func:`usdahd.numerics.offsets.triangle_offset_scale`: 64 ulps of the
#: triangle's largest coordinate, which Embree, Cycles' CPU intersector, does not re-hit), so
#: both renderers sample the same height; the size at most SIZE_LIFTS such offsets.
SIZE_LIFTS = 16.0
#: A probe lies in its face's plane (lifted by ``lift`` along the face normal), not
#: perpendicular to the shading normal, once that normal tilts more than 1 degree from the face
#: (cos below TILT_COS). Perpendicular to a normal tilted by t, the probe's edge dips by
#: radius sin t, and its radius is 5-8 lifts: from t ~ 7 degrees part of it lay under the mesh,
#: where the mesh shadowed it (measured 2026-12-05 on a flat quad whose corner normals lean
#: 15 degrees toward a crease: Cycles' point truth 0.712 at the crease where the sun term is
#: 0.787, -9.5 %; usdahd and the truth agreed from 7 texels away). The face plane is also what
#: usdahd's estimator assumes: the cosine about the shading normal, no directions under the
#: face. Below 1 degree the plane is the shading normal's, as before (so probes of flat
#: meshes are unchanged and their cached truths stay valid: the cache key hashes the probes).
TILT_COS = float(np.cos(np.radians(1.0)))
#: Probe circumradius in bake-image pixels: Blender's bake lattice samples each pixel at
#: (x + 0.501, y + 0.502) (RE_bake_pixels_populate), well inside 0.3 px (inradius 0.15 px);
#: no neighbouring pixel's sample point is within 0.5 px.
UV_RADIUS = 0.3


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def mesh_probes(tri_p, tri_n, tri_uv, resolution) -> dict:
    """Probe triangles of one baked mesh.

    tri_p : (t, 3, 3) float64 world corners; tri_n : (t, 3, 3) unit shading normals per corner;
    tri_uv : (t, 3, 2) float64 lightmap UVs; resolution : (w, h).
    returns : {"p": (n, 3, 3) float64 probe corners (counter-clockwise about the shading
    normal, or about the face normal where the two differ by more than 1 degree), "n": (n, 3)
    float64 unit shading normal, "uv": (n, 3, 2) float64 probe UVs,
    "ids": (n,) int64 texel ids y * w + x, "width": (n,) float64 texel width in metres}.
    """
    w, h = (int(r) for r in resolution)
    ok = np.isfinite(tri_uv).all(axis=(1, 2))
    idx = np.nonzero(ok)[0]
    r = rasterize_uv(tri_uv[idx], (w, h), conservative=False)
    keep = r.center_inside
    ids, tri, lam = r.ids[keep], idx[r.triangle[keep]], r.barycentrics[keep]
    P = tri_p[tri]
    p = np.einsum("nk,nkd->nd", lam, P)
    n = _unit(np.einsum("nk,nkd->nd", lam, tri_n[tri]))
    ng = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area3 = 0.5 * np.linalg.norm(ng, axis=1)
    ng = _unit(ng)
    ng *= np.where((ng * n).sum(axis=1) < 0, -1.0, 1.0)[:, None]  # the side the normal is on
    puv = tri_uv[tri] * np.array([w, h])
    area_px = 0.5 * np.abs(
        (puv[:, 1, 0] - puv[:, 0, 0]) * (puv[:, 2, 1] - puv[:, 0, 1])
        - (puv[:, 2, 0] - puv[:, 0, 0]) * (puv[:, 1, 1] - puv[:, 0, 1])
    )
    width = np.sqrt(area3 / np.maximum(area_px, 1e-300))  # metres per texel
    ulp = np.finfo(np.float32).eps * np.maximum(np.abs(p).max(axis=1), 1.0)
    cap = triangle_offset_scale(P)  # usdahd's ray offset on each probe's triangle
    size = np.maximum(np.minimum(SIZE * width, SIZE_LIFTS * cap), SIZE_ULPS * ulp)
    lift = np.maximum(np.minimum(LIFT * width, cap), LIFT_ULPS * ulp)
    centre = p + lift[:, None] * ng
    # the probe's plane: about the shading normal where it (nearly) is the face normal, else
    # the face's own plane (a probe perpendicular to a tilted normal dips through the mesh)
    axis = np.where(((n * ng).sum(axis=1) >= TILT_COS)[:, None], n, ng)
    a = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = _unit(np.cross(a, axis))
    b = np.cross(axis, t)
    ang = np.array([0.5, 0.5 + 2.0 / 3.0, 0.5 + 4.0 / 3.0]) * np.pi  # counter-clockwise
    rad = 0.5 * size
    corners = centre[:, None, :] + rad[:, None, None] * (
        np.cos(ang)[None, :, None] * t[:, None, :] + np.sin(ang)[None, :, None] * b[:, None, :]
    )
    # UV: same angles about the pixel centre, counter-clockwise in UV (v up)
    x, y = ids % w, ids // w
    cu = (x + 0.5) / w
    cv = 1.0 - (y + 0.5) / h
    uv = np.stack(
        [
            cu[:, None] + UV_RADIUS * np.cos(ang)[None, :] / w,
            cv[:, None] + UV_RADIUS * np.sin(ang)[None, :] / h,
        ],
        axis=-1,
    )
    return {"p": corners, "n": n, "uv": uv, "ids": ids, "width": width}


def scene_probes(scene_file) -> dict:
    """Probes of every baked mesh of an exported scene file (``export.save_scene``): {``p_<k>``,
    ``n_<k>``, ``uv_<k>``: arrays of :func:`mesh_probes` per mesh k}."""
    data = np.load(scene_file, allow_pickle=False)
    meta = json.loads(str(data["meta"]))
    tri_mesh = data["tri_mesh"]
    arrays = {}
    for k, m in enumerate(meta["meshes"]):
        sel = np.nonzero(tri_mesh == k)[0]
        if not m["baked"] or len(sel) == 0:
            continue
        pr = mesh_probes(data["tri_p"][sel], data["tri_n"][sel], data["tri_uv"][sel],
                         m["resolution"])  # fmt: skip
        arrays.update({f"p_{k}": pr["p"], f"n_{k}": pr["n"], f"uv_{k}": pr["uv"]})
    return arrays


def probes_digest(arrays: dict) -> str:
    """Content hash (16 hex digits) of :func:`scene_probes` arrays: a point truth's cache key
    (benchmarks/reference/runner.py), so only truths whose probes change are recomputed."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def write_probes(scene_file, out_file) -> dict:
    """:func:`scene_probes` written atomically to ``out_file`` (npz); returns {mesh index:
    probe count}."""
    arrays = scene_probes(scene_file)
    save_npz(out_file, arrays, prefix=".probes.")
    return {int(k[2:]): len(v) for k, v in arrays.items() if k.startswith("p_")}
