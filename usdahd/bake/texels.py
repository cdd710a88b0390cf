"""Lightmap texels of one mesh: conservative UV rasterisation, sample points and tangent frames.

numpy only (no pxr, OpenImageIO or Embree). See ``docs/texels.md`` for the conventions an
engine importer needs (texel/UV convention, tangent-frame construction).

Texel ``(x, y)`` covers UV ``[x/w, (x+1)/w] x [1-(y+1)/h, 1-y/h]`` (row 0 = top, v = 1), as
pinned in :mod:`usdahd.bake.types`. Internally UVs are mapped to *pixel coordinates*
``px = u * w``, ``py = (1 - v) * h`` in which texel ``(x, y)`` is the unit square
``[x, x+1] x [y, y+1]`` and its centre is ``(x + 0.5, y + 0.5)``.

Public functions
----------------
rasterize(mesh, resolution, *, conservative=True) -> Texels
tangent_frames(mesh) -> (tangent (t,3,3), sign (t,))        per-corner MikkTSpace-style tangents
chart_ids(mesh) -> (t,) int32                               UV-connected charts
resolution_for_density(mesh, texels_per_unit, *, max_resolution=8192) -> (w, h)
mesh_from_arrays(points, triangles, *, uv=None, normals=None, path="/mesh") -> MeshData
texel_density(mesh, resolution) -> float                    texels per world unit achieved
uv_to_pixel(uv, resolution) -> (..., 2) float64             UV -> pixel coordinates
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.types import Texels
from usdahd.errors import InputError, UsageError
from usdahd.scene.types import MeshData

#: Largest lightmap side accepted by default: 8192^2 texels x 27 SH floats is already 7 GB.
MAX_RESOLUTION = 8192

# Tolerances (pixel units = texels), one place, each with its reason.
#: A texel square must overlap a triangle by more than this to count as covered, so texels that
#: only touch a triangle along a texel boundary (charts aligned with the grid) are not covered.
COVER_EPS = 1e-6
#: A texel centre counts as "strictly inside" a triangle (for the UV-overlap statistic) when it
#: is farther than this from every edge; centres on a shared edge of adjacent triangles are not
#: overlap.
OVERLAP_EPS = 1e-4
#: |2 x signed UV area| in texels^2 below this -> degenerate UV triangle (no barycentrics).
DEGENERATE_UV_AREA2 = 1e-10
#: Squared length below which a vector is treated as zero (tangent/normal fallbacks).
TINY2 = 1e-24
#: Candidate texels per vectorized chunk: bounds peak memory (~100 bytes per candidate).
CHUNK = 1 << 20


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


def _check_mesh(mesh: MeshData) -> np.ndarray:
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


def uv_to_pixel(uv: np.ndarray, resolution) -> np.ndarray:
    """UV (..., 2) -> pixel coordinates (..., 2) float64: ``(u * w, (1 - v) * h)``."""
    w, h = resolution
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([uv[..., 0] * w, (1.0 - uv[..., 1]) * h], axis=-1)


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
        g, _ = _normalize(
            np.cross(pts[tri[:, 1]] - pts[tri[:, 0]], pts[tri[:, 2]] - pts[tri[:, 0]])
        )
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


def _normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors and a mask of which inputs were non-zero."""
    n2 = np.einsum("...i,...i->...", v, v)
    ok = n2 > TINY2
    out = np.where(ok[..., None], v / np.sqrt(np.where(ok, n2, 1.0))[..., None], 0.0)
    return out, ok


def _any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to unit ``n`` (..., 3): Duff et al. 2017 branchless ONB."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    return np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


# --------------------------------------------------------------------------------------------
# tangent frames


