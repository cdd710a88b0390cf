"""Uniform subdivision of polygon meshes: Catmull-Clark and Loop, vectorised numpy.

The baker traces a ``catmullClark`` or ``loop`` UsdGeom.Mesh on a refinement of its control
cage instead of the cage itself (docs/usd-semantics.md, "Subdivision surfaces"):

- :func:`catmull_clark` one level of Catmull-Clark (1987) on any polygon mesh: every n-gon
  becomes n quads; vertex, edge and face points by the usual masks; boundaries as USD's
  default ``interpolateBoundary = edgeAndCorner`` (boundary edges are B-spline curves, a
  boundary vertex with a single face is a fixed corner).
- :func:`loop` one level of Loop (1987) on a triangle mesh (Warren's β for the vertex mask).
- :func:`cc_limit` projects a quad mesh (one or more Catmull-Clark levels done) onto the limit
  surface with the limit masks: interior vertex of valence n ``(n² v + 4 Σ e_j + Σ f_j) /
  (n (n + 5))`` (e_j edge neighbours, f_j the opposite corners of its quads), boundary
  ``(a + 4 v + b) / 6``, corners fixed.
- :func:`refine` repeats a scheme ``levels`` times, carrying per-corner (face-varying) values
  such as lightmap UVs *linearly* within each cage face (bilinearly for quads): the refined
  faces tile each cage face's UV polygon exactly, so a texel addressed through the cage's UVs
  finds the refined surface point of the same cage-face parameter.

All masks are affine (weights sum to 1), so refining world-space points equals transforming
object-space refinements. Creases, corners and holes are not applied (the caller warns).

numpy only.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics.triangles import edge_cross

__all__ = ["cc_limit", "catmull_clark", "loop", "refine", "vertex_normals", "quads_to_triangles"]


def _face_tables(counts: np.ndarray, idx: np.ndarray):
    """(face of corner, next corner, previous corner, first corner of each face)."""
    counts = np.asarray(counts, np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    face = np.repeat(np.arange(len(counts)), counts)
    k = np.arange(len(idx)) - start[face]
    n = counts[face]
    nxt = start[face] + (k + 1) % n
    prv = start[face] + (k - 1) % n
    return face, nxt, prv, start


def _edges(idx: np.ndarray, nxt: np.ndarray, n_pts: int):
    """Undirected edges of the corner -> next-corner half-edges.

    returns (edge id per corner (c,), edge endpoints (e, 2), faces per edge (e,))."""
    a, b = idx, idx[nxt]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * np.int64(n_pts) + hi
    uniq, inv = np.unique(key, return_inverse=True)
    ends = np.stack([uniq // n_pts, uniq % n_pts], axis=1)
    nface = np.bincount(inv, minlength=len(uniq))
    return inv.ravel(), ends, nface


def catmull_clark(points, counts, idx, fv=()):
    """One level of Catmull-Clark subdivision.

    points : (v, 3) float64; counts : (f,) int faceVertexCounts (all >= 3); idx : (c,) int
    faceVertexIndices; fv : per-corner (c, k) arrays refined linearly within each face.
    returns (points (v + e + f, 3), idx (4c,) of quads (counts all 4), parent face (c,) of
    each quad, [fv refined (4c, k)]). Quad ``i`` is corner ``i`` of the input: (its vertex,
    the midpoint of its next edge, the face centre, the midpoint of its previous edge), so the
    winding is kept.
    """
    p = np.asarray(points, np.float64)
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(idx, np.int64)
    nv, nf, nc = len(p), len(counts), len(idx)
    face, nxt, prv, _ = _face_tables(counts, idx)
    edge, ends, nface = _edges(idx, nxt, nv)
    ne = len(ends)
    # face points
    fp = np.zeros((nf, 3))
    np.add.at(fp, face, p[idx])
    fp /= counts[:, None]
    # edge points: interior (mean of endpoints and adjacent face points), boundary: midpoint
    mid = 0.5 * (p[ends[:, 0]] + p[ends[:, 1]])
    fsum = np.zeros((ne, 3))
    np.add.at(fsum, edge, fp[face])
    interior = nface >= 2
    ep = mid.copy()
    ep[interior] = 0.5 * (mid[interior] + fsum[interior] / nface[interior, None])
    # vertex points
    val = np.bincount(ends.ravel(), minlength=nv)  # edges per vertex
    bnd_e = ~interior
    nbnd = np.bincount(ends[bnd_e].ravel(), minlength=nv)  # boundary edges per vertex
    fcount = np.bincount(idx, minlength=nv)  # faces per vertex
    q = np.zeros((nv, 3))
    np.add.at(q, idx, fp[face])
    r = np.zeros((nv, 3))
    np.add.at(r, ends[:, 0], mid)
    np.add.at(r, ends[:, 1], mid)
    vp = p.copy()
    inner = (nbnd == 0) & (val >= 3) & (fcount > 0)
    n = val[inner].astype(np.float64)[:, None]
    vp[inner] = (q[inner] / fcount[inner, None] + 2.0 * r[inner] / n + (n - 3.0) * p[inner]) / n
    # boundary vertices (exactly two boundary edges, more than one face): cubic B-spline curve
    bmask = (nbnd == 2) & (fcount > 1)
    bsum = np.zeros((nv, 3))
    be = ends[bnd_e]
    np.add.at(bsum, be[:, 0], p[be[:, 1]])
    np.add.at(bsum, be[:, 1], p[be[:, 0]])
    vp[bmask] = 0.75 * p[bmask] + 0.125 * bsum[bmask]
    # corners (one face) and non-manifold vertices keep their position
    out_p = np.concatenate([vp, ep, fp])
    e_off, f_off = nv, nv + ne
    quads = np.stack([idx, e_off + edge, f_off + face, e_off + edge[prv]], axis=1).reshape(-1)
    out_fv = []
    for a in fv:
        a = np.asarray(a, np.float64)
        a2 = a.reshape(nc, -1)
        fc = np.zeros((nf, a2.shape[1]))
        np.add.at(fc, face, a2)
        fc /= counts[:, None]
        emid = 0.5 * (a2 + a2[nxt])
        r4 = np.stack([a2, emid, fc[face], emid[prv]], axis=1).reshape(4 * nc, -1)
        out_fv.append(r4.reshape((4 * nc,) + a.shape[1:]))
    return out_p, quads, face, out_fv


def loop(points, tris, fv=()):
    """One level of Loop subdivision of a triangle mesh.

    points : (v, 3); tris : (t, 3) int; fv : per-corner (t, 3, k) arrays (midpoints).
    returns (points (v + e, 3), tris (4t, 3), parent triangle (4t,), [fv (4t, 3, k)]).
    """
    p = np.asarray(points, np.float64)
    tris = np.asarray(tris, np.int64)
    nv, nt = len(p), len(tris)
    idx = tris.reshape(-1)
    counts = np.full(nt, 3, np.int64)
    face, nxt, prv, _ = _face_tables(counts, idx)
    edge, ends, nface = _edges(idx, nxt, nv)
    ne = len(ends)
    interior = nface == 2
    # edge points: 3/8 (a + b) + 1/8 (c + d) inside; midpoints on boundaries
    opp = np.zeros((ne, 3))
    np.add.at(opp, edge, p[idx[prv]])  # the corner opposite each half-edge
    ep = 0.5 * (p[ends[:, 0]] + p[ends[:, 1]])
    ep[interior] = 0.375 * (p[ends[interior, 0]] + p[ends[interior, 1]]) + 0.125 * opp[interior]
    val = np.bincount(ends.ravel(), minlength=nv).astype(np.float64)
    nsum = np.zeros((nv, 3))
    np.add.at(nsum, ends[:, 0], p[ends[:, 1]])
    np.add.at(nsum, ends[:, 1], p[ends[:, 0]])
    bnd_e = ~interior
    nbnd = np.bincount(ends[bnd_e].ravel(), minlength=nv)
    fcount = np.bincount(idx, minlength=nv)
    vp = p.copy()
    inner = (nbnd == 0) & (val >= 3)
    nn = val[inner]
    beta = (0.625 - (0.375 + 0.25 * np.cos(2 * np.pi / nn)) ** 2) / nn
    vp[inner] = (1.0 - nn * beta)[:, None] * p[inner] + beta[:, None] * nsum[inner]
    bmask = (nbnd == 2) & (fcount > 1)
    bsum = np.zeros((nv, 3))
    be = ends[bnd_e]
    np.add.at(bsum, be[:, 0], p[be[:, 1]])
    np.add.at(bsum, be[:, 1], p[be[:, 0]])
    vp[bmask] = 0.75 * p[bmask] + 0.125 * bsum[bmask]
    out_p = np.concatenate([vp, ep])
    e = (nv + edge).reshape(nt, 3)  # e[:, k]: edge from corner k to corner k+1
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    eab, ebc, eca = e[:, 0], e[:, 1], e[:, 2]
    new = np.stack(
        [
            np.stack([a, eab, eca], 1),
            np.stack([eab, b, ebc], 1),
            np.stack([eca, ebc, c], 1),
            np.stack([eab, ebc, eca], 1),
        ],
        axis=1,
    ).reshape(-1, 3)
    parent = np.repeat(np.arange(nt), 4)
    out_fv = []
    for arr in fv:
        v = np.asarray(arr, np.float64)
        ua, ub, uc = v[:, 0], v[:, 1], v[:, 2]
        mab, mbc, mca = 0.5 * (ua + ub), 0.5 * (ub + uc), 0.5 * (uc + ua)
        out_fv.append(
            np.stack(
                [
                    np.stack([ua, mab, mca], 1),
                    np.stack([mab, ub, mbc], 1),
                    np.stack([mca, mbc, uc], 1),
                    np.stack([mab, mbc, mca], 1),
                ],
                axis=1,
            ).reshape((4 * nt, 3) + v.shape[2:])
        )
    return out_p, new, parent, out_fv


def cc_limit(points, quads):
    """Project the vertices of a quad mesh from Catmull-Clark refinement onto the limit surface.

    points : (v, 3); quads : (q, 4) int. returns (v, 3) limit positions (see the module
    docstring for the masks; vertices of one face and non-manifold ones are kept)."""
    p = np.asarray(points, np.float64)
    q = np.asarray(quads, np.int64)
    nv = len(p)
    idx = q.reshape(-1)
    counts = np.full(len(q), 4, np.int64)
    face, nxt, prv, _ = _face_tables(counts, idx)
    edge, ends, nface = _edges(idx, nxt, nv)
    val = np.bincount(ends.ravel(), minlength=nv).astype(np.float64)
    bnd_e = nface < 2
    nbnd = np.bincount(ends[bnd_e].ravel(), minlength=nv)
    fcount = np.bincount(idx, minlength=nv)
    esum = np.zeros((nv, 3))
    np.add.at(esum, ends[:, 0], p[ends[:, 1]])
    np.add.at(esum, ends[:, 1], p[ends[:, 0]])
    diag = np.zeros((nv, 3))
    np.add.at(diag, idx, p[idx[nxt[nxt]]])  # the corner opposite each corner of its quad
    out = p.copy()
    inner = (nbnd == 0) & (val >= 3) & (fcount == val)
    n = val[inner][:, None]
    out[inner] = (n * n * p[inner] + 4.0 * esum[inner] + diag[inner]) / (n * (n + 5.0))
    bmask = (nbnd == 2) & (fcount > 1)
    bsum = np.zeros((nv, 3))
    be = ends[bnd_e]
    np.add.at(bsum, be[:, 0], p[be[:, 1]])
    np.add.at(bsum, be[:, 1], p[be[:, 0]])
    out[bmask] = (4.0 * p[bmask] + bsum[bmask]) / 6.0
    return out


def quads_to_triangles(quads, fv=()):
    """Split quads (q, 4) into triangles (2q, 3) ((0, 1, 2), (0, 2, 3)); fv (4q, k) per
    quad corner -> (2q, 3, k). returns (tris, quad of each triangle, [fv])."""
    q = np.asarray(quads, np.int64).reshape(-1, 4)
    sel = np.array([[0, 1, 2], [0, 2, 3]])
    tris = q[:, sel].reshape(-1, 3)
    parent = np.repeat(np.arange(len(q)), 2)
    out = []
    for a in fv:
        a = np.asarray(a)
        a4 = a.reshape((len(q), 4) + a.shape[1:])
        out.append(a4[:, sel].reshape((2 * len(q), 3) + a.shape[1:]))
    return tris, parent, out


def vertex_normals(points, tris):
    """Unit vertex normals (v, 3): the angle-weighted mean of the triangles around each vertex
    (smooth everywhere, as a subdivision surface is)."""
    p = np.asarray(points, np.float64)
    t = np.asarray(tris, np.int64)
    fn = edge_cross(p[t])
    ln = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = np.divide(fn, ln, out=np.zeros_like(fn), where=ln > 0)
    out = np.zeros_like(p)
    for k in range(3):
        u = p[t[:, (k + 1) % 3]] - p[t[:, k]]
        w = p[t[:, (k + 2) % 3]] - p[t[:, k]]
        cosang = np.einsum("ij,ij->i", u, w) / np.maximum(
            np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300
        )
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(out, t[:, k], fn * ang[:, None])
    ln = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, ln, out=np.zeros_like(out), where=ln > 0)


def refine(points, counts, idx, scheme, levels, fv=(), limit=True):
    """Refine a polygon mesh ``levels`` times and triangulate it.

    scheme : "catmullClark" (any polygons) or "loop" (triangles only; else Catmull-Clark).
    fv : per-corner (c, k) arrays, refined linearly within each cage face.
    limit : project Catmull-Clark vertices onto the limit surface (after >= 1 level).
    returns (points (v', 3), tris (t', 3), cage face of each triangle (t',), [fv (t', 3, k)],
    normals (v', 3) unit vertex normals of the refined surface).
    """
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(idx, np.int64)
    fv = [np.asarray(a, np.float64) for a in fv]
    p = np.asarray(points, np.float64)
    if scheme == "loop" and np.all(counts == 3):
        tris, parent = idx.reshape(-1, 3), np.arange(len(counts))
        vals = [a.reshape((len(counts), 3) + a.shape[1:]) for a in fv]
        for _ in range(levels):
            p, tris, par, vals = loop(p, tris, vals)
            parent = parent[par]
        return p, tris, parent, vals, vertex_normals(p, tris)
    parent = np.arange(len(counts))
    q_idx, vals = idx, fv
    cnt = counts
    for _ in range(levels):
        p, q_idx, par, vals = catmull_clark(p, cnt, q_idx, vals)
        parent = parent[par]
        cnt = np.full(len(q_idx) // 4, 4, np.int64)
    if levels == 0:  # fan triangulation of the cage (no refinement)
        face, _, _, start = _face_tables(counts, idx)
        ntri = counts - 2
        tf = np.repeat(np.arange(len(counts)), ntri)
        first = np.concatenate([[0], np.cumsum(ntri)[:-1]])
        k = np.arange(len(tf)) - first[tf]
        s = start[tf]
        corners = np.stack([s, s + k + 1, s + k + 2], axis=1)
        out = [a[corners] for a in fv]
        tris = idx[corners]
        return p, tris, tf, out, vertex_normals(p, tris)
    quads = q_idx.reshape(-1, 4)
    if limit:
        p = cc_limit(p, quads)
    tris, qpar, out = quads_to_triangles(quads, vals)
    return p, tris, parent[qpar], out, vertex_normals(p, tris)
