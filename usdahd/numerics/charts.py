"""Chart geometry of the lightmap unwrap (usdahd.bake.unwrap): 2-D triangle overlap, unfolding
polygons into a chart, de-stretching, convex hulls and minimum-area rectangles, cutting ring charts
into their sides, and the shelf layout of charts for xatlas's pack pass.

numpy only. UVs are float64 (t, 3, 2) arrays in pass-1 texels unless stated.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "LAYOUT_GAP",
    "OVERLAP_EPS",
    "ChartRects",
    "convex_hull",
    "destretch",
    "extend_into",
    "grow",
    "layout",
    "min_area_rect",
    "overlaps",
    "project_polygon",
    "self_overlap",
    "signed_area2",
    "split_polygons",
    "split_rings",
    "unfold",
    "unfold_polygon",
    "widen_thin",
]

#: Penetration (pass-1 texels) below which two UV triangles of a chart only touch.
OVERLAP_EPS = 1e-4
#: Gap (pass-1 texels) between charts laid side by side as pass 2's input.
LAYOUT_GAP = 4.0


def signed_area2(uv: np.ndarray) -> np.ndarray:
    """Twice the signed area of 2-D triangles (..., 3, 2)."""
    e1 = uv[..., 1, :] - uv[..., 0, :]
    e2 = uv[..., 2, :] - uv[..., 0, :]
    return e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]


def overlaps(tri: np.ndarray, others: np.ndarray, eps: float = OVERLAP_EPS) -> bool:
    """Whether the interior of the 2-D triangle ``tri`` (3, 2) overlaps the interior of any of
    ``others`` (m, 3, 2) by more than ``eps`` (separating-axis test; shared edges and corners
    only touch)."""
    if len(others) == 0:
        return False
    lo, hi = tri.min(axis=0), tri.max(axis=0)
    near = ((others.min(axis=1) < hi - eps) & (others.max(axis=1) > lo + eps)).all(axis=1)
    o = others[near]
    if len(o) == 0:
        return False
    sep = np.zeros(len(o), dtype=bool)
    for j in range(3):
        e = tri[(j + 1) % 3] - tri[j]
        n = np.array([-e[1], e[0]])
        length = np.hypot(*n)
        if length == 0:
            continue
        n = n / length
        a, b = tri @ n, o @ n
        sep |= (b.min(axis=1) >= a.max() - eps) | (b.max(axis=1) <= a.min() + eps)
    e = o[:, [1, 2, 0]] - o
    n = np.stack([-e[..., 1], e[..., 0]], axis=-1)
    length = np.hypot(n[..., 0], n[..., 1])
    n = n / np.where(length > 0, length, 1.0)[..., None]
    a = np.einsum("mjk,ik->mji", n, tri)
    b = np.einsum("mjk,mik->mji", n, o)
    axis_sep = (b.min(axis=2) >= a.max(axis=2) - eps) | (b.max(axis=2) <= a.min(axis=2) + eps)
    sep |= (axis_sep & (length > 0)).any(axis=1)
    return not bool(sep.all())


def unfold(pa, pb, pc, ua, ub, sign):
    """The UV of ``c`` that lays the 3-D triangle (a, b, c) flat against the placed UV edge
    (ua, ub) at that edge's scale, on the side giving the triangle (a, b, c) the signed UV
    area ``sign``; None when the edge is degenerate."""
    e, d = pb - pa, pc - pa
    length = float(np.linalg.norm(e))
    eu = ub - ua
    length_uv = float(np.hypot(*eu))
    if length <= 0 or length_uv <= 0:
        return None
    x = float(d @ e) / length
    y = float(np.linalg.norm(np.cross(e, d))) / length
    along = eu / length_uv
    perp = np.array([-along[1], along[0]]) * (1.0 if sign > 0 else -1.0)
    return ua + (length_uv / length) * (x * along + y * perp)


def project_polygon(points, tris, scale):
    """Per-corner UVs (k, 3, 2) of one polygon laid out on its own: its corners projected onto
    the polygon's best-fit (Newell) plane at ``scale`` texels per unit, oriented as xatlas lays
    out an unmirrored chart (clockwise in pass-1 texels, whose y axis points down)."""
    p = points[tris]  # (k, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]).sum(axis=0)
    length = float(np.linalg.norm(n))
    n = n / length if length > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(helper, n)
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    uv = np.stack([p @ t, -(p @ b)], axis=-1) * scale
    return uv - uv.reshape(-1, 2).min(axis=0)


def grow(points, triangles, tris, corner, placed, sign):
    """Complete ``placed`` (polygon corner -> UV) over the polygon's triangles ``tris``: each
    triangle with two placed corners gets its third by :func:`unfold`, until all are placed.
    Returns the polygon's (k, 3, 2) UVs, or None when a triangle has no placed edge, an edge
    is degenerate or a triangle comes out flipped (signed area not of ``sign``)."""
    pending = [int(i) for i in tris]
    while pending:
        left = []
        for i in pending:
            cs = [int(c) for c in corner[i]]
            known = [c in placed for c in cs]
            if all(known):
                continue
            if sum(known) < 2:
                left.append(i)
                continue
            j = known.index(False)
            a, b = (j + 1) % 3, (j + 2) % 3  # (a, b, j) keeps the triangle's cyclic order
            v = triangles[i]
            new = unfold(
                points[v[a]], points[v[b]], points[v[j]], placed[cs[a]], placed[cs[b]], sign
            )
            if new is None:
                return None
            placed[cs[j]] = new
        if len(left) == len(pending):
            return None
        pending = left
    out = np.array([[placed[int(c)] for c in corner[i]] for i in tris], dtype=np.float64)
    if (signed_area2(out) * sign <= 0).any():
        return None
    return out


def extend_into(points, triangles, tris, corner, uv, labels, chart):
    """Lay the triangles of one polygon (``tris``) that are not in ``chart`` out in that
    chart's UV space, unfolded edge by edge from the polygon's triangles already in it, so
    every corner of the polygon has one UV. Returns the polygon's (k, 3, 2) UVs or None when
    that cannot be done (see :func:`grow`; or a corner with two UVs in the chart)."""
    inside = labels[tris] == chart
    placed: dict[int, np.ndarray] = {}
    for i in tris[inside]:
        for j in range(3):
            c = int(corner[i, j])
            if c in placed and not np.array_equal(placed[c], uv[i, j]):
                return None
            placed[c] = uv[i, j]
    sign = 1.0 if signed_area2(uv[tris[inside]]).sum() > 0 else -1.0
    return grow(points, triangles, tris, corner, placed, sign)


def unfold_polygon(points, triangles, tris, corner, scale):
    """One polygon laid out as a chart of its own: its largest triangle flat at ``scale``
    texels per unit, the others unfolded from it edge by edge (every triangle keeps its 3-D
    shape), oriented as xatlas lays out an unmirrored chart (negative signed area in pass-1
    texels, whose y axis points down). None when that cannot be done (:func:`grow`)."""
    p = points[triangles[tris]]
    area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    seed = int(np.argmax(area))
    v = triangles[tris[seed]]
    cs = [int(c) for c in corner[tris[seed]]]
    length = float(np.linalg.norm(points[v[1]] - points[v[0]]))
    if length <= 0:
        return None
    placed = {cs[0]: np.zeros(2), cs[1]: np.array([length * scale, 0.0])}
    third = unfold(points[v[0]], points[v[1]], points[v[2]], placed[cs[0]], placed[cs[1]], -1.0)
    if third is None:
        return None
    placed[cs[2]] = third
    out = grow(points, triangles, tris, corner, placed, -1.0)
    return None if out is None else out - out.reshape(-1, 2).min(axis=0)


def self_overlap(laid: np.ndarray) -> bool:
    """Whether two of a polygon's UV triangles (k, 3, 2) overlap each other."""
    return any(overlaps(laid[i], np.delete(laid, i, axis=0)) for i in range(len(laid) - 1))