def _uv_signed_area2(uv: np.ndarray) -> np.ndarray:
    """Twice the signed UV-space area (t,) of each triangle (> 0: counter-clockwise, v up)."""
    return _cross2(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0])


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
    uv = _check_mesh(mesh)
    pts = np.asarray(mesh.points, dtype=np.float64)
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    nrm, _ = _normalize(np.asarray(mesh.normals, dtype=np.float64))
    p = pts[tri]  # (t, 3, 3)
    t = len(tri)

    area2 = _uv_signed_area2(uv)
    scale2 = np.max(np.sum((uv - uv[:, [1, 2, 0]]) ** 2, axis=-1), axis=1)
    degenerate = np.abs(area2) <= 1e-12 * scale2 + 1e-30
    sign = np.where(area2 < 0.0, -1.0, 1.0)

    dp1, dp2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    duv1, duv2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    tri_t = (dp1 * duv2[:, 1:2] - dp2 * duv1[:, 1:2]) * sign[:, None]  # (t, 3)

    # per-corner projection and angle weight
    proj = tri_t[:, None, :] - nrm * np.einsum("tci,ti->tc", nrm, tri_t)[..., None]
    corner_t, ok = _normalize(proj)
    e_next, _ = _normalize(p[:, [1, 2, 0]] - p)
    e_prev, _ = _normalize(p[:, [2, 0, 1]] - p)
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
    summed, ok_sum = _normalize(acc[group].reshape(t, 3, 3))
    # re-project (corners of a group share the normal, so this is exact up to rounding)
    summed = summed - nrm * np.einsum("tci,tci->tc", nrm, summed)[..., None]
    summed, ok_sum = _normalize(summed)
    fallback = np.where(ok[..., None], corner_t, _any_perpendicular(_safe_normal(nrm, p)))
    tangent = np.where(ok_sum[..., None], summed, fallback)
    return tangent, sign


