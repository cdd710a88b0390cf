"""Lightmap texels of one mesh: sample points, tangent frames, charts, density.

numpy only (no pxr, OpenImageIO or Embree).
See ``docs/texels.md`` for the conventions an engine importer needs (texel/UV convention,
tangent-frame construction) and the contact rule. The UV rasterisation
itself (coverage, winning triangle, barycentrics, UV -> pixel mapping) is
:mod:`usdahd.numerics.raster`, shared with the validator; this module adds the baker's
policy (resolution limits, input checks) and the 3-D side (positions, normals, frames).

Texel ``(x, y)`` covers UV ``[x/w, (x+1)/w] x [1-(y+1)/h, 1-y/h]`` (row 0 = top, v = 1), as
pinned in :mod:`usdahd.bake.types` and :mod:`usdahd.numerics.raster`.

Public functions
----------------
rasterize(mesh, resolution, *, conservative=True) -> Texels
tangent_frames(mesh) -> (tangent (t,3,3), sign (t,))        per-corner MikkTSpace-style tangents
chart_ids(mesh) -> (t,) int32                               UV-connected charts
resolution_for_density(mesh, texels_per_unit, *, max_resolution=8192) -> (w, h)
mesh_from_arrays(points, triangles, *, uv=None, normals=None, path="/mesh") -> MeshData
texel_density(mesh, resolution) -> float                    texels per world unit achieved
half_texel_vectors(mesh, resolution) -> (t, 2, 3)          half a texel along u, v in world units

Contacts, covers and rim texels (sample points moved or flagged where other geometry is
closer than the texel is wide) are :mod:`usdahd.bake.contacts`.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.types import Texels
from usdahd.errors import InputError, UsageError
from usdahd.numerics.raster import rasterize_uv, signed_area2
from usdahd.numerics.triangles import (
    any_perpendicular,
    normalize,
    texel_frame,
    triangle_areas,
    unit_normals,
)
from usdahd.numerics.triangles import barycentrics as triangle_barycentrics
from usdahd.scene.types import MeshData

__all__ = [
    "MAX_RESOLUTION",
    "chart_ids",
    "check_mesh",
    "half_texel_vectors",
    "rasterize",
    "resolution_for_density",
    "tangent_frames",
    "uv_charts",
]

#: Largest lightmap side accepted by default: 8192^2 texels x 27 SH floats is already 7 GB.
MAX_RESOLUTION = 8192


# --------------------------------------------------------------------------------------------
# input checks


def _check_resolution(resolution, max_resolution: int = MAX_RESOLUTION) -> tuple[int, int]:
    try:
        w, h = (int(r) for r in resolution)
    except (TypeError, ValueError):
        raise UsageError(
            f"lightmap resolution must be (width, height), got {resolution!r}"
        ) from None
    if w < 1 or h < 1:
        raise UsageError(f"lightmap resolution must be positive, got {w}x{h}")
    if max(w, h) > max_resolution:
        raise UsageError(
            f"lightmap resolution {w}x{h} exceeds the maximum {max_resolution}; "
            "lower --resolution/--texel-density or raise max_resolution"
        )
    return w, h


def check_mesh(mesh: MeshData) -> np.ndarray:
    if mesh.uv is None:
        raise InputError(
            f"{mesh.path}: mesh has no lightmap UV set {mesh.uv_name!r}; "
            "choose another with --uv or let the baker unwrap it"
        )
    uv = np.asarray(mesh.uv, dtype=np.float64)
    t = len(mesh.triangles)
    if uv.shape != (t, 3, 2):
        raise InputError(f"{mesh.path}: lightmap UVs have shape {uv.shape}, expected ({t}, 3, 2)")
    if not np.isfinite(uv).all():
        raise InputError(f"{mesh.path}: lightmap UVs {mesh.uv_name!r} contain NaN or infinity")
    if not np.isfinite(mesh.points).all():
        raise InputError(f"{mesh.path}: points contain NaN or infinity")
    return uv


def mesh_from_arrays(
    points,
    triangles,
    *,
    uv=None,
    normals=None,
    path: str = "/mesh",
    uv_name: str = "st",
) -> MeshData:
    """A :class:`MeshData` from plain arrays (tests, samples, non-USD callers).

    points (v, 3); triangles (t, 3) counter-clockwise; uv (t, 3, 2) per corner, or (v, 2) per
    vertex; normals (t, 3, 3) per corner, (v, 3) per vertex, or None for flat geometric normals.
    """
    pts = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int32)
    t = len(tri)
    if normals is None:
        g, _ = unit_normals(pts[tri])
        nrm = np.repeat(g[:, None, :], 3, axis=1)
    else:
        nrm = np.asarray(normals, dtype=np.float64)
        if nrm.shape == pts.shape:
            nrm = nrm[tri]
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float32)
        if uv.shape == (len(pts), 2):
            uv = uv[tri]
    return MeshData(
        path=path,
        points=pts,
        triangles=tri,
        normals=nrm.astype(np.float32),
        uv=uv,
        uv_name=uv_name,
        material=np.zeros(t, np.int32),
        face=np.arange(t, dtype=np.int32),
        corner=np.arange(3 * t, dtype=np.int32).reshape(t, 3),
    )


# --------------------------------------------------------------------------------------------
# small vector helpers


# --------------------------------------------------------------------------------------------
# tangent frames


def tangent_frames(mesh: MeshData) -> tuple[np.ndarray, np.ndarray]:
    """Per-corner unit tangents and per-triangle handedness signs (MikkTSpace-style).

    Construction (``docs/texels.md`` spells it out for importers):

    1. Per triangle, ``T = (dp1 * dv2 - dp2 * dv1) * sign`` with ``dp = p_i - p_0``,
       ``d(u,v) = uv_i - uv_0`` and ``sign = +1`` if the UV triangle is counter-clockwise
       (v up) else ``-1``: the direction of dp/du.
    2. Per corner, ``T`` projected into the plane of the corner normal and normalized,
       weighted by the corner's 3-D angle.
    3. Corners that share position, normal, lightmap UV and sign (exact equality, as
       MikkTSpace welds) sum their weighted tangents; the sum is normalized.

    Degenerate-UV triangles contribute nothing to step 3 and take their group's tangent (or any
    vector perpendicular to the normal). Returns ``tangent : (t, 3, 3) float64`` (unit,
    perpendicular to the corner normal) and ``sign : (t,) float64`` of +1/-1.
    """
    uv = check_mesh(mesh)
    pts = np.asarray(mesh.points, dtype=np.float64)
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    nrm, _ = normalize(np.asarray(mesh.normals, dtype=np.float64))
    p = pts[tri]  # (t, 3, 3)
    t = len(tri)

    area2 = signed_area2(uv)
    scale2 = np.max(np.sum((uv - uv[:, [1, 2, 0]]) ** 2, axis=-1), axis=1)
    degenerate = np.abs(area2) <= 1e-12 * scale2 + 1e-30
    sign = np.where(area2 < 0.0, -1.0, 1.0)

    dp1, dp2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    duv1, duv2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    tri_t = (dp1 * duv2[:, 1:2] - dp2 * duv1[:, 1:2]) * sign[:, None]  # (t, 3)

    # per-corner projection and angle weight
    proj = tri_t[:, None, :] - nrm * np.einsum("tci,ti->tc", nrm, tri_t)[..., None]
    corner_t, ok = normalize(proj)
    e_next, _ = normalize(p[:, [1, 2, 0]] - p)
    e_prev, _ = normalize(p[:, [2, 0, 1]] - p)
    angle = np.arccos(np.clip(np.einsum("tci,tci->tc", e_next, e_prev), -1.0, 1.0))
    weight = np.where(ok & ~degenerate[:, None], angle, 0.0)

    # group corners by (position, normal, uv, sign), exact values
    key = np.concatenate(
        [p.reshape(-1, 3), nrm.reshape(-1, 3), uv.reshape(-1, 2), np.repeat(sign, 3)[:, None]],
        axis=1,
    )
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    acc = np.zeros((group.max() + 1 if t else 0, 3))
    contrib = (corner_t * weight[..., None]).reshape(-1, 3)
    for k in range(3):
        acc[:, k] = np.bincount(group, weights=contrib[:, k], minlength=len(acc))
    summed, ok_sum = normalize(acc[group].reshape(t, 3, 3))
    # re-project (corners of a group share the normal, so this is exact up to rounding)
    summed = summed - nrm * np.einsum("tci,tci->tc", nrm, summed)[..., None]
    summed, ok_sum = normalize(summed)
    fallback = np.where(ok[..., None], corner_t, any_perpendicular(_safe_normal(nrm, p)))
    tangent = np.where(ok_sum[..., None], summed, fallback)
    return tangent, sign


def _safe_normal(nrm: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Corner normals, replaced by the geometric normal (or +z) where zero."""
    g, gok = unit_normals(p)
    g = np.where(gok[:, None], g, np.array([0.0, 0.0, 1.0]))
    n2 = np.einsum("...i,...i->...", nrm, nrm)
    return np.where((n2 > 0.5)[..., None], nrm, g[:, None, :])