def split_polygons(corner, face, key) -> np.ndarray:
    """Polygons (sorted ids) with a corner that gets two different ``key`` rows (chart, u, v)
    from two of its triangles: a faceVarying primvar cannot hold them."""
    c = corner.reshape(-1)
    k = key.reshape(len(c), -1)
    order = np.lexsort((*k.T[::-1], c))
    c, k = c[order], k[order]
    differ = (c[1:] == c[:-1]) & (k[1:] != k[:-1]).any(axis=1)
    tri = (order // 3)[1:][differ]
    return np.unique(face[tri])


def destretch(uv, labels, tri_points, tpu):
    """Undo xatlas's packing stretch of each pass-1 chart. xatlas scales every chart to a
    whole number of texels along its packed x and y axes (``ceil(extent) / extent``, up to 2x
    for a chart a texel wide), so a pass-1 chart is stretched along the output's x and y axes
    by unknown factors. Its parameterisation was conformal (LSCM, or an orthogonal
    projection), and an axis stretch changes only the ratio of the u and v gradient lengths;
    so per chart the x/y scale ratio that makes them equal again (area-weighted geometric mean
    over its triangles) is applied, then the chart is rescaled so its UV area is its surface
    area x tpu^2 (xatlas's own chart normalisation)."""
    uv = uv.copy()
    t = labels >= 0
    if not t.any():
        return uv
    n = int(labels.max()) + 1
    lab = labels[t]
    p = tri_points[t]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    normal = np.cross(e1, e2)
    area2 = np.linalg.norm(normal, axis=1)
    ok = (l1 > 0) & (area2 > 0)
    x = np.where(ok, (e2 * e1).sum(axis=1) / np.where(ok, l1, 1.0), 0.0)
    y = np.where(ok, area2 / np.where(ok, l1, 1.0), 1.0)
    d = uv[t] - uv[t][:, :1]  # (k, 3, 2): d[:, 1] = uv1 - uv0, d[:, 2] = uv2 - uv0
    # the gradient g of a UV coordinate in the triangle's own frame: (l1, 0) . g = d1,
    # (x, y) . g = d2
    gx = d[:, 1] / np.where(ok, l1, 1.0)[:, None]  # (k, 2): d/dx of (u, v)
    gy = (d[:, 2] - x[:, None] * gx) / y[:, None]  # (k, 2): d/dy of (u, v)
    len_u = np.hypot(gx[:, 0], gy[:, 0])
    len_v = np.hypot(gx[:, 1], gy[:, 1])
    ok &= (len_u > 0) & (len_v > 0)
    w = np.where(ok, area2, 0.0)
    log_ratio = np.where(ok, np.log(np.where(ok, len_v, 1.0) / np.where(ok, len_u, 1.0)), 0.0)
    num = np.zeros(n)
    den = np.zeros(n)
    np.add.at(num, lab, w * log_ratio)
    np.add.at(den, lab, w)
    ratio = np.exp(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0))
    scale = np.stack([np.sqrt(ratio), 1.0 / np.sqrt(ratio)], axis=1)  # equal |grad u|, |grad v|
    lo = np.full((n, 2), np.inf)
    np.minimum.at(lo, np.repeat(lab, 3), uv[t].reshape(-1, 2))
    origin = lo[lab][:, None, :]
    moved = origin + (uv[t] - origin) * scale[lab][:, None, :]
    # area normalisation, per chart
    area_uv = np.zeros(n)
    area_3d = np.zeros(n)
    np.add.at(area_uv, lab, 0.5 * np.abs(signed_area2(moved)))
    np.add.at(area_3d, lab, 0.5 * area2 * tpu * tpu)
    f = np.where(area_uv > 0, np.sqrt(area_3d / np.where(area_uv > 0, area_uv, 1.0)), 1.0)
    uv[t] = origin + (moved - origin) * f[lab][:, None, None]
    return uv


