"""The one UV rasteriser, fan triangulation and UV -> pixel mapping (baker and validator).

numpy + numba only (no pxr, OpenImageIO or Embree); ``docs/texels.md`` states the conventions
an engine importer needs. :mod:`usdahd.bake.texels` builds the baker's texels (sample points,
tangent frames) on :func:`rasterize_uv`; the validator checks UV sets with the same functions.

Texel ``(x, y)`` covers UV ``[x/w, (x+1)/w] x [1-(y+1)/h, 1-y/h]`` (row 0 = top, v = 1).
Internally UVs are mapped to *pixel coordinates* ``px = u * w``, ``py = (1 - v) * h``
(:func:`uv_to_pixel`) in which texel ``(x, y)`` is the unit square ``[x, x+1] x [y, y+1]`` and
its centre is ``(x + 0.5, y + 0.5)``; a texel's id is ``y * w + x`` (row-major).

Public functions
----------------
uv_to_pixel(uv, resolution) -> (..., 2) float64              UV -> pixel coordinates
fan_triangulate(counts) -> (face (t,), corners (t, 3))       polygon fan, face-vertex slots
signed_area2(px) -> (t,) float64                             twice the signed triangle area
rasterize_uv(uv, resolution, *, conservative, backend) -> Raster   covered texels, winners
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from usdahd.errors import UsageError

__all__ = [
    "UV_OVERLAP_LIMIT",
    "coverage",
    "fan_triangulate",
    "rasterize_uv",
    "signed_area2",
    "uv_to_pixel",
]

# Tolerances (pixel units = texels), one place, each with its reason.
#: A texel square must overlap a triangle by more than this to count as covered, so texels that
#: only touch a triangle along a texel boundary (charts aligned with the grid) are not covered.
COVER_EPS = 1e-6
#: A texel centre counts as "strictly inside" a triangle (for the UV-overlap statistic) when it
#: is farther than this from every edge; centres on a shared edge of adjacent triangles are not
#: overlap.
OVERLAP_EPS = 1e-4
#: Share of a lightmap's covered texels whose centres may lie in two UV triangles: above it the
#: baker does not use the UV set (it unwraps a new one, usdahd/pipeline/plan.py) and the
#: validator's UVSet rule reports UVOverlap, so a UV set the baker accepts passes validation.
UV_OVERLAP_LIMIT = 0.01
#: |2 x signed UV area| in texels^2 below this -> degenerate UV triangle (no barycentrics).
DEGENERATE_UV_AREA2 = 1e-10
#: Candidate texels per vectorized chunk of the numpy path: bounds peak memory (~100 bytes per
#: candidate).
CHUNK = 1 << 20
#: Sample point of a conservative texel (centre outside every triangle): this fraction of the
#: way from the point of the texel square's part inside the triangle closest to the centre (on
#: the triangle's edge) to that part's centroid; strictly inside both when > 0. Until issue 37
#: it was the triangle's closest point (0 here gives exactly that): on a step under a tenth of
#: a texel high the crease's dark line became the texel's value (-13 % along the border); 0.5
#: measured best over steps of 0.05 to 4 texels (benchmarks/crease_texels.py, docs/texels.md
#: "Conservative texels: the sample point").
CONSERVATIVE_INSET = 0.5
#: Overlap area (texels^2) below which a conservative texel keeps the closest point (the
#: centroid of a sliver of area ~COVER_EPS is that point up to rounding).
CENTROID_MIN_AREA = 1e-9
#: Rasteriser implementations: "numba" (default, dense per-texel buffers of 9 bytes per texel)
#: and "numpy" (the reference; the same result, tested in tests/bake/test_texels.py).
BACKENDS = ("numba", "numpy")


# --------------------------------------------------------------------------------------------
# mappings


def uv_to_pixel(uv: np.ndarray, resolution) -> np.ndarray:
    """UV (..., 2) -> pixel coordinates (..., 2) float64: ``(u * w, (1 - v) * h)``."""
    w, h = resolution
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([uv[..., 0] * w, (1.0 - uv[..., 1]) * h], axis=-1)


def fan_triangulate(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation of polygons with ``counts`` vertices, in face-vertex (corner) slots.

    Polygon ``f`` with corners ``s .. s + n - 1`` (``s`` = sum of the earlier counts) becomes the
    triangles ``(s, s + k + 1, s + k + 2)`` for ``k = 0 .. n - 3``; polygons with fewer than 3
    corners give none. Winding is the polygon's.
    counts : (f,) int, vertices per polygon (UsdGeomMesh faceVertexCounts).
    returns : face (t,) int64, the polygon of each triangle; corners (t, 3) int64, indices into
    the face-vertex arrays (faceVertexIndices, faceVarying primvars).
    """
    counts = np.asarray(counts, dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts), dtype=np.int64), ntri)
    first = np.concatenate([[0], np.cumsum(ntri)[:-1]]).astype(np.int64)
    k = np.arange(len(face), dtype=np.int64) - first[face]
    s = start[face]
    return face, np.stack([s, s + k + 1, s + k + 2], axis=1)


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the 2-D cross product of (..., 2) vectors -> (...)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def signed_area2(p: np.ndarray) -> np.ndarray:
    """Twice the signed area (t,) of 2-D triangles p (t, 3, 2) (> 0: counter-clockwise in p's
    axes; pixel space has y down, so there it is minus the UV-space value)."""
    return cross2(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


# --------------------------------------------------------------------------------------------
# geometry of texel centres against triangles (pixel space)


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


def closest_point(c: np.ndarray, P: np.ndarray):
    """Closest point q (m, 2) of triangles P (m, 3, 2) to points c (m, 2) lying outside them,
    and the squared distance (m,)."""
    best_q, best_d2 = _closest_on_segment(c, P[:, 0], P[:, 1])
    for i in (1, 2):
        qi, di = _closest_on_segment(c, P[:, i], P[:, (i + 1) % 3])
        better = di < best_d2
        best_q = np.where(better[:, None], qi, best_q)
        best_d2 = np.where(better, di, best_d2)
    return best_q, best_d2


def edge_distances(c: np.ndarray, P: np.ndarray, area2: np.ndarray):
    """Signed distances (m, 3) of points c (m, 2) to the edge lines of triangles P (m, 3, 2),
    positive inside; edge i is opposite corner i. Also the unit-normal box half-widths (m, 3)
    of a texel square along each edge normal."""
    a = P[:, [1, 2, 0]]
    e = P[:, [2, 0, 1]] - a
    elen = np.sqrt(np.einsum("mei,mei->me", e, e))
    elen = np.where(elen > 0, elen, 1.0)
    dist = cross2(e, c[:, None, :] - a) * np.sign(area2)[:, None] / elen
    half = 0.5 * (np.abs(e[..., 0]) + np.abs(e[..., 1])) / elen
    return dist, half


def _clip_square(c: np.ndarray, P: np.ndarray, area2: np.ndarray):
    """The unit squares centred at c (m, 2) clipped to triangles P (m, 3, 2) (Sutherland-
    Hodgman, one half-plane per edge): polygons (m, 7, 2) relative to c and their vertex
    counts (m,) (fewer than 3: no overlap)."""
    m = len(c)
    kmax = 7
    off = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    poly = np.zeros((m, kmax, 2))
    poly[:, :4] = off  # relative to the centre, for precision
    P = P - c[:, None, :]
    cnt = np.full(m, 4, np.int64)
    sgn = np.sign(area2)
    rows = np.arange(m)
    for i in range(3):
        a = P[:, (i + 1) % 3]
        e = P[:, (i + 2) % 3] - a
        # signed side of every vertex, >= 0 inside (edge i, opposite corner i)
        side = cross2(e[:, None, :], poly - a[:, None, :]) * sgn[:, None]
        out = np.zeros((m, kmax, 2))
        ocnt = np.zeros(m, np.int64)
        for k in range(kmax):
            live = k < cnt
            nxt = np.where(k + 1 < cnt, k + 1, 0)
            cur_p, nxt_p = poly[:, k], poly[rows, nxt]
            cur_s, nxt_s = side[:, k], side[rows, nxt]
            keep = live & (cur_s >= 0)
            out[rows[keep], ocnt[keep]] = cur_p[keep]
            ocnt += keep
            cross = live & ((cur_s >= 0) != (nxt_s >= 0))
            den = np.where(cross, cur_s - nxt_s, 1.0)
            x = cur_p + (cur_s / den)[:, None] * (nxt_p - cur_p)
            ok = cross & (ocnt < kmax)
            out[rows[ok], ocnt[ok]] = x[ok]
            ocnt += ok
        poly, cnt = out, ocnt
    return poly, cnt


def _polygon_next(cnt: np.ndarray, kmax: int) -> np.ndarray:
    k = np.arange(kmax)
    return np.where(k[None, :] + 1 < cnt[:, None], k[None, :] + 1, 0)


def clip_square(c: np.ndarray, P: np.ndarray, area2: np.ndarray):
    """Area (m,) and centroid (m, 2) of the part of the unit square centred at each c (m, 2)
    inside its triangle P (m, 3, 2) (area 0, centroid nan where they do not overlap)."""
    return _area_centroid(c, *_clip_square(c, P, area2))


def _area_centroid(c: np.ndarray, poly: np.ndarray, cnt: np.ndarray):
    """:func:`clip_square`'s area and centroid from :func:`_clip_square`'s polygons."""
    kmax = poly.shape[1]
    q1 = np.take_along_axis(poly, _polygon_next(cnt, kmax)[..., None], axis=1)
    cr = np.where(np.arange(kmax)[None, :] < cnt[:, None], cross2(poly, q1), 0.0)
    area = 0.5 * cr.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cen = ((poly + q1) * cr[..., None]).sum(axis=1) / (6.0 * area)[:, None]
    return np.abs(area), c + cen


def conservative_points(c: np.ndarray, P: np.ndarray, area2: np.ndarray, inset: float):
    """Sample points (m, 2) of conservative texels with centres c (m, 2) outside their
    triangles P (m, 3, 2): ``inset`` (0..1) of the way from the point of the texel square's
    part inside the triangle closest to c to that part's centroid (CONSERVATIVE_INSET). Both
    lie in that convex part, so for inset > 0 the point is strictly inside it. Texels whose
    square overlaps by at most CENTROID_MIN_AREA, and every texel at inset 0, take the
    triangle's closest point."""
    q, _ = closest_point(c, P)
    if inset == 0.0 or not len(c):
        return q  # the rule until issue 37
    poly, cnt = _clip_square(c, P, area2)
    kmax = poly.shape[1]
    # closest point of the clipped polygon to the centre (the origin of poly's coordinates)
    nxt = np.take_along_axis(poly, _polygon_next(cnt, kmax)[..., None], axis=1)
    best, best_d2 = np.zeros((len(c), 2)), np.full(len(c), np.inf)
    for k in range(kmax):
        qk, dk = _closest_on_segment(np.zeros((len(c), 2)), poly[:, k], nxt[:, k])
        better = (k < cnt) & (dk < best_d2)
        best = np.where(better[:, None], qk, best)
        best_d2 = np.where(better, dk, best_d2)
    area, cen = _area_centroid(c, poly, cnt)
    ok = (area > CENTROID_MIN_AREA) & np.isfinite(cen).all(axis=1) & (cnt >= 3)
    inner = c + best + inset * (cen - (c + best))
    return np.where(ok[:, None], inner, q)


# -- numpy reference path ------------------------------------------------------------------


def _raster_numpy(px, area2, live, w, h, conservative):
    """Winner triangle per covered texel. Returns (ids (n,) int64 sorted texel ids y * w + x,
    tri (n,) int64, overlap ids (m,) int64: sorted texels whose centre is strictly inside two
    or more triangles)."""
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
        dist, half = edge_distances(c, px[t], area2[t])
        inside = (dist >= 0.0).all(axis=1)
        keep = ((dist + half) > COVER_EPS).all(axis=1) if conservative else inside
        strict_l.append((y * w + x)[(dist > OVERLAP_EPS).all(axis=1)])
        idx = np.nonzero(keep)[0]
        score = -dist[idx].min(axis=1)
        out = np.nonzero(~inside[idx])[0]
        if len(out):
            _, d2 = closest_point(c[idx[out]], px[t[idx[out]]])
            score[out] = d2
        ids_l.append((y * w + x)[idx])
        tri_l.append(t[idx])
        score_l.append(score)
    if not ids_l:
        z = np.zeros(0, np.int64)
        return z, z, z
    ids, tri, score = (np.concatenate(v) for v in (ids_l, tri_l, score_l))
    # candidates are in triangle order; stable sorts keep the lower triangle on ties
    o1 = np.argsort(score, kind="stable")
    o2 = np.argsort(ids[o1], kind="stable")
    order = o1[o2]
    first = np.ones(len(order), dtype=bool)
    first[1:] = ids[order][1:] != ids[order][:-1]
    win = order[first]
    strict_ids, strict_counts = np.unique(np.concatenate(strict_l), return_counts=True)
    return ids[win], tri[win], strict_ids[strict_counts >= 2].astype(np.int64)


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
    return ids, best[ids], np.nonzero(strict >= 2)[0]


# --------------------------------------------------------------------------------------------
# the rasteriser


@dataclass
class Raster:
    """Covered texels of a UV layout and the triangle each one takes (:func:`rasterize_uv`).

    n covered texels, sorted by id ``y * w + x``; t triangles.
    """

    resolution: tuple[int, int]  # (w, h)
    ids: np.ndarray  # (n,) int64 texel ids y * w + x, ascending
    triangle: np.ndarray  # (n,) int64 winning triangle per texel
    center_inside: np.ndarray  # (n,) bool: the texel centre lies in its triangle
    barycentrics: np.ndarray  # (n, 3) float64 of the sample point (centre, or inset)
    overlap_ids: np.ndarray  # (m,) int64 ascending: centres strictly inside >= 2 triangles
    degenerate: np.ndarray  # (t,) bool: UV triangles with |2 area| <= DEGENERATE_UV_AREA2 px^2

    @property
    def xy(self) -> np.ndarray:
        """(n, 2) int64 texel coordinates (x, y) of the covered texels."""
        w = self.resolution[0]
        return np.stack([self.ids % w, self.ids // w], axis=1)


def _cover(uv, resolution, *, conservative: bool, backend: str):
    """(pixel-space corners, signed areas, degenerate mask, covered texel ids, their winning
    triangles, texel ids whose centre lies strictly in two or more triangles)."""
    if backend not in BACKENDS:
        raise UsageError(f"unknown rasterize backend {backend!r}; use 'numba' or 'numpy'")
    w, h = (int(r) for r in resolution)
    px = uv_to_pixel(uv, (w, h))
    # pixel space has y down, so area2 here is minus the UV-space one
    area2 = signed_area2(px)
    degenerate = np.abs(area2) <= DEGENERATE_UV_AREA2
    live = np.nonzero(~degenerate)[0]

    run = _raster_numba if backend == "numba" else _raster_numpy
    ids, tri_idx, overlap_ids = run(px, area2, live, w, h, conservative)
    return px, area2, degenerate, ids, tri_idx, overlap_ids


def coverage(
    uv: np.ndarray, resolution, *, conservative: bool = True, backend: str = "numba"
) -> tuple[np.ndarray, np.ndarray]:
    """The covered texel ids and the overlap ids of :func:`rasterize_uv` (same kernel, same
    values) without the sample points and barycentrics: what a UV-overlap statistic needs,
    at a fraction of the memory (a 1024^2 map's barycentric stage holds ~0.3 GB)."""
    _, _, _, ids, _, overlap_ids = _cover(
        uv, resolution, conservative=conservative, backend=backend
    )
    return ids, overlap_ids


def rasterize_uv(
    uv: np.ndarray, resolution, *, conservative: bool = True, backend: str = "numba"
) -> Raster:
    """Rasterise UV triangles at ``resolution`` (w, h) into covered texels and their winners.

    A texel is covered when its centre lies in a triangle, or (``conservative``) when its square
    overlaps a triangle by more than COVER_EPS; then ``center_inside`` is False and the sample
    point lies inside the triangle and the square, half way (CONSERVATIVE_INSET) from the
    point of the square's part inside the triangle closest to the centre to that part's
    centroid (:func:`conservative_points`). Each texel
    takes one triangle: one containing its centre if any (the deepest), else the nearest; ties
    go to the lower triangle index. Degenerate UV triangles cover nothing.

    uv : (t, 3, 2) float, finite (the caller checks; see :func:`usdahd.bake.texels.rasterize`).
    resolution : (w, h) positive ints. backend : one of BACKENDS (same result).
    returns : :class:`Raster`.
    """
    w, h = (int(r) for r in resolution)
    px, area2, degenerate, ids, tri_idx, overlap_ids = _cover(
        uv, (w, h), conservative=conservative, backend=backend
    )

    # sample point of each winner: the centre if inside, else inset from the closest point
    x = ids % w
    y = ids // w
    c = np.stack([x + 0.5, y + 0.5], axis=1).astype(np.float64)
    P = px[tri_idx]
    dist, _ = edge_distances(c, P, area2[tri_idx])
    inside = (dist >= 0.0).all(axis=1)
    q = c.copy()
    out = np.nonzero(~inside)[0]
    if len(out):
        q[out] = conservative_points(c[out], P[out], area2[tri_idx[out]], CONSERVATIVE_INSET)
    lam = cross2(P[:, [2, 0, 1]] - P[:, [1, 2, 0]], q[:, None, :] - P[:, [1, 2, 0]])
    lam = np.clip(lam / area2[tri_idx][:, None], 0.0, None)
    lam /= np.where(lam.sum(axis=1) > 0, lam.sum(axis=1), 1.0)[:, None]
    return Raster(
        resolution=(w, h),
        ids=ids,
        triangle=tri_idx,
        center_inside=inside,
        barycentrics=lam,
        overlap_ids=overlap_ids,
        degenerate=degenerate,
    )
