"""Coincident opposite-facing triangles ("twins") in the reference export, separated for Cycles.

Production assets model a thin wall or a sheet as two coplanar faces wound opposite ways (the
classroom's front wall: a +z and a -z face at the same z to < 1 um). Cycles starts shadow
and bounce rays exactly on the surface and skips only the triangle it left, so the coplanar
twin occludes every ray leaving the face: light reflected off either side comes out almost
black. Measured on the classroom (session notes, issue 43): one-bounce irradiance 4 cm from the
cavity side of that wall 4.8e-6 in Cycles against 4.14e-5 in usdahd (8.6x); with the twin moved
1 mm, Cycles reads 4.14e-5, the same as usdahd, and the walls' texels agree within 1 %. usdahd
offsets each ray off the side it leaves (two-sided shading), so the twins do not shadow it.

:func:`separate_twins` moves each twin :data:`TWIN_GAP` / 2 toward the side it faces: the pair
becomes a closed slab TWIN_GAP thick, each side seen as the front face its author wound. That
is far below a lightmap texel (centimetres) and the points usdahd bakes are offset off the
surface anyway; scenes without twins are exported unchanged (same digest, same cached truth).
A box resting on a floor is the same configuration locally (its bottom face and the floor
under it): there the move changes nothing lit (the floor under the box stays covered).
Coincident faces wound the *same* way are left as they are (none seen in the shared scenes).
"""

from __future__ import annotations

import numpy as np

#: Distance (m) the two faces of a twin pair end up apart (each moves half of it).
TWIN_GAP = 1e-3
#: Two faces are coplanar when their planes are this close (m) ...
PLANE_TOL = 1e-5
#: ... and their unit normals are opposite to this dot product.
NORMAL_DOT = -0.99999
#: Barycentric points of a triangle tested against the opposite faces (the centroid, three
#: points towards the corners, three towards the edge midpoints): a face counts as a twin where
#: any lies on one (both directions are tested, so of two overlapping faces one is found).
_PROBE_BARY = (
    np.array(
        [[2, 2, 2], [4, 1, 1], [1, 4, 1], [1, 1, 4], [1, 2.5, 2.5], [2.5, 1, 2.5], [2.5, 2.5, 1]],
        np.float64,
    )
    / 6.0
)
#: Pairs tested per block (bounds memory on a large coplanar group such as a doubled floor).
_BLOCK = 1 << 20


def _plane_keys(g: np.ndarray, d: np.ndarray):
    """Canonical (sign, normal key, offset) per face: the sign makes the largest component of
    the normal positive, so twins share the normal key with opposite signs."""
    big = np.argmax(np.abs(g), axis=1)
    sign = np.where(g[np.arange(len(g)), big] >= 0, 1, -1)
    gc = g * sign[:, None]
    nkey = np.round(gc / 1e-3).astype(np.int64)
    return sign, nkey, d * sign


def find_twins(tri_p: np.ndarray) -> np.ndarray:
    """(t,) bool: faces with an opposite-facing coplanar face over part of them.

    tri_p : (t, 3, 3) float64 world-space corners, counter-clockwise about the front.
    """
    p = np.asarray(tri_p, np.float64)
    t = len(p)
    out = np.zeros(t, bool)
    if t < 2:
        return out
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area2 = np.linalg.norm(n, axis=1)
    ok = area2 > 1e-14
    g = np.where(ok[:, None], n / np.where(ok, area2, 1)[:, None], 0.0)
    sign, nkey, dc = _plane_keys(g, np.einsum("ij,ij->i", g, p.mean(1)))
    qd = np.floor(dc / (4 * PLANE_TOL)).astype(np.int64)
    # group by normal key and offset cell (4 PLANE_TOL wide); a twin may sit in the next cell
    buckets: dict = {}
    for i in np.flatnonzero(ok):
        buckets.setdefault((*nkey[i], qd[i]), []).append(i)
    for key in buckets:  # each cell with the next one up: every pair within PLANE_TOL meets
        group = np.asarray(buckets[key] + buckets.get((*key[:3], key[3] + 1), []))
        pos, neg = group[sign[group] > 0], group[sign[group] < 0]
        if len(pos) and len(neg):
            _mark_overlaps(p, g, dc, pos, neg, out)
            _mark_overlaps(p, g, dc, neg, pos, out)
    return out


def _mark_overlaps(p, g, dc, a, b, out) -> None:
    """Mark faces of ``a`` with a probe point on a coplanar opposite face of ``b``."""
    pts = np.einsum("kc,acx->akx", _PROBE_BARY, p[a])  # (na, k, 3)
    step = max(1, _BLOCK // max(len(b), 1))
    e0, e1 = p[b, 1] - p[b, 0], p[b, 2] - p[b, 0]
    d00 = np.einsum("ij,ij->i", e0, e0)
    d01 = np.einsum("ij,ij->i", e0, e1)
    d11 = np.einsum("ij,ij->i", e1, e1)
    den = d00 * d11 - d01 * d01
    good = den > 1e-30
    for s in range(0, len(a), step):
        ia = a[s : s + step]
        plane = np.abs(dc[ia][:, None] - dc[b][None]) < PLANE_TOL
        plane &= (g[ia] @ g[b].T) < NORMAL_DOT
        plane &= good[None]
        if not plane.any():
            continue
        ra, rb = np.nonzero(plane)
        q = pts[s + ra] - p[b[rb], 0][:, None]  # (m, k, 3)
        d20 = np.einsum("mkx,mx->mk", q, e0[rb])
        d21 = np.einsum("mkx,mx->mk", q, e1[rb])
        v = (d11[rb, None] * d20 - d01[rb, None] * d21) / den[rb, None]
        w = (d00[rb, None] * d21 - d01[rb, None] * d20) / den[rb, None]
        inside = ((v >= -1e-9) & (w >= -1e-9) & (v + w <= 1 + 1e-9)).any(axis=1)
        out[ia[np.unique(ra[inside])]] = True


def separate_twins(tri_p: np.ndarray, gap: float = TWIN_GAP):
    """(moved tri_p (t, 3, 3) float64, (t,) bool twins): each twin face moved gap / 2 along
    its own front normal. Returns the input array itself when there is no twin."""
    twins = find_twins(tri_p)
    if not twins.any():
        return tri_p, twins
    p = np.array(tri_p, np.float64)
    n = np.cross(p[twins, 1] - p[twins, 0], p[twins, 2] - p[twins, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p[twins] += (0.5 * gap) * n[:, None, :]
    return p, twins