def convex_hull(pts: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise, no repeated point) of 2-D points (n, 2) (monotone chain)."""
    pts = np.asarray(pts, dtype=np.float64)
    if len(pts) > 1:  # np.unique(pts, axis=0) without its structured-array sort (4x faster)
        pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]
        keep = np.ones(len(pts), dtype=bool)
        keep[1:] = (pts[1:] != pts[:-1]).any(axis=1)
        pts = pts[keep]
    if len(pts) < 3:
        return pts

    def half(points):
        out: list = []
        for q in points:
            while len(out) >= 2:
                a, b = out[-2], out[-1]
                if (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]) > 0:
                    break
                out.pop()
            out.append(q)
        return out

    lower = half(pts)
    upper = half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def min_area_rect(hull: np.ndarray):
    """The smallest-area bounding rectangle of a convex hull (k >= 3, 2): (rot (2, 2) rows
    = its axes, a rotation; lo (2,), hi (2,) its extent in those axes)."""
    edges = np.roll(hull, -1, axis=0) - hull
    length = np.hypot(edges[:, 0], edges[:, 1])
    d = edges[length > 0] / length[length > 0, None]
    best = None
    for a in d:
        rot = np.array([a, [-a[1], a[0]]])
        local = hull @ rot.T
        lo, hi = local.min(axis=0), local.max(axis=0)
        area = float(np.prod(hi - lo))
        if best is None or area < best[0]:
            best = (area, rot, lo, hi)
    return best[1], best[2], best[3]


class ChartRects:
    """The smallest bounding rectangles (:func:`min_area_rect` of the :func:`convex_hull`) of
    the charts of one UV layout ``uv`` (t, 3, 2), each computed once: :func:`split_rings` and
    :func:`widen_thin` ask for the same charts again for every candidate labelling, width floor
    and density of an unwrap (:mod:`usdahd.bake.unwrap`), and the hulls were most of its time
    (Sponza's plan: 111,546 hulls for 1,090 widenings). A chart is its triangles (sorted
    indices into ``uv``), whatever its label. ``uv`` must not change while the cache is used."""

    def __init__(self, uv: np.ndarray):
        self.uv = uv
        self._rects: dict[bytes, tuple | None] = {}
        self._tables: dict[bytes, tuple] = {}

    def charts(self, labels: np.ndarray):
        """The charts of ``labels`` (t,) with a non-degenerate hull, label >= 0, in label
        order: (list of their triangles, rot (c, 2, 2), lo (c, 2), hi (c, 2)); the last
        labellings asked for are kept (an unwrap asks again for each floor and density)."""
        key = np.asarray(labels).tobytes()
        got = self._tables.get(key)
        if got is None:
            order = np.argsort(labels, kind="stable")
            cuts = np.flatnonzero(np.diff(labels[order])) + 1
            tris, rot, lo, hi = [], [], [], []
            for t in np.split(order, cuts):
                if len(t) == 0 or labels[t[0]] < 0:
                    continue
                rect = self(t)
                if rect is None:
                    continue
                tris.append(t)
                rot.append(rect[0])
                lo.append(rect[1])
                hi.append(rect[2])
            got = (
                tris,
                np.array(rot, dtype=np.float64).reshape(-1, 2, 2),
                np.array(lo, dtype=np.float64).reshape(-1, 2),
                np.array(hi, dtype=np.float64).reshape(-1, 2),
            )
            if len(self._tables) >= 8:
                self._tables.pop(next(iter(self._tables)))
            self._tables[key] = got
        return got

    def __call__(self, tris: np.ndarray):
        """(rot, lo, hi) of the chart made of the triangles ``tris`` (increasing int64), or
        None when its hull is degenerate (under 3 points)."""
        key = np.asarray(tris, dtype=np.int64).tobytes()
        if key not in self._rects:
            hull = convex_hull(self.uv[tris].reshape(-1, 2))
            self._rects[key] = None if len(hull) < 3 else min_area_rect(hull)
        return self._rects[key]


def _rects_for(uv, rects):
    if rects is None:
        return ChartRects(uv)
    if rects.uv.shape != np.shape(uv):
        raise ValueError("ChartRects was made for another UV layout")
    return rects


def split_rings(uv, labels, face, solidity, rects=None):
    """Cut every ring chart, one covering less than ``solidity`` of its smallest bounding
    rectangle, into its four sides: each polygon goes to the side of that rectangle nearest its
    centroid. Whole polygons move, at their UVs (a side may be disconnected: its pieces keep
    their places), so nothing overlaps and every polygon corner keeps one UV; the new seams are
    between polygons. ``rects``: a :class:`ChartRects` of ``uv`` to reuse. Returns new labels
    (t,)."""
    rects = _rects_for(uv, rects)
    labels = np.array(labels, copy=True)
    if len(labels) == 0:
        return labels
    next_label = int(labels.max()) + 1
    order = np.argsort(labels, kind="stable")
    cuts = np.flatnonzero(np.diff(labels[order])) + 1
    for tris in np.split(order, cuts):
        rect = rects(tris)
        if rect is None:
            continue
        rot, lo, hi = rect
        area = 0.5 * float(np.abs(signed_area2(uv[tris])).sum())
        if area >= solidity * float(np.prod(hi - lo)):
            continue
        polys, inverse = np.unique(face[tris], return_inverse=True)
        centre = np.zeros((len(polys), 2))
        count = np.zeros(len(polys))
        np.add.at(centre, inverse, uv[tris].mean(axis=1) @ rot.T)
        np.add.at(count, inverse, 1.0)
        c = centre / count[:, None]
        side = np.argmin(
            np.stack([c[:, 0] - lo[0], hi[0] - c[:, 0], c[:, 1] - lo[1], hi[1] - c[:, 1]], axis=1),
            axis=1,
        )
        for k in np.unique(side)[1:]:
            labels[tris[side[inverse] == k]] = next_label
            next_label += 1
    return labels


def layout(uv, labels):
    """Pass 2's input: the charts side by side on shelves (rows of charts, LAYOUT_GAP apart,
    about as wide as the square root of their total bounding-box area, so coordinates stay
    near pass 1's atlas size and float32 keeps them to ~1e-4 texel), so that no two charts
    share a UV value (xatlas finds a UV mesh's charts by shared UV values), as an indexed UV
    mesh: (vertices (n, 2) float32, indices (t, 3) uint32)."""
    _, lab = np.unique(labels, return_inverse=True)
    lab = lab.ravel()
    n = int(lab.max()) + 1
    flat = uv.reshape(-1, 2)
    lab3 = np.repeat(lab, 3)
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, lab3, flat)
    np.maximum.at(hi, lab3, flat)
    size = hi - lo + LAYOUT_GAP
    width = max(float(size[:, 0].max()), float(np.sqrt((size[:, 0] * size[:, 1]).sum())))
    origin = np.zeros((n, 2))
    x = y = row = 0.0
    for c in range(n):
        if x > 0 and x + size[c, 0] > width:
            x, y, row = 0.0, y + row, 0.0
        origin[c] = (x, y)
        x += size[c, 0]
        row = max(row, size[c, 1])
    moved = (flat - lo[lab3] + origin[lab3]).astype(np.float32).astype(np.float64)
    # the distinct (chart, u, v) rows in sorted order and each corner's row: np.unique(rows,
    # axis=0, return_inverse=True) without its structured-array sort (several times faster)
    order = np.lexsort((moved[:, 1], moved[:, 0], lab3))
    m, c = moved[order], lab3[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (c[1:] != c[:-1]) | (m[1:] != m[:-1]).any(axis=1)
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    verts = np.ascontiguousarray(m[first], dtype=np.float32)
    return verts, np.ascontiguousarray(inverse.reshape(-1, 3), dtype=np.uint32)


def widen_thin(uv, labels, scale, floor, rects=None):
    """Stretch every chart of ``uv`` (t, 3, 2) whose smallest bounding rectangle is less than
    ``floor`` texels across (at ``scale`` texels per ``uv`` unit) along that rectangle's short
    axis, about the chart's own origin, until it is ``floor`` texels across: a sliver (a
    moulding's face under a texel wide) then covers ``floor`` + 1 texel rows instead of one or
    two, each its own surface sample. A positive affine map of a chart: it stays free of
    overlap and keeps its orientation. ``rects``: a :class:`ChartRects` of ``uv`` to reuse.
    Returns (uv, number of charts stretched)."""
    if len(labels) == 0 or floor <= 0:
        return np.array(uv, dtype=np.float64, copy=True), 0
    rects = _rects_for(uv, rects)
    uv = np.array(uv, dtype=np.float64, copy=True)
    tris, rot, lo, hi = rects.charts(np.asarray(labels))
    ext = hi - lo
    axis = np.argmin(ext, axis=1)
    width = ext[np.arange(len(ext)), axis] * scale
    count = 0
    for i in np.flatnonzero((width < floor) & (width > 0)):
        k = int(axis[i])
        local = uv[tris[i]].reshape(-1, 2) @ rot[i].T
        local[:, k] = lo[i, k] + (local[:, k] - lo[i, k]) * (floor / float(width[i]))
        uv[tris[i]] = (local @ rot[i]).reshape(-1, 3, 2)
        count += 1
    return uv, count
