"""Normals of meshes that do not author any: the one rule the baker and the validator share.

A lightmap texel's hemisphere is centred on the shading normal, so the normals of a mesh without
authored ``normals`` are an input of the bake as much as its points. The rule (docs/schema.md,
"Normals"):

- **crease angle** (``subdivisionScheme = "none"``, ``"bilinear"``, or unauthored; see below):
  the corner of polygon ``f`` at point ``v`` is the angle-weighted average of the normals of
  the polygons around ``v`` whose normal is within :data:`CREASE_ANGLE_DEG` of ``f``'s own
  normal (``f`` itself always counts). Decided per pair of polygons, so a box is flat (its
  faces meet at 90 degrees: every corner keeps its own face normal, both triangles of a side
  get identical normals) and a tessellated cylinder is smooth (32 segments meet at 11.25
  degrees). Polygons are the mesh's own faces, not the fan triangles the tracer uses, so a
  quad has one normal per corner however it is triangulated.
- **smooth** (``catmullClark`` or ``loop`` authored): a subdivision surface is smooth
  everywhere, so every corner averages all polygons around its point (the crease angle is 180
  degrees). usdahd does not subdivide: the cage is traced with these normals.

Weights are the polygon's interior angle at the corner (Thürmer & Wüthrich 1998): unlike area
weights they do not change when a face is split into more triangles. Points are identified by
index (``faceVertexIndices``): faces that do not share point indices are not smoothed together,
as in Hydra. Everything is computed in the mesh's object space, where USD authors normals;
the baker authors the result into its override layer (``normals``, faceVarying) and records the
rule in ``ahdLightmap:baked:normals``, so a renderer shades with the normals the lightmap was
baked for.

Why 30 degrees: it is the default of Blender's "smooth by angle" and of Maya's and 3ds Max's
soften/auto-smooth, so assets look the way their authors saw them; it keeps every box, bevel
of 45 degrees or more and hexagonal prism faceted (a normal that leans across a hard edge
tilts the baked hemisphere by up to half the edge angle and leaks light around it) and smooths
tessellations of 13 or more segments per turn (27.7 degrees; our implicit gprims use 24).
A 12-segment circle meets exactly at 30 degrees: the test is ``angle < 30 + 0.5`` degrees
(:data:`CREASE_MARGIN_DEG`) so rounding never splits such a ring into smooth and faceted
corners.

Numerics only: numpy, no pxr.
"""

from __future__ import annotations

import math

import numpy as np

#: Crease angle of the rule in degrees (see the module docstring for why 30).
CREASE_ANGLE_DEG = 30.0
#: Tolerance added to the crease angle so polygons that meet at exactly 30 degrees (a 12-gon)
#: are smoothed whatever the float rounding of their normals.
CREASE_MARGIN_DEG = 0.5
#: ``ahdLightmap:baked:normals`` tokens: where the normals the bake used came from.
RULE_AUTHORED = "authored"
RULE_CREASE = "creaseAngle30"
RULE_SMOOTH = "smooth"
RULES = (RULE_AUTHORED, RULE_CREASE, RULE_SMOOTH)
#: Version of the rule, part of the bake's content hash: change it whenever the computed
#: normals change, so bakes made with the old rule are re-baked.
RULE_VERSION = "normals-2: crease 30+0.5 deg, interior-angle weights, object space"
#: subdivisionScheme values whose limit surface is smooth (RULE_SMOOTH).
SMOOTH_SCHEMES = ("catmullClark", "loop")
#: Pairs processed per chunk (bounds memory for very high-valence points, e.g. a fan's apex).
_CHUNK_PAIRS = 1 << 21


def rule_for_scheme(scheme: str | None) -> str:
    """The rule for a mesh's subdivisionScheme (None = unauthored: the crease rule, see
    docs/schema.md: usdahd does not subdivide, and unsubdivided meshes without normals render
    faceted in RTX renderers)."""
    return RULE_SMOOTH if scheme in SMOOTH_SCHEMES else RULE_CREASE