def _safe_normal(nrm: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Corner normals, replaced by the geometric normal (or +z) where zero."""
    g, gok = _normalize(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
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
    return uv_charts(_check_mesh(mesh))


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
    uv = _check_mesh(mesh)
    p = np.asarray(mesh.points, dtype=np.float64)[np.asarray(mesh.triangles, dtype=np.int64)]
    world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    uv_area = 0.5 * np.abs(_uv_signed_area2(uv)).sum()
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


def _candidates(px: np.ndarray, w: int, h: int):
    """Per-triangle texel bounding boxes (clipped): x0, y0, width, height (int64, >= 0)."""
    lo = px.min(axis=1)
    hi = px.max(axis=1)
    x0 = np.clip(np.floor(lo[:, 0] + COVER_EPS), 0, w).astype(np.int64)
    y0 = np.clip(np.floor(lo[:, 1] + COVER_EPS), 0, h).astype(np.int64)
    x1 = np.clip(np.ceil(hi[:, 0] - COVER_EPS) - 1, -1, w - 1).astype(np.int64)
    y1 = np.clip(np.ceil(hi[:, 1] - COVER_EPS) - 1, -1, h - 1).astype(np.int64)
    bw = np.maximum(x1 - x0 + 1, 0)
    bh = np.maximum(y1 - y0 + 1, 0)
    return x0, y0, bw, bh


def _closest_on_segment(c, a, b):
    ab = b - a
    l2 = np.einsum("ni,ni->n", ab, ab)
    s = np.clip(np.einsum("ni,ni->n", c - a, ab) / np.where(l2 > 0, l2, 1.0), 0.0, 1.0)
    q = a + s[:, None] * ab
    d2 = np.einsum("ni,ni->n", c - q, c - q)
    return q, d2


def _closest_point(c: np.ndarray, P: np.ndarray):
    """Closest point q (m, 2) of triangles P (m, 3, 2) to points c (m, 2) lying outside them,
    and the squared distance (m,)."""
    best_q, best_d2 = _closest_on_segment(c, P[:, 0], P[:, 1])
    for i in (1, 2):
        qi, di = _closest_on_segment(c, P[:, i], P[:, (i + 1) % 3])
        better = di < best_d2
        best_q = np.where(better[:, None], qi, best_q)
        best_d2 = np.where(better, di, best_d2)
    return best_q, best_d2


def _edge_distances(c: np.ndarray, P: np.ndarray, area2: np.ndarray):
    """Signed distances (m, 3) of points c (m, 2) to the edge lines of triangles P (m, 3, 2),
    positive inside; edge i is opposite corner i. Also the unit-normal box half-widths (m, 3)
    of a texel square along each edge normal."""
    a = P[:, [1, 2, 0]]
    e = P[:, [2, 0, 1]] - a
    elen = np.sqrt(np.einsum("mei,mei->me", e, e))
    elen = np.where(elen > 0, elen, 1.0)
    dist = _cross2(e, c[:, None, :] - a) * np.sign(area2)[:, None] / elen
    half = 0.5 * (np.abs(e[..., 0]) + np.abs(e[..., 1])) / elen
    return dist, half


# -- numpy reference path ------------------------------------------------------------------


def _raster_numpy(px, area2, live, w, h, conservative):
    """Winner triangle per covered texel. Returns (ids (n,) int64 sorted texel ids y * w + x,
    tri (n,) int64, number of texels whose centre is strictly inside two or more triangles)."""
    x0, y0, bw, bh = _candidates(px[live], w, h)
    counts = bw * bh
    has = counts > 0
    live, x0, y0, bw = live[has], x0[has], y0[has], bw[has]
    starts = np.concatenate([[0], np.cumsum(counts[has])])
    total = int(starts[-1])
    ids_l, tri_l, score_l, strict_l = [], [], [], []
    for k0 in range(0, total, CHUNK):
        k = np.arange(k0, min(total, k0 + CHUNK), dtype=np.int64)
        j = np.searchsorted(starts, k, side="right") - 1
        local = k - starts[j]
        x = x0[j] + local % bw[j]
        y = y0[j] + local // bw[j]
        c = np.stack([x + 0.5, y + 0.5], axis=1)
        t = live[j]
        dist, half = _edge_distances(c, px[t], area2[t])
        inside = (dist >= 0.0).all(axis=1)
        keep = ((dist + half) > COVER_EPS).all(axis=1) if conservative else inside
        strict_l.append((y * w + x)[(dist > OVERLAP_EPS).all(axis=1)])
        idx = np.nonzero(keep)[0]
        score = -dist[idx].min(axis=1)
        out = np.nonzero(~inside[idx])[0]
        if len(out):
            _, d2 = _closest_point(c[idx[out]], px[t[idx[out]]])
            score[out] = d2
        ids_l.append((y * w + x)[idx])
        tri_l.append(t[idx])
        score_l.append(score)
    if not ids_l:
        z = np.zeros(0, np.int64)
        return z, z, 0
    ids, tri, score = (np.concatenate(v) for v in (ids_l, tri_l, score_l))
    # candidates are in triangle order; stable sorts keep the lower triangle on ties
    o1 = np.argsort(score, kind="stable")
    o2 = np.argsort(ids[o1], kind="stable")
    order = o1[o2]
    first = np.ones(len(order), dtype=bool)
    first[1:] = ids[order][1:] != ids[order][:-1]
    win = order[first]
    _, strict_counts = np.unique(np.concatenate(strict_l), return_counts=True)
    return ids[win], tri[win], int((strict_counts >= 2).sum())


# -- numba path ----------------------------------------------------------------------------

_raster_kernel = None


def _get_kernel():
    """Compile (once, cached on disk) the numba rasterisation kernel."""
    global _raster_kernel
    if _raster_kernel is not None:
        return _raster_kernel
    from numba import njit

    @njit(cache=True, fastmath=False)
    def kernel(px, area2, live, w, h, conservative, cover_eps, strict_eps, score, best, strict):
        for t in live:
            sgn = 1.0 if area2[t] > 0 else -1.0
            lox = min(px[t, 0, 0], px[t, 1, 0], px[t, 2, 0])
            hix = max(px[t, 0, 0], px[t, 1, 0], px[t, 2, 0])
            loy = min(px[t, 0, 1], px[t, 1, 1], px[t, 2, 1])
            hiy = max(px[t, 0, 1], px[t, 1, 1], px[t, 2, 1])
            x0 = max(int(np.floor(lox + cover_eps)), 0)
            y0 = max(int(np.floor(loy + cover_eps)), 0)
            x1 = min(int(np.ceil(hix - cover_eps)) - 1, w - 1)
            y1 = min(int(np.ceil(hiy - cover_eps)) - 1, h - 1)
            ax = np.empty(3)
            ay = np.empty(3)
            ex = np.empty(3)
            ey = np.empty(3)
            el = np.empty(3)
            half = np.empty(3)
            for i in range(3):
                i1 = (i + 1) % 3
                i2 = (i + 2) % 3
                ax[i] = px[t, i1, 0]
                ay[i] = px[t, i1, 1]
                ex[i] = px[t, i2, 0] - ax[i]
                ey[i] = px[t, i2, 1] - ay[i]
                ln = np.sqrt(ex[i] * ex[i] + ey[i] * ey[i])
                el[i] = ln if ln > 0 else 1.0
                half[i] = 0.5 * (abs(ex[i]) + abs(ey[i])) / el[i]
            for y in range(y0, y1 + 1):
                cy = y + 0.5
                for x in range(x0, x1 + 1):
                    cx = x + 0.5
                    inside = True
                    strict_in = True
                    keep = True
                    mind = np.inf
                    for i in range(3):
                        d = (ex[i] * (cy - ay[i]) - ey[i] * (cx - ax[i])) * sgn / el[i]
                        mind = min(mind, d)
                        if d < 0.0:
                            inside = False
                        if not d > strict_eps:
                            strict_in = False
                        if not d + half[i] > cover_eps:
                            keep = False
                    if not conservative:
                        keep = inside
                    k = y * w + x
                    if strict_in and strict[k] < 255:
                        strict[k] += 1
                    if not keep:
                        continue
                    if inside:
                        s = -mind
                    else:
                        s = np.inf
                        for i in range(3):
                            # closest point on segment from corner i to corner i+1
                            bx = px[t, i, 0]
                            by = px[t, i, 1]
                            sx = px[t, (i + 1) % 3, 0] - bx
                            sy = px[t, (i + 1) % 3, 1] - by
                            l2 = sx * sx + sy * sy
                            u = ((cx - bx) * sx + (cy - by) * sy) / l2 if l2 > 0 else 0.0
                            u = min(max(u, 0.0), 1.0)
                            dx = cx - (bx + u * sx)
                            dy = cy - (by + u * sy)
                            s = min(s, dx * dx + dy * dy)
                    if s < score[k]:
                        score[k] = s
                        best[k] = t

    _raster_kernel = kernel
    return kernel


def _raster_numba(px, area2, live, w, h, conservative):
    """Same result as :func:`_raster_numpy` with dense per-texel buffers (9 bytes/texel)."""
    kernel = _get_kernel()
    score = np.full(w * h, np.inf)
    best = np.full(w * h, -1, dtype=np.int64)
    strict = np.zeros(w * h, dtype=np.uint8)
    kernel(
        np.ascontiguousarray(px),
        area2,
        live.astype(np.int64),
        w,
        h,
        conservative,
        COVER_EPS,
        OVERLAP_EPS,
        score,
        best,
        strict,
    )
    ids = np.nonzero(best >= 0)[0]
    return ids, best[ids], int((strict >= 2).sum())


def rasterize(
    mesh: MeshData,
    resolution,
    *,
    conservative: bool = True,
    max_resolution: int = MAX_RESOLUTION,
    backend: str = "numba",
) -> Texels:
    """Rasterise the lightmap UVs of ``mesh`` at ``resolution`` (w, h) into covered texels.

    A texel is covered when its centre lies in a triangle, or (``conservative``) when its square
    overlaps a triangle by a positive area; then the sample point is the point of the triangle
    closest (in UV) to the texel centre and ``center_inside`` is False. Each texel takes one
    triangle: one containing its centre if any (the deepest), else the nearest; ties go to the
    lower triangle index. ``backend`` "numba" (default) or "numpy" (reference; same result).

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
    uv = _check_mesh(mesh)
    if backend not in ("numba", "numpy"):
        raise UsageError(f"unknown rasterize backend {backend!r}; use 'numba' or 'numpy'")
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    pts = np.asarray(mesh.points, dtype=np.float64)
    t = len(tri)
    px = uv_to_pixel(uv, (w, h))
    # pixel space has y down, so area2 here is minus the UV-space one
    area2 = _cross2(px[:, 1] - px[:, 0], px[:, 2] - px[:, 0])
    degenerate_uv = np.abs(area2) <= DEGENERATE_UV_AREA2
    live = np.nonzero(~degenerate_uv)[0]

    run = _raster_numba if backend == "numba" else _raster_numpy
    ids, tri_idx, overlap = run(px, area2, live, w, h, conservative)

    # sample point of each winner: the centre if inside, else the closest point
    x = ids % w
    y = ids // w
    c = np.stack([x + 0.5, y + 0.5], axis=1).astype(np.float64)
    P = px[tri_idx]
    dist, _ = _edge_distances(c, P, area2[tri_idx])
    inside = (dist >= 0.0).all(axis=1)
    q = c.copy()
    out = np.nonzero(~inside)[0]
    if len(out):
        q[out], _ = _closest_point(c[out], P[out])
    lam = _cross2(P[:, [2, 0, 1]] - P[:, [1, 2, 0]], q[:, None, :] - P[:, [1, 2, 0]])
    lam = np.clip(lam / area2[tri_idx][:, None], 0.0, None)
    lam /= np.where(lam.sum(axis=1) > 0, lam.sum(axis=1), 1.0)[:, None]
    n = len(tri_idx)

    p = pts[tri[tri_idx]]  # (n, 3, 3)
    position = np.einsum("nc,nci->ni", lam, p)
    gp = pts[tri]
    gnorm, gok = _normalize(np.cross(gp[:, 1] - gp[:, 0], gp[:, 2] - gp[:, 0]))
    nrm_c, _ = _normalize(np.asarray(mesh.normals, dtype=np.float64))
    shade, sok = _normalize(np.einsum("nc,nci->ni", lam, nrm_c[tri_idx]))
    geom = gnorm[tri_idx]
    geom = np.where(gok[tri_idx][:, None], geom, shade)
    shade = np.where(sok[:, None], shade, geom)
    geom = np.where((np.abs(geom).sum(axis=1) > 0)[:, None], geom, [0.0, 0.0, 1.0])
    shade = np.where((np.abs(shade).sum(axis=1) > 0)[:, None], shade, [0.0, 0.0, 1.0])

    tangent_c, sign = tangent_frames(mesh)
    tan = np.einsum("nc,nci->ni", lam, tangent_c[tri_idx])
    tan = tan - shade * np.einsum("ni,ni->n", shade, tan)[:, None]
    tan, tok = _normalize(tan)
    tan = np.where(tok[:, None], tan, _any_perpendicular(shade))
    sgn = sign[tri_idx]
    bit = sgn[:, None] * np.cross(shade, tan)
    frame = np.stack([tan, bit, shade], axis=1)

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
    q = texels.position.astype(np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    nn = np.einsum("ni,ni->n", n, n)
    nn = np.where(nn > 0, nn, 1.0)
    lam = np.stack(
        [
            np.einsum("ni,ni->n", np.cross(p[:, 2] - p[:, 1], q - p[:, 1]), n),
            np.einsum("ni,ni->n", np.cross(p[:, 0] - p[:, 2], q - p[:, 2]), n),
            np.einsum("ni,ni->n", np.cross(p[:, 1] - p[:, 0], q - p[:, 0]), n),
        ],
        axis=1,
    )
    return lam / nn[:, None]