# --------------------------------------------------------------------------------------------
# charts


def connected_components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Component label (n,) int64 (smallest member index) of the graph with edges a[i]-b[i].

    Vectorized hook-and-compress (Shiloach-Vishkin style); O(log n) rounds in practice.
    """
    parent = np.arange(n, dtype=np.int64)
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    while True:
        pa, pb = parent[a], parent[b]
        diff = pa != pb
        if not diff.any():
            return parent
        lo = np.minimum(pa[diff], pb[diff])
        hi = np.maximum(pa[diff], pb[diff])
        np.minimum.at(parent, hi, lo)
        while True:
            pp = parent[parent]
            if np.array_equal(pp, parent):
                break
            parent = pp


def chart_ids(mesh: MeshData) -> np.ndarray:
    """UV chart of each triangle (t,) int32, numbered 0.. in order of first triangle.

    Two triangles are in the same chart when they share an edge whose two UV endpoints are
    identical (exact values), i.e. charts are the connected pieces of the layout in texture
    space. Used to keep dilation, invalid-texel filling and denoising inside a chart.
    """
    return uv_charts(check_mesh(mesh))


def uv_charts(uv: np.ndarray) -> np.ndarray:
    """:func:`chart_ids` from per-corner UVs ``(t, 3, 2)`` alone (any 2-D coordinates)."""
    uv = np.asarray(uv)
    t = len(uv)
    if t == 0:
        return np.zeros(0, dtype=np.int32)
    ends = np.stack([uv, uv[:, [1, 2, 0]]], axis=2).reshape(t * 3, 2, 2)  # edge endpoints
    # canonical endpoint order
    swap = (ends[:, 0, 0] > ends[:, 1, 0]) | (
        (ends[:, 0, 0] == ends[:, 1, 0]) & (ends[:, 0, 1] > ends[:, 1, 1])
    )
    ends = np.where(swap[:, None, None], ends[:, ::-1], ends)
    _, edge = np.unique(ends.reshape(-1, 4), axis=0, return_inverse=True)
    edge = edge.ravel()
    owner = np.repeat(np.arange(t), 3)
    order = np.argsort(edge, kind="stable")
    e_sorted, o_sorted = edge[order], owner[order]
    same = e_sorted[1:] == e_sorted[:-1]
    labels = connected_components(t, o_sorted[1:][same], o_sorted[:-1][same])
    _, first, inv = np.unique(labels, return_index=True, return_inverse=True)
    # renumber by first triangle
    rank = np.argsort(np.argsort(first))
    return rank[inv.ravel()].astype(np.int32)


# --------------------------------------------------------------------------------------------
# density


def _areas(mesh: MeshData) -> tuple[float, float]:
    uv = check_mesh(mesh)
    p = np.asarray(mesh.points, dtype=np.float64)[np.asarray(mesh.triangles, dtype=np.int64)]
    world = triangle_areas(p).sum()
    uv_area = 0.5 * np.abs(signed_area2(uv)).sum()
    return float(world), float(uv_area)


def texel_density(mesh: MeshData, resolution) -> float:
    """Average texels per world unit (linear) the mesh gets at ``resolution`` (w, h)."""
    w, h = _check_resolution(resolution, max_resolution=np.iinfo(np.int32).max)
    world, uv_area = _areas(mesh)
    if world <= 0.0:
        raise InputError(f"{mesh.path}: mesh has zero surface area")
    return float(np.sqrt(uv_area * w * h / world))


def resolution_for_density(
    mesh: MeshData, texels_per_unit: float, *, max_resolution: int = MAX_RESOLUTION
) -> tuple[int, int]:
    """Square resolution (n, n) giving ``texels_per_unit`` texels per world unit on average.

    n = ceil(texels_per_unit * sqrt(world area / UV area)). Raises UsageError (naming the mesh,
    the needed size and what to do) above ``max_resolution`` instead of exhausting memory.
    """
    if not np.isfinite(texels_per_unit) or texels_per_unit <= 0:
        raise UsageError(f"texel density must be positive, got {texels_per_unit!r}")
    world, uv_area = _areas(mesh)
    if world <= 0.0 or uv_area <= 0.0:
        raise InputError(f"{mesh.path}: mesh has zero surface or lightmap UV area")
    n = int(np.ceil(texels_per_unit * np.sqrt(world / uv_area) - 1e-9))
    n = max(n, 1)
    if n > max_resolution:
        raise UsageError(
            f"{mesh.path}: {texels_per_unit:g} texels per unit needs a {n}x{n} lightmap, above "
            f"the maximum {max_resolution}; lower --texel-density or raise the maximum"
        )
    return n, n


# --------------------------------------------------------------------------------------------
# rasterisation


def rasterize(
    mesh: MeshData,
    resolution,
    *,
    conservative: bool = True,
    max_resolution: int = MAX_RESOLUTION,
    backend: str = "numba",
) -> Texels:
    """Rasterise the lightmap UVs of ``mesh`` at ``resolution`` (w, h) into covered texels.

    Coverage, the triangle each texel takes and its sample point are
    :func:`usdahd.numerics.raster.rasterize_uv` (``conservative``, ``backend`` passed on): a
    texel is covered when its centre lies in a triangle, or (``conservative``) when its square
    overlaps one; then ``center_inside`` is False and the sample point lies inside the part of
    the square the triangle covers (``raster.CONSERVATIVE_INSET``, docs/texels.md). This
    adds the checks (resolution at most ``max_resolution``, finite UVs of shape (t, 3, 2))
    and the 3-D side.

    Returns :class:`~usdahd.bake.types.Texels` sorted by ``y * w + x`` (row-major) with

    position : (n, 3) float32 barycentric interpolation of the triangle's points.
    geom_normal : (n, 3) float32 unit geometric normal (counter-clockwise front).
    frame : (n, 3, 3) float32 rows t, b, n: n = normalized interpolated corner normal,
        t = interpolated corner tangent (:func:`tangent_frames`) Gram-Schmidt against n,
        b = sign * cross(n, t). Orthonormal; det = sign (+1 unless the UV chart is mirrored).
    stats : covered, center_inside, conservative, overlap_texels (centres strictly inside two or
        more triangles), uv_outside_fraction (share of UV corners outside [0, 1]),
        degenerate_uv_triangles, degenerate_triangles (zero 3-D area), mirrored_texels.
    """
    w, h = _check_resolution(resolution, max_resolution)
    uv = check_mesh(mesh)
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    pts = np.asarray(mesh.points, dtype=np.float64)
    t = len(tri)
    r = rasterize_uv(uv, (w, h), conservative=conservative, backend=backend)
    ids, tri_idx, inside, lam = r.ids, r.triangle, r.center_inside, r.barycentrics
    degenerate_uv = r.degenerate
    overlap = len(r.overlap_ids)
    x = ids % w
    y = ids // w
    n = len(tri_idx)

    p = pts[tri[tri_idx]]  # (n, 3, 3)
    position = np.einsum("nc,nci->ni", lam, p)
    gp = pts[tri]
    gnorm, gok = unit_normals(gp)
    nrm_c, _ = normalize(np.asarray(mesh.normals, dtype=np.float64))
    shade, sok = normalize(np.einsum("nc,nci->ni", lam, nrm_c[tri_idx]))
    geom = gnorm[tri_idx]
    geom = np.where(gok[tri_idx][:, None], geom, shade)
    shade = np.where(sok[:, None], shade, geom)
    geom = np.where((np.abs(geom).sum(axis=1) > 0)[:, None], geom, [0.0, 0.0, 1.0])
    shade = np.where((np.abs(shade).sum(axis=1) > 0)[:, None], shade, [0.0, 0.0, 1.0])

    tangent_c, sign = tangent_frames(mesh)
    sgn = sign[tri_idx]
    frame = texel_frame(shade, np.einsum("nc,nci->ni", lam, tangent_c[tri_idx]), sgn)

    xy = np.stack([x, y], axis=1).astype(np.int32)
    stats = {
        "triangles": int(t),
        "covered": int(n),
        "center_inside": int(inside.sum()),
        "conservative": int(n - inside.sum()),
        "overlap_texels": overlap,
        "uv_outside_fraction": float(((uv < 0.0) | (uv > 1.0)).any(axis=-1).mean()) if t else 0.0,
        "degenerate_uv_triangles": int(degenerate_uv.sum()),
        "degenerate_triangles": int((~gok).sum()),
        "mirrored_texels": int((sgn < 0).sum()),
    }
    return Texels(
        resolution=(w, h),
        xy=xy,
        position=position.astype(np.float32),
        geom_normal=geom.astype(np.float32),
        frame=frame.astype(np.float32),
        triangle=tri_idx.astype(np.int32),
        center_inside=inside,
        stats=stats,
    )


def barycentrics(texels: Texels, mesh: MeshData) -> np.ndarray:
    """Barycentric weights (n, 3) float64 of each texel's sample point on its triangle."""
    p = np.asarray(mesh.points, dtype=np.float64)[np.asarray(mesh.triangles)[texels.triangle]]
    return triangle_barycentrics(p, texels.position.astype(np.float64))