def polygon_frames(points, counts, indices):
    """Per-polygon unit normals and per-corner interior angles.

    points : (v, 3) float64; counts : (f,) int64 faceVertexCounts; indices : (c,) int64
    faceVertexIndices (c = counts.sum()).
    returns (face_normals (f, 3) float64 unit or zero for degenerate/short faces,
    angles (c,) float64 radians, 0 at corners of degenerate/short faces, face (c,) int64).
    The polygon normal is the sum of its fan triangles' cross products (Newell's vector for a
    planar polygon), right-handed (counter-clockwise front).
    """
    p = np.asarray(points, np.float64)
    counts = np.asarray(counts, np.int64)
    idx = np.asarray(indices, np.int64)
    nf = len(counts)
    face = np.repeat(np.arange(nf), counts)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    local = np.arange(len(idx)) - start[face]
    cnt = counts[face]
    safe = np.maximum(cnt, 1)
    nxt = idx[start[face] + (local + 1) % safe]
    prv = idx[start[face] + (local - 1) % safe]
    pc = p[idx]
    # Polygon normal: sum over fan triangles (s, k, k+1) of cross(p_k - p_s, p_k+1 - p_s).
    apex = p[idx[start[face]]]
    fan = (local >= 1) & (local <= cnt - 2)
    cr = np.cross(pc - apex, p[nxt] - apex)
    cr[~fan] = 0.0
    fn = np.zeros((nf, 3))
    for j in range(3):
        fn[:, j] = np.bincount(face, weights=cr[:, j], minlength=nf)
    ln = np.linalg.norm(fn, axis=1, keepdims=True)
    scale = float(np.abs(p).max()) if p.size else 1.0
    good = (ln[:, 0] > 1e-300) & (ln[:, 0] > 1e-14 * max(scale, 1e-300) ** 2) & (counts >= 3)
    fn = np.where(good[:, None], fn / np.where(ln > 0, ln, 1.0), 0.0)
    # Interior angle at each corner between the edges to the previous and next corner.
    e1 = p[prv] - pc
    e2 = p[nxt] - pc
    l1 = np.linalg.norm(e1, axis=1)
    l2 = np.linalg.norm(e2, axis=1)
    ok = (l1 > 0) & (l2 > 0) & good[face]
    cosang = np.einsum("ij,ij->i", e1, e2) / np.where(ok, l1 * l2, 1.0)
    ang = np.where(ok, np.arccos(np.clip(cosang, -1.0, 1.0)), 0.0)
    return fn, ang, face


def compute_normals(points, counts, indices, rule: str = RULE_CREASE, left_handed: bool = False):
    """Normals of a polygon mesh by the rule (see the module docstring), one per face-vertex.

    points : (v, 3) float64 object-space points; counts : (f,) int faceVertexCounts; indices :
    (c,) int faceVertexIndices; rule : RULE_CREASE or RULE_SMOOTH; left_handed : the mesh's
    orientation is leftHanded (normals point to the clockwise side).
    returns (c, 3) float32 unit normals in face-vertex order (faceVarying), ready to author.
    Corners of faces with fewer than 3 points or zero area take the smooth average at their
    point, else +Z (they cover no surface).
    """
    if rule not in (RULE_CREASE, RULE_SMOOTH):
        raise ValueError(f"unknown normals rule {rule!r}; expected one of {RULES[1:]}")
    idx = np.asarray(indices, np.int64)
    counts = np.asarray(counts, np.int64)
    dead = collapsed_faces(points, counts, idx)
    if not dead.any():
        return _normals(points, counts, idx, rule, left_handed)[0]
    # Faces whose corners all sit on one position have a zero normal and zero angles: they add
    # nothing to any other corner, so the rule runs on the other faces alone (a million such
    # triangles cost seconds and ~100 MB instead of GBs, issue 40) and their corners take the
    # fallback below (identical to running the rule on the whole mesh).
    live = np.repeat(~dead, counts)
    out = np.empty((len(idx), 3), np.float32)
    out[live], weighted = _normals(points, counts[~dead], idx[live], rule, left_handed)
    return _fallback(out, live, idx, weighted)


def collapsed_faces(points, counts, idx) -> np.ndarray:
    """(f,) bool: faces of 3 or more corners that all sit on one position (repeated indices or
    coincident points): zero area whatever the transform. Vectorised, O(corners) memory."""
    p = np.asarray(points, np.float64)
    nf = len(counts)
    if nf == 0 or len(idx) == 0:
        return np.zeros(nf, bool)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    # each corner's face's first point (a face of 0 corners repeats nothing)
    first = np.repeat(idx[np.minimum(start, len(idx) - 1)], counts)
    moved = np.zeros(len(idx), bool)
    for j in range(3):
        moved |= p[idx, j] != p[first, j]
    face = np.repeat(np.arange(nf), counts)
    return (counts >= 3) & (np.bincount(face, weights=moved, minlength=nf) == 0)


def _fallback(out, live, idx, weighted) -> np.ndarray:
    """``out`` with the corners not in ``live`` set as :func:`_normals` sets corners of
    zero-area faces: the angle-weighted average of the live corners at their point, else +Z."""
    nv = int(idx.max()) + 1
    live_idx = idx[live]
    vsum = np.zeros((nv, 3))
    for j in range(3):
        vsum[:, j] = np.bincount(live_idx, weights=weighted[:, j], minlength=nv)
    # per point, then gathered (a million dead corners usually sit on a few points)
    la = np.linalg.norm(vsum, axis=1, keepdims=True)
    alt = np.where(la > 1e-300, vsum / np.where(la > 0, la, 1.0), [0.0, 0.0, 1.0])
    out[~live] = (alt / 1.0).astype(np.float32)[idx[~live]]
    return out


