"""Sample points near other geometry: contacts, covers and rim texels (docs/texels.md).

numpy only; each function is handed a tracer (``usdahd.bake.trace``'s interface). Split from
:mod:`usdahd.bake.texels` (which rasterises the texels these functions move or flag).

Public functions
----------------
push_off_contacts(texels, mesh, tracer) -> (Texels, invalid) sample points moved off contacts
move_off_covers(texels, mesh, tracer) -> (Texels, moved)    rim texels moved out from under covers
walled_in(position, geom_normal, offsets, tracer) -> (n,) bool
covered(position, geom_normal, offsets, size, tracer) -> (n,) bool
texel_sizes(texels, mesh) -> (n,) float64                   a texel's world size
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from usdahd.bake.texels import check_mesh, half_texel_vectors
from usdahd.bake.types import Texels
from usdahd.numerics.sampling import (
    cosine_hemisphere,
    orthonormal_basis,
    r2_sequence,
    texel_hemisphere,
    to_world,
    uniform_hemisphere,
)
from usdahd.scene.types import MeshData

__all__ = [
    "COVERED",
    "COVERED_DISTANCE",
    "covered",
    "inside_pilot",
    "move_off_covers",
    "push_off_contacts",
    "texel_sizes",
    "walled_in",
]

# contacts: sample points moved off surfaces that cross the texel's footprint

#: Directions of the footprint probes, in half-texel steps along (dP/du, dP/dv): the 4 edge
#: midpoints and the 4 corners of the texel's footprint on its triangle's plane.
CONTACT_PROBES = np.array(
    [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)], dtype=np.float64
)
#: Probe rounds: after a move the probes are cast again from the new point; a texel still
#: behind a surface after this many moves is reported invalid (filled from its neighbours).
CONTACT_ROUNDS = 3
#: Floor on the cosine between a probe and the back face it hit when placing the point beyond
#: that face (a grazing hit would otherwise push the point arbitrarily far).
CONTACT_MIN_COS = 0.05
#: Hemisphere rays per candidate texel of the enclosure test (a fixed R2 set, uniform on the
#: geometric normal's hemisphere): only texels with a back-face probe hit pay for them.
CONTACT_ENCLOSURE_RAYS = 32
#: A texel whose origin sees back faces in more than this fraction of its hemisphere is inside
#: geometry: inside a closed solid it is all of it, while outside a convex single-sided shell
#: (a room modelled from the inside) a point on the ground sees the shell's back in at most half
#: (a plane wall right next to it; 32 rays measured 17/32 at 3 cm from a wall, hence the
#: margin). The integrator's ``backface_threshold`` (0.25) is lower, but it also asks for
#: :func:`walled_in` (such a near-wall point is not: it is estimated, not filled).
CONTACT_ENCLOSED = 0.75


def _crossed_by_offset(p, o, d, t, hn, k) -> np.ndarray:
    """(m * k,) bool: probe hits whose face's plane separates the sample point from its ray
    origin (the point on or in front of the face, the origin behind it). p (m, 3) points; o, d
    (m * k, 3) probe origins and directions; t (m * k,) hit distances; hn (m * k, 3) normals."""
    hit = o + d * np.where(np.isfinite(t), t, 0.0)[:, None]
    pp = np.repeat(p, k, axis=0)
    tol = 1e-6 * (1.0 + np.abs(pp).max(axis=1))
    return np.einsum("ij,ij->i", pp - hit, hn) >= -tol


def _enclosed(origin: np.ndarray, g: np.ndarray, tracer) -> np.ndarray:
    """(m,) bool: origins whose hemisphere about ``g`` sees back faces in more than
    ``CONTACT_ENCLOSED`` of ``CONTACT_ENCLOSURE_RAYS`` fixed directions."""
    local, _ = uniform_hemisphere(r2_sequence(CONTACT_ENCLOSURE_RAYS))  # (r, 3)
    return _back_fraction(origin, g, local, tracer) > CONTACT_ENCLOSED


def _back_fraction(origin: np.ndarray, g: np.ndarray, local: np.ndarray, tracer) -> np.ndarray:
    """(m,) fraction of rays from ``origin`` (m, 3) along the directions ``local`` (r, 3), given
    in each origin's frame about ``g`` (m, 3) (z = g), whose first hit is a back face of a
    one-sided mesh (``Tracer.back_face``)."""
    m, r = len(origin), len(local)
    frames = orthonormal_basis(g)  # (m, 3, 3)
    dirs = to_world(local[None, :, :], frames[:, None, :, :]).reshape(-1, 3)
    hit = tracer.intersect(np.repeat(origin, r, axis=0), dirs)
    tri = hit["tri"]
    hn = tracer.geom_normal[np.maximum(tri, 0)].astype(np.float64)
    return tracer.back_face(tri, dirs, hn).reshape(m, r).mean(axis=1)


def push_off_contacts(texels: Texels, mesh: MeshData, tracer) -> tuple[Texels, np.ndarray]:
    """Move sample points whose ray origin lies behind a surface crossing the texel's footprint.

    The problem: a sample point exactly on (or within its ray offset of) a contact, e.g. the
    bottom edge of an overhanging face resting on the ground, gets its ray origin
    ``P + offset * n`` on the far side of the other surface (below the ground, inside a
    solid); its hemisphere then sees what lies behind that surface (the sky under the ground)
    and the texel comes out as a bright line. No test from the origin back to ``P`` can see a
    surface through ``P`` itself in float32.

    The rule (the "push out of geometry" of GPU lightmappers such as Bakery, Unity's
    progressive lightmapper and Godot's LightmapGI, which probe a texel's footprint with short
    rays): from each texel's ray origin (:meth:`Tracer.offset` along its geometric normal, the
    origin the integrator uses) 8 probes run in the plane of its triangle toward the 4 edge
    midpoints and 4 corners of the texel's footprint (``CONTACT_PROBES`` x
    :func:`half_texel_vectors`, so each reaches exactly the footprint's boundary). If a probe's
    first hit is a **back face** (``dot(d, n_hit) > 0``), the origin is behind a surface that
    crosses the footprint: the sample point moves along the nearest such probe to just beyond
    that hit (by ``2 * offset / max(cos, CONTACT_MIN_COS)``, so the new origin is in front of
    it), still on the triangle's plane and inside the footprint, and the probes are cast again
    (up to ``CONTACT_ROUNDS`` rounds, for corners of two surfaces). Front-face hits (a wall the
    origin is in front of, a crease of the mesh itself) leave the texel alone, as do texels
    whose whole footprint is behind a surface (no probe hits anything: they are inside
    geometry and the integrator's back-face test flags them). A texel still behind a surface
    after the last round, or whose move would leave its footprint, keeps its point and is
    returned in ``invalid`` so the caller fills it from valid neighbours, like texels inside
    geometry.

    A back face in the footprint alone does not say which side is inside: single-sided
    geometry seen from behind (an interior shell seen from outside, as the classroom's walls
    seen from the ground around it, a card seen from its back) gives the same probe hit as the
    inside of a box. So a texel is moved only when its point really is behind a surface:

    - the offset carried its ray origin across the surface the probe hit (the sample point
      ``P`` is on or in front of that face's plane, the origin behind it): the bright line at
      contacts; or
    - its origin is inside geometry: back faces in more than ``CONTACT_ENCLOSED`` (3/4) of
      ``CONTACT_ENCLOSURE_RAYS`` hemisphere rays (inside a closed solid: all of them).

    Other texels keep their point (measured on the shared classroom at 24^2: 4 ground texels
    next to its inward-facing walls were moved 4.2 m into the building and came out black
    where Cycles has them sunlit).

    Why move rather than always invalidate: the moved point still lies in the texel's own
    footprint and sees what that part of the footprint sees (Cycles, which jitters samples
    over the footprint, averages over it); filling from neighbours instead would replace a
    whole row of contact texels by values from one side. The frame and geometric normal are
    kept (the point stays on the triangle's plane).

    texels, mesh: as :func:`rasterize` returned them for this mesh; tracer: a
    :class:`usdahd.bake.trace.Tracer` over the scene (``offset``, ``intersect``,
    ``geom_normal``, ``texel_offsets``). Costs ``8 x rounds`` rays per texel (a bake traces
    hundreds). Returns ``(texels, invalid (n,) bool)``; ``texels`` is the same object when no
    point moved, else a copy with the new ``position`` and ``stats["contact_texels"]`` (moved)
    and ``stats["contact_invalid"]``.
    """
    n = len(texels)
    invalid = np.zeros(n, bool)
    if n == 0:
        return texels, invalid
    # Each texel's probes depend on that texel only, so the texels go in chunks of
    # CONTACT_CHUNK (the same result; the probe arrays take ~1.5 kB per texel, which was a
    # 1 GB transient on the classroom's largest map).
    half_t = half_texel_vectors(mesh, texels.resolution)  # (t, 2, 3)
    scales = tracer.texel_offsets(texels, mesh)  # the integrator's ray offsets
    moved = np.zeros(n, bool)
    position = None
    for a in range(0, n, CONTACT_CHUNK):
        b = min(n, a + CONTACT_CHUNK)
        pos, mv, inv = _push_off_chunk(
            half_t[texels.triangle[a:b]],
            texels.position[a:b].astype(np.float64),
            texels.geom_normal[a:b].astype(np.float64),
            scales[a:b],
            tracer,
        )
        moved[a:b], invalid[a:b] = mv, inv
        if mv.any():
            if position is None:
                position = texels.position.copy()
            position[a:b][mv] = pos[mv]
    if moved.any() or invalid.any():  # invalid texels keep their original point
        if position is None:
            position = texels.position.copy()
        stats = dict(
            texels.stats, contact_texels=int(moved.sum()), contact_invalid=int(invalid.sum())
        )
        texels = replace(texels, position=position, stats=stats)
    texels, rim = move_off_covers(texels, mesh, tracer, skip=invalid)
    if rim.any():
        moved |= rim
        stats = dict(texels.stats, contact_texels=int(moved.sum()), rim_texels=int(rim.sum()))
        stats.setdefault("contact_invalid", int(invalid.sum()))
        texels = replace(texels, stats=stats)
    return texels, invalid


#: Texels probed at once by :func:`push_off_contacts` (bounds its memory; any value gives the
#: same result).
CONTACT_CHUNK = 65536


def _push_off_chunk(half, pos, ng, scales, tracer):
    """:func:`push_off_contacts` of m texels: half (m, 2, 3) half-texel vectors, pos / ng
    (m, 3) float64 points and geometric normals, scales (m,) ray offsets. Returns (pos (m, 3)
    float64 moved points, moved (m,) bool, invalid (m,) bool); moved excludes invalid."""
    n = len(pos)
    invalid = np.zeros(n, bool)
    probes = np.einsum("kj,njc->nkc", CONTACT_PROBES, half)  # (n, 8, 3)
    length = np.linalg.norm(probes, axis=2)
    ok = length > 0
    dirs = probes / np.where(ok, length, 1.0)[..., None]
    k = len(CONTACT_PROBES)
    pos = pos.copy()
    moved = np.zeros(n, bool)
    todo = np.nonzero(ok.any(axis=1))[0]
    for rnd in range(CONTACT_ROUNDS + 1):
        if len(todo) == 0:
            break
        p, g = pos[todo], ng[todo]
        origin = tracer.offset(p, g, g, scales[todo])
        o = np.repeat(origin, k, axis=0)
        d = dirs[todo].reshape(-1, 3)
        tfar = length[todo].reshape(-1)
        hit = tracer.intersect(o, np.where(tfar[:, None] > 0, d, g.repeat(k, 0)), tfar)
        tri = hit["tri"]
        hn = tracer.geom_normal[np.maximum(tri, 0)].astype(np.float64)
        cos = np.einsum("ij,ij->i", d, hn)
        back0 = (tfar > 0) & (hit["t"] < tfar) & tracer.back_face(tri, d, hn)
        back = back0.copy()
        if rnd == 0 and back.any():  # only points really behind a surface (docstring)
            back &= _crossed_by_offset(p, o, d, hit["t"], hn, k)
            cand = ~back.reshape(-1, k).any(axis=1) & back0.reshape(-1, k).any(axis=1)
            enclosed = np.zeros(len(todo), bool)
            enclosed[cand] = _enclosed(origin[cand], g[cand], tracer)
            back |= back0 & np.repeat(enclosed, k)
        back = back.reshape(-1, k)
        behind = back.any(axis=1)
        if not behind.any():
            break
        t = np.where(back, hit["t"].reshape(-1, k), np.inf)
        j = np.argmin(t, axis=1)
        rows = np.arange(len(todo))
        sel = todo[behind]
        if rnd == CONTACT_ROUNDS:  # still behind a surface after the last move
            invalid[sel] = True
            break
        jb, rb = j[behind], rows[behind]
        scale = tracer.offset_scale(p[rb], scales[todo[rb]])  # the origin's offset
        step = t[rb, jb] + 2.0 * scale / np.maximum(cos.reshape(-1, k)[rb, jb], CONTACT_MIN_COS)
        fits = step <= length[sel, jb]
        invalid[sel[~fits]] = True
        go = sel[fits]
        pos[go] += dirs[go, jb[fits]] * step[fits][:, None]
        moved[go] = True
        todo = go
    moved &= ~invalid
    return pos, moved, invalid


#: The inside pilot (:func:`inside_pilot`): rays per texel over its hemisphere (the first
#: R2 points through the integrator's texel hemisphere mapping, in every texel's frame), and
#: the fraction of them that must meet a back face. 0.75 of 8 where the integrator's rule is
#: 0.25 of all its samples: only texels far past that rule stop early (under a box resting on
#: a floor all 8 meet its inside); a texel near it is traced in full and judged as before.
INSIDE_PILOT_RAYS = 8
INSIDE_PILOT = 0.75


def inside_pilot(position: np.ndarray, geom_normal: np.ndarray, offsets: np.ndarray, tracer):
    """(n,) float64 pilot back-face fraction of each texel (asked only of texels whose ray along
    the normal meets a back face), 0 where it is not also :func:`walled_in`: the texels with a
    fraction above ``INSIDE_PILOT`` are inside geometry before any path is traced
    (:func:`usdahd.bake.integrate.bake_texels` gives them a few samples only: their estimate
    is replaced by their neighbours', and a path from inside a closed box bounces until
    Russian roulette ends it: 10.3 rays a sample under stretched_boxes' boxes against 2.4 on
    the open floor, 9x the time).

    position, geom_normal : (n, 3); offsets : (n,) float64 ray-origin offsets
    (``tracer.texel_offsets``); tracer : usdahd.bake.trace.Tracer."""
    p = np.asarray(position, np.float64)
    g = np.asarray(geom_normal, np.float64)
    if len(p) == 0:
        return np.zeros(0)
    offsets = np.asarray(offsets, np.float64)
    origin = tracer.offset(p, g, g, offsets)
    frac = np.zeros(len(p))
    # one ray along the normal first: only a texel that meets a back face there is asked
    tri = tracer.intersect(origin, g)["tri"]
    hn = tracer.geom_normal[np.maximum(tri, 0)].astype(np.float64)
    ask = np.nonzero(tracer.back_face(tri, g, hn))[0]
    if len(ask):
        local, _ = texel_hemisphere(r2_sequence(INSIDE_PILOT_RAYS))
        frac[ask] = _back_fraction(origin[ask], g[ask], local, tracer)
    high = np.nonzero(frac > INSIDE_PILOT)[0]
    if len(high):
        frac[high[~walled_in(p[high], g[high], offsets[high], tracer)]] = 0.0
    frac[frac <= INSIDE_PILOT] = 0.0
    return frac


#: Directions of the walled-in test: evenly spread azimuths in the surface's tangent plane.
WALLED_IN_RAYS = 16
#: A texel is walled in when at least this fraction of its along-surface rays hit back faces.
WALLED_IN = 0.75


def walled_in(position: np.ndarray, geom_normal: np.ndarray, offsets: np.ndarray, tracer):
    """(n,) bool: texels whose point is closed in along its own surface, i.e. inside geometry.

    position, geom_normal : (n, 3) texel sample points and geometric normals; offsets : (n,)
    float64 ray-origin offsets (``tracer.texel_offsets``); tracer : usdahd.bake.trace.Tracer.

    From the ray origin (the point lifted by its offset) ``WALLED_IN_RAYS`` rays run in the
    tangent plane, evenly spread in azimuth; the texel is walled in when at least ``WALLED_IN``
    of them hit a back face of a one-sided mesh (``Tracer.back_face``). The integrator's
    hemisphere back-face fraction alone cannot tell the inside of a solid from a thin gap under
    a single-sided card: a ceiling 1 cm above a one-sided emissive panel sees the panel's back
    in ~99 % of its cosine-weighted hemisphere, like the floor under a box. Along the surface
    the two differ: from the floor under the box every such ray meets a wall from behind; from
    the ceiling in the gap they leave through it (and behind a lone one-sided wall or under a
    one-sided table top about half or none meet a back face). So a texel is inside geometry
    only when both tests say so (:func:`usdahd.bake.integrate.inside_geometry`).
    """
    p = np.asarray(position, np.float64)
    g = np.asarray(geom_normal, np.float64)
    if len(p) == 0:
        return np.zeros(0, bool)
    phi = (np.arange(WALLED_IN_RAYS) + 0.5) * (2.0 * np.pi / WALLED_IN_RAYS)
    local = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)  # z = normal
    origin = tracer.offset(p, g, g, np.asarray(offsets, np.float64))
    return _back_fraction(origin, g, local, tracer) >= WALLED_IN


#: Covered texels (:func:`covered`): cosine-distributed probe directions, the probe length in
#: texel sizes, and the share of probes that must hit within it.
COVERED_RAYS = 32
COVERED_DISTANCE = 0.5
COVERED = 0.9


def texel_sizes(texels: Texels, mesh: MeshData) -> np.ndarray:
    """(n,) float64 world size of each texel: the longer of its two sides on its triangle,
    ``2 * max(|a_u|, |a_v|)`` (:func:`half_texel_vectors`); 0 on triangles with degenerate
    UVs."""
    tri, inv = np.unique(np.asarray(texels.triangle, np.int64), return_inverse=True)
    half = half_texel_vectors(mesh, texels.resolution, tri)
    return 2.0 * np.linalg.norm(half, axis=-1).max(axis=-1)[inv.reshape(-1)]


def covered(
    position: np.ndarray, geom_normal: np.ndarray, offsets: np.ndarray, size: np.ndarray, tracer
) -> np.ndarray:
    """(n,) bool: texels whose point lies under a surface much closer than the texel is wide,
    e.g. the board under a chess piece's closed base (docs/texels.md, "Covered texels").

    position, geom_normal : (n, 3); offsets : (n,) ray-origin offsets; size : (n,) world texel
    sizes (:func:`texel_sizes`). With ``D = COVERED_DISTANCE * size`` (half a texel: the
    reach of the texel's footprint from its centre), both must hold: the ray along the
    geometric normal hits a surface within ``D`` (something lies right over the point), and at
    least ``COVERED`` of ``COVERED_RAYS`` fixed cosine-distributed directions hit a surface
    (either face, any mesh) within ``D``. Such a point sees nothing but the underside of what
    covers it: it bakes black, and the bilinear lookup spreads that black half a texel beyond
    the cover's outline, where the surface is lit. Under a flat cover at height ``h`` the share
    is ``1 - (h / D)^2`` (cosine-weighted directions within ``acos(h / D)`` of the normal), so
    only a cover lower than ``0.32 D`` (0.16 texel) counts; a point beside one wall reaches
    0.5, in an inner corner 0.75, at the end of a slot 0.875, and a crevice open above fails
    the first test: they stay estimated.
    """
    p = np.asarray(position, np.float64)
    g = np.asarray(geom_normal, np.float64)
    reach = COVERED_DISTANCE * np.asarray(size, np.float64)
    out = np.zeros(len(p), bool)
    if len(p) == 0:
        return out
    origin = tracer.offset(p, g, g, np.asarray(offsets, np.float64))
    ok = reach > 0
    over = np.zeros(len(p), bool)
    idx = np.nonzero(ok)[0]
    if len(idx):
        over[idx] = tracer.intersect(origin[idx], g[idx], reach[idx])["tri"] >= 0
    cand = np.nonzero(over)[0]
    if len(cand) == 0:
        return out
    local, _ = cosine_hemisphere(r2_sequence(COVERED_RAYS))
    r = len(local)
    frames = orthonormal_basis(g[cand])
    dirs = to_world(local[None, :, :], frames[:, None, :, :]).reshape(-1, 3)
    hit = tracer.intersect(np.repeat(origin[cand], r, axis=0), dirs, np.repeat(reach[cand], r))
    share = (hit["tri"] >= 0).reshape(-1, r).mean(axis=1)
    out[cand] = share >= COVERED
    return out


#: Rim texels (:func:`move_off_covers`): a point counts as under a cover when the ray along its
#: geometric normal hits a surface within ``RIM_HEIGHT`` of the covered probe length ``D``
#: (``sqrt(1 - COVERED)``, 0.32: the height under which a flat cover makes a texel
#: :func:`covered`); the footprint is searched on a ``RIM_GRID`` x ``RIM_GRID`` grid of points
#: (the centres of its sub-squares); the new point lies ``RIM_INSET`` of the way from the
#: uncovered candidate closest to the old point to the uncovered candidates' centroid (the rule
#: of ``raster.CONSERVATIVE_INSET`` for the covered part of a conservative texel).
RIM_HEIGHT = float(np.sqrt(1.0 - COVERED))
RIM_GRID = 4
RIM_INSET = 0.5


def _uv_barycentrics(tuv: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(m, k, 3) barycentrics of the UV points (u, v) (m, k) on the UV triangles tuv (m, 3, 2);
    NaN on degenerate triangles."""
    a, b, c = tuv[:, 0], tuv[:, 1], tuv[:, 2]
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    safe = np.where(np.abs(det) > 1e-300, det, np.nan)[:, None]
    du, dv = u - a[:, 0:1], v - a[:, 1:2]
    l1 = (du * e2[:, 1:2] - dv * e2[:, 0:1]) / safe
    l2 = (e1[:, 0:1] * dv - e1[:, 1:2] * du) / safe
    return np.stack([1.0 - l1 - l2, l1, l2], axis=-1)


def _closest_on_triangle(tuv: np.ndarray, u: np.ndarray, v: np.ndarray):
    """(u, v) (m, k) moved to their closest points on the UV triangles tuv (m, 3, 2) when they
    lie outside (points inside stay)."""
    p = np.stack([u, v], axis=-1)  # (m, k, 2)
    bary = _uv_barycentrics(tuv, u, v)
    inside = np.all(bary >= 0.0, axis=-1)
    best = p.copy()
    dist = np.full(u.shape, np.inf)
    for i in range(3):
        a, b = tuv[:, i][:, None, :], tuv[:, (i + 1) % 3][:, None, :]
        ab = b - a
        den = np.maximum((ab**2).sum(axis=-1), 1e-300)
        t = np.clip(((p - a) * ab).sum(axis=-1) / den, 0.0, 1.0)
        q = a + t[..., None] * ab
        d = ((p - q) ** 2).sum(axis=-1)
        closer = ~inside & (d < dist)
        best = np.where(closer[..., None], q, best)
        dist = np.where(closer, d, dist)
    return best[..., 0], best[..., 1]


def move_off_covers(texels: Texels, mesh: MeshData, tracer, skip=None) -> tuple[Texels, np.ndarray]:
    """Move the sample point of a *rim texel* out from under a low cover to the uncovered part
    of its footprint (docs/texels.md, "Rim texels").

    A texel whose point lies under a surface much closer than the texel is wide (the board
    under a chess piece's base floating 0.5 mm over it) sees that surface's underside. Deep
    under the cover :func:`covered` flags it and the bake fills it from its chart; near the
    cover's outline its point still sees out sideways, so it stays estimated, dark, while
    the bilinear lookup reads it up to half a texel outside the outline, where the surface
    is lit and the path-traced view averages the lit part of the footprint only (the part
    under the cover is hidden from every view).

    The rule: a texel is *under a cover* when the ray along its geometric normal from its ray
    origin hits a surface (either face) within ``RIM_HEIGHT * COVERED_DISTANCE`` of its
    world size (:func:`texel_sizes`: 0.16 texel, the height under which a flat cover makes a
    texel :func:`covered`). Its footprint (the texel's square in UV, mapped through its own
    triangle) is searched on a ``RIM_GRID`` x ``RIM_GRID`` grid; a candidate is *uncovered*
    when it lies on the triangle, its normal ray hits nothing within that height, and the
    way along the surface from the texel's ray origin to the candidate's meets nothing. The
    point moves ``RIM_INSET`` of the way from the uncovered candidate closest to it toward the
    uncovered candidates' centroid (the closest one when that point fails the same tests).
    Texels with no uncovered candidate (the whole footprint under the cover), and those in
    ``skip`` ((n,) bool), keep their point. The frame and geometric normal are kept.

    Returns ``(texels, moved (n,) bool)``; ``texels`` is the same object when no point moved,
    else a copy with the new ``position``. Costs one ray per texel and ``2 * RIM_GRID^2``
    more for texels under a cover.
    """
    n = len(texels)
    moved = np.zeros(n, bool)
    if n == 0 or mesh.uv is None:
        return texels, moved
    w, h = texels.resolution
    uv_t = check_mesh(mesh)
    size = texel_sizes(texels, mesh)
    low = RIM_HEIGHT * COVERED_DISTANCE * size
    scales = tracer.texel_offsets(texels, mesh)
    p = texels.position.astype(np.float64)
    g = texels.geom_normal.astype(np.float64)
    ok = low > 0
    if skip is not None:
        ok &= ~np.asarray(skip, bool)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return texels, moved
    o = tracer.offset(p[idx], g[idx], g[idx], scales[idx])
    cand = idx[tracer.intersect(o, g[idx], low[idx])["tri"] >= 0]
    if len(cand) == 0:
        return texels, moved
    s = (np.arange(RIM_GRID) + 0.5) / RIM_GRID  # sub-square centres, in texels from the corner
    gx, gy = (a.ravel() for a in np.meshgrid(s, s))
    k = len(gx)
    xy = texels.xy[cand].astype(np.float64)
    u = (xy[:, 0:1] + gx[None, :]) / w
    v = 1.0 - (xy[:, 1:2] + gy[None, :]) / h  # row 0 = top (v = 1)
    tri = np.asarray(texels.triangle)[cand]
    tuv = uv_t[tri].astype(np.float64)
    # grid points off the triangle go to its closest point (a sliver thinner than the grid
    # spacing, e.g. a step face of the chess board's frame, still gets candidates)
    u, v = _closest_on_triangle(tuv, u, v)
    bary = _uv_barycentrics(tuv, u, v)  # (m, k, 3)
    on_tri = np.all(bary >= -1e-6, axis=-1)  # NaN (degenerate UVs) is not
    bary = np.clip(bary, 0.0, None)
    bary /= np.where(on_tri, bary.sum(axis=-1), 1.0)[..., None]
    corners = np.asarray(mesh.points, np.float64)[np.asarray(mesh.triangles, np.int64)[tri]]
    q = np.einsum("mkc,mci->mki", np.nan_to_num(bary), corners)  # (m, k, 3)
    pc, gc, sc, lc = p[cand], g[cand], scales[cand], low[cand]
    free = _rim_uncovered(pc, gc, sc, lc, q.reshape(len(cand), k, 3), tracer) & on_tri
    has = free.any(axis=1)
    if not has.any():
        return texels, moved
    rows = np.nonzero(has)[0]
    fq, ff = q[rows], free[rows]
    dist = np.where(ff, np.linalg.norm(fq - pc[rows, None, :], axis=-1), np.inf)
    c0 = fq[np.arange(len(rows)), np.argmin(dist, axis=1)]
    c1 = (fq * ff[..., None]).sum(axis=1) / ff.sum(axis=1)[:, None]
    new = c0 + RIM_INSET * (c1 - c0)
    good = _rim_uncovered(pc[rows], gc[rows], sc[rows], lc[rows], new[:, None, :], tracer)[:, 0]
    new = np.where(good[:, None], new, c0)
    position = texels.position.copy()
    position[cand[rows]] = new.astype(np.float32)
    moved[cand[rows]] = True
    return replace(texels, position=position), moved


def _rim_uncovered(p, g, scales, low, q, tracer) -> np.ndarray:
    """(m, k) bool: candidate points q (m, k, 3) on the planes of points p (m, 3) (normals g,
    ray offsets scales, cover heights low) whose normal ray meets nothing within ``low`` and
    whose ray origin the way along the surface from p's origin reaches without meeting a
    surface that faces it (a back face, the way out of a solid, does not block)."""
    m, k = q.shape[:2]
    gk = np.repeat(g, k, axis=0)
    sk = np.repeat(scales, k)
    oq = tracer.offset(q.reshape(-1, 3), gk, gk, sk)
    over = tracer.intersect(oq, gk, np.repeat(low, k))["tri"] >= 0
    o = np.repeat(tracer.offset(p, g, g, scales), k, axis=0)
    way = oq - o
    length = np.linalg.norm(way, axis=1)
    go = length > 0
    d = np.where(go[:, None], way / np.where(go, length, 1.0)[:, None], gk)
    hit = tracer.intersect(o, d, np.where(go, length, 0.0))
    tri = hit["tri"]
    hn = tracer.geom_normal[np.maximum(tri, 0)].astype(np.float64)
    # a surface facing the way blocks it (a wall between); a back face is the way out of a
    # solid the origin lies in (the contact rule's case), which leads to the open side
    blocked = go & (tri >= 0) & ~tracer.back_face(tri, d, hn)
    return (~over & ~blocked).reshape(m, k)