def half_texel_vectors(mesh: MeshData, resolution, triangles=None) -> np.ndarray:
    """World vectors (t, 2, 3) float64 of half a texel step along u and along v per triangle
    (of ``triangles``, an index array, when given: then (len(triangles), 2, 3)).

    ``dP/du / (2 w)`` and ``dP/dv / (2 h)`` from the triangle's UV Jacobian; zero for
    triangles with degenerate UVs (their texels are not probed).
    """
    w, h = _check_resolution(resolution, max_resolution=np.iinfo(np.int32).max)
    uv = check_mesh(mesh)
    tris = np.asarray(mesh.triangles, dtype=np.int64)
    if triangles is not None:
        uv, tris = uv[triangles], tris[triangles]
    p = np.asarray(mesh.points, dtype=np.float64)[tris]
    dp = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)  # (t, 3, 2)
    duv = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=2)  # (t, 2, 2)
    det = duv[:, 0, 0] * duv[:, 1, 1] - duv[:, 0, 1] * duv[:, 1, 0]
    scale2 = np.max(np.sum((uv - uv[:, [1, 2, 0]]) ** 2, axis=-1), axis=1)
    ok = np.abs(det) > 1e-12 * scale2 + 1e-30
    safe = np.where(ok, det, 1.0)
    inv = (
        np.stack(
            [
                np.stack([duv[:, 1, 1], -duv[:, 0, 1]], axis=1),
                np.stack([-duv[:, 1, 0], duv[:, 0, 0]], axis=1),
            ],
            axis=1,
        )
        / safe[:, None, None]
    )  # (t, 2, 2) inverse of duv
    jac = np.einsum("tik,tkj->tij", dp, inv)  # (t, 3, 2): columns dP/du, dP/dv
    out = np.stack([jac[:, :, 0] / (2.0 * w), jac[:, :, 1] / (2.0 * h)], axis=1)
    return np.where(ok[:, None, None], out, 0.0)