def _normals(points, counts, idx, rule, left_handed):
    """:func:`compute_normals` on every face: ((c, 3) float32 normals, (c, 3) float64 each
    corner's angle-weighted face normal)."""
    fn, ang, face = polygon_frames(points, counts, idx)
    if left_handed:
        fn = -fn
    c = len(idx)
    out = np.zeros((c, 3))
    if c == 0:
        return out.astype(np.float32), out
    cos_limit = math.cos(math.radians(min(CREASE_ANGLE_DEG + CREASE_MARGIN_DEG, 180.0)))
    weighted = fn[face] * ang[:, None]  # (c, 3) each corner's contribution to its point
    if rule == RULE_SMOOTH:
        nv = int(idx.max()) + 1
        vsum = np.zeros((nv, 3))
        for j in range(3):
            vsum[:, j] = np.bincount(idx, weights=weighted[:, j], minlength=nv)
        out = vsum[idx]
    else:
        # Every pair (corner a, corner b) at the same point: a gathers b when their faces'
        # normals are within the crease angle (sorted by point; k^2 pairs for k corners).
        # Corners of zero-area faces (normal 0) neither gather nor are gathered (their dot
        # with any normal is 0), so they are left out of the pairs: a million degenerate
        # triangles on one point would otherwise be 10^12 pairs (issue 40); their corners
        # take the fallback below, as before.
        live = np.flatnonzero(np.any(fn != 0.0, axis=1)[face])
        order = live[np.argsort(idx[live], kind="stable")]
        sv = idx[order]
        n_live = len(order)
        bounds = np.flatnonzero(np.diff(sv)) + 1
        gstart = np.concatenate([[0], bounds]) if n_live else np.zeros(0, np.int64)
        gsize = np.diff(np.concatenate([gstart, [n_live]]))
        k = np.repeat(gsize, gsize)  # group size at each sorted position
        s = np.repeat(gstart, gsize)  # group start at each sorted position
        cum = np.cumsum(k)
        pos = 0
        while pos < n_live:
            end = int(np.searchsorted(cum, (cum[pos - 1] if pos else 0) + _CHUNK_PAIRS, "right"))
            end = max(end, pos + 1)
            kk = k[pos:end]
            a = np.repeat(order[pos:end], kk)
            first = np.repeat(np.cumsum(kk) - kk, kk)
            j = np.arange(len(a)) - first
            b = order[np.repeat(s[pos:end], kk) + j]
            dots = np.einsum("ij,ij->i", fn[face[a]], fn[face[b]])
            keep = dots >= cos_limit
            a, b = a[keep], b[keep]
            for d in range(3):
                out[:, d] += np.bincount(a, weights=weighted[b, d], minlength=c)
            pos = end
    ln = np.linalg.norm(out, axis=1, keepdims=True)
    bad = ln[:, 0] <= 1e-300
    if bad.any():  # corners of degenerate faces: the all-faces average at their point
        nv = int(idx.max()) + 1
        vsum = np.zeros((nv, 3))
        for j in range(3):
            vsum[:, j] = np.bincount(idx, weights=weighted[:, j], minlength=nv)
        alt = vsum[idx[bad]]
        la = np.linalg.norm(alt, axis=1, keepdims=True)
        alt = np.where(la > 1e-300, alt / np.where(la > 0, la, 1.0), [0.0, 0.0, 1.0])
        out[bad] = alt
        ln[bad] = 1.0
    return (out / ln).astype(np.float32), weighted


def to_world(normals, m3):
    """Object-space normals to world space (inverse transpose), renormalized.

    normals : (..., 3) float32 or float64 object-space normals (authored or computed);
    m3 : (3, 3) float64 upper-left block of the row-vector local-to-world matrix.
    returns (..., 3) float64; rows whose transform is degenerate come back non-finite or zero
    (the caller checks). The baker and the validator send authored and computed normals through
    this one function, so a bake's normals read back from its layer hash identically.
    """
    n = np.asarray(normals, np.float64) @ np.linalg.inv(np.asarray(m3, np.float64)).T
    ln = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / ln


__all__ = [
    "CREASE_ANGLE_DEG",
    "RULES",
    "RULE_AUTHORED",
    "RULE_CREASE",
    "RULE_SMOOTH",
    "RULE_VERSION",
    "collapsed_faces",
    "compute_normals",
    "polygon_frames",
    "rule_for_scheme",
    "to_world",
    "SMOOTH_SCHEMES",
]
