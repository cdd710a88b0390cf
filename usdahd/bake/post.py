"""Image-quality post-processing of baked lightmaps: gutter dilation, invalid-texel filling and
seam stitching. numpy only.

Data layouts (see ``docs/texels.md``):

- *Per-texel arrays* ``values (n, ...)`` are aligned with a :class:`~usdahd.bake.types.Texels`
  (row ``i`` belongs to texel ``texels.xy[i]``); radiance SH is ``(n, 3, 9)`` in the texel's
  tangent frame. :func:`fill_invalid` and :func:`stitch` work on these, before fitting.
- *Images* ``(h, w, c)`` with row 0 at the top (``usdahd.bake.types``); :func:`to_image` /
  :func:`from_image` convert, :func:`dilate` pads the gutter of encoded textures.
- *Several meshes* are a list of per-texel arrays plus the matching list of Texels; a
  :class:`Seams` refers to texels as (mesh index, texel x, y), so seams can join different
  meshes' arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from usdahd.bake.types import Texels
from usdahd.errors import InputError, UsageError
from usdahd.numerics import sh as shmod
from usdahd.numerics.raster import uv_to_pixel
from usdahd.scene.types import MeshData

__all__ = [
    "coverage_mask",
    "dilate",
    "fill_invalid",
    "find_seams",
    "from_image",
    "stitch",
    "to_image",
]

# 8-neighbourhood offsets (dx, dy)
_NEIGHBOURS = np.array(
    [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)], dtype=np.int64
)

#: Seam endpoints whose UVs differ by less than this (texels) are the same UV point (no seam).
SEAM_UV_EPS = 1e-3
#: Default maximum angle between the shading normals on the two sides of a seam; sharper
#: creases are real lighting discontinuities and are not stitched.
SEAM_MAX_NORMAL_ANGLE = 30.0
#: SH coefficients stitched in each texel's own tangent frame rather than in world space:
#: Y10 (I_z) and Y20, which a rotation about the normal leaves unchanged (see :func:`stitch`).
LOCAL_COEFFS = (2, 6)


# --------------------------------------------------------------------------------------------
# layouts


def _ids(texels: Texels) -> np.ndarray:
    w = texels.resolution[0]
    return texels.xy[:, 1].astype(np.int64) * w + texels.xy[:, 0]


def texel_index(texels: Texels, xy: np.ndarray) -> np.ndarray:
    """Row of each texel coordinate ``xy (..., 2)`` in ``texels`` (int64, -1 if uncovered or
    outside the image)."""
    w, h = texels.resolution
    xy = np.asarray(xy, dtype=np.int64)
    ids = _ids(texels)
    if len(ids) > 1 and not (ids[1:] > ids[:-1]).all():
        raise InputError("texels must be sorted row-major (as rasterize returns them)")
    x, y = xy[..., 0], xy[..., 1]
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    q = np.where(inside, y * w + x, -1)
    pos = np.clip(np.searchsorted(ids, q), 0, max(len(ids) - 1, 0))
    found = inside & (len(ids) > 0) & (ids[pos] == q if len(ids) else False)
    return np.where(found, pos, -1)


def coverage_mask(texels: Texels) -> np.ndarray:
    """(h, w) bool: True on covered texels."""
    w, h = texels.resolution
    mask = np.zeros((h, w), dtype=bool)
    mask[texels.xy[:, 1], texels.xy[:, 0]] = True
    return mask


def to_image(texels: Texels, values: np.ndarray, fill=0) -> np.ndarray:
    """Scatter per-texel ``values (n, ...)`` into an image ``(h, w, ...)`` (``fill`` elsewhere)."""
    w, h = texels.resolution
    values = np.asarray(values)
    if len(values) != len(texels):
        raise InputError(f"{len(values)} values for {len(texels)} texels")
    image = np.full((h, w, *values.shape[1:]), fill, dtype=values.dtype)
    image[texels.xy[:, 1], texels.xy[:, 0]] = values
    return image


def from_image(texels: Texels, image: np.ndarray) -> np.ndarray:
    """Gather per-texel values ``(n, ...)`` from an image ``(h, w, ...)``."""
    return np.asarray(image)[texels.xy[:, 1], texels.xy[:, 0]]


# --------------------------------------------------------------------------------------------
# dilation


def dilate(
    image: np.ndarray,
    mask: np.ndarray,
    width: int | None = 2,
    *,
    labels: np.ndarray | None = None,
    return_mask: bool = False,
):
    """Fill texels outside ``mask`` from valid neighbours, ``width`` rings deep.

    image : (h, w) or (h, w, c), any numeric dtype (averaged in float64, cast back; integer
        images are rounded). mask : (h, w) bool, True where the image is valid.
    width : rings to grow (None: until nothing more can be reached).
    labels : optional (h, w) int; a texel is filled only from neighbours with the same label
        (fill inside charts). Valid texels are never changed.

    Each ring sets every invalid texel that has at least one valid 8-neighbour to the mean of
    those neighbours, then marks it valid, so bilinear filtering and mip-maps near chart borders
    read data, never empty texels. Returns the image (and the grown mask if ``return_mask``).
    """
    image = np.asarray(image)
    mask = np.asarray(mask, dtype=bool)
    squeeze = image.ndim == 2
    img = image[..., None] if squeeze else image
    h, w = mask.shape
    if img.shape[:2] != (h, w):
        raise InputError(f"image {image.shape[:2]} and mask {mask.shape} sizes differ")
    if width is not None and width < 0:
        raise UsageError(f"dilation width must be >= 0, got {width}")
    out = img.astype(np.float64, copy=True)
    valid = mask.copy()
    if labels is not None:
        labels = np.asarray(labels)
    rings = 0
    while width is None or rings < width:
        cand = np.zeros((h, w), dtype=bool)
        pad = np.pad(valid, 1)
        for dx, dy in _NEIGHBOURS:
            cand |= pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
        cand &= ~valid
        ys, xs = np.nonzero(cand)
        if len(ys) == 0:
            break
        acc = np.zeros((len(ys), out.shape[2]))
        cnt = np.zeros(len(ys))
        for dx, dy in _NEIGHBOURS:
            ny, nx = ys + dy, xs + dx
            ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
            ny, nx = np.where(ok, ny, 0), np.where(ok, nx, 0)
            ok &= valid[ny, nx]
            if labels is not None:
                ok &= labels[ny, nx] == labels[ys, xs]
            acc += np.where(ok[:, None], out[ny, nx], 0.0)
            cnt += ok
        got = cnt > 0
        if not got.any():
            break
        out[ys[got], xs[got]] = acc[got] / cnt[got, None]
        valid[ys[got], xs[got]] = True
        rings += 1
    if np.issubdtype(img.dtype, np.integer):
        info = np.iinfo(img.dtype)
        out = np.clip(np.rint(out), info.min, info.max)
    result = out.astype(img.dtype)
    result = result[..., 0] if squeeze else result
    return (result, valid) if return_mask else result


# --------------------------------------------------------------------------------------------
# invalid (inside-geometry) texels


def _neighbour_table(texels: Texels) -> np.ndarray:
    """(n, 8) row of each texel's 8-neighbours in ``texels`` (-1 if not covered)."""
    nb = texels.xy[:, None, :].astype(np.int64) + _NEIGHBOURS[None]
    return texel_index(texels, nb)


def fill_invalid(
    values: np.ndarray,
    texels: Texels,
    invalid: np.ndarray,
    *,
    charts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Replace invalid texels (e.g. inside geometry) by values grown from valid neighbours.

    values : (n, ...) per-texel array (e.g. SH (n, 3, 9)); invalid : (n,) bool.
    charts : (n,) chart id per texel (``chart_ids(mesh)[texels.triangle]``): texels are filled
        from valid neighbours of the same chart first (so light never leaks across a chart
        border); what a chart cannot fill (no valid texel in it) is then filled from any
        neighbour. Growth is ring by ring through covered texels (mean of the filled
        8-neighbours, as :func:`dilate`). Returns (values, unfilled (n,) bool): texels no valid
        texel reaches keep their value and are flagged.
    """
    values = np.asarray(values)
    invalid = np.asarray(invalid, dtype=bool)
    n = len(texels)
    if len(values) != n or invalid.shape != (n,):
        raise InputError(f"values {values.shape} / invalid {invalid.shape} vs {n} texels")
    flat = values.reshape(n, -1).astype(np.float64)
    nb = _neighbour_table(texels)
    valid = ~invalid
    passes = [charts, None] if charts is not None else [None]
    for chart in passes:
        while True:
            todo = np.nonzero(~valid)[0]
            if len(todo) == 0:
                break
            idx = nb[todo]
            ok = idx >= 0
            safe = np.where(ok, idx, 0)
            ok &= valid[safe]
            if chart is not None:
                ok &= chart[safe] == chart[todo][:, None]
            cnt = ok.sum(axis=1)
            got = cnt > 0
            if not got.any():
                break
            acc = np.einsum("kj,kjc->kc", ok[got].astype(np.float64), flat[safe[got]])
            flat[todo[got]] = acc / cnt[got, None]
            valid[todo[got]] = True
    out = flat.reshape(values.shape).astype(values.dtype, copy=False)
    return out, ~valid


# --------------------------------------------------------------------------------------------
# SH frame rotation


def _sh_quadratic_forms() -> tuple[np.ndarray, np.ndarray]:
    """Band 1 and 2 of the real SH basis as forms in the direction d: Y_k(d) = a_k . d for
    k = 1..3 (rows of the (3, 3) array), Y_k(d) = d^T A_k d for k = 4..8 ((5, 3, 3) traceless
    symmetric matrices, so Y20 = C20 (3 z^2 - 1) = C20 (2 z^2 - x^2 - y^2) on the sphere)."""
    a = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]) * shmod.C1
    q = np.zeros((5, 3, 3))
    q[0, 0, 1] = q[0, 1, 0] = 0.5 * shmod.C2  # C2 x y
    q[1, 1, 2] = q[1, 2, 1] = -0.5 * shmod.C2  # -C2 y z
    q[2] = np.diag([-1.0, -1.0, 2.0]) * shmod.C20  # C20 (3 z^2 - 1)
    q[3, 0, 2] = q[3, 2, 0] = -0.5 * shmod.C2  # -C2 x z
    q[4] = np.diag([1.0, -1.0, 0.0]) * shmod.C22  # C22 (x^2 - y^2)
    return a, q


_FORMS = _sh_quadratic_forms()


def sh_frame_matrices(frames: np.ndarray) -> np.ndarray:
    """(n, 9, 9) matrices M taking tangent-space SH to world space: ``c_world = M @ c_local``.

    frames : (n, 3, 3) rows t, b, n (``local = frame @ world``), any orthonormal frame
    (mirrored ones too). f_world(d) = f_local(frame d); M is orthogonal, so ``M.T`` maps back.
    Exact, in closed form: band 0 is invariant; band 1 is a linear form a_k . d, so
    Y_k(F d) = (F^T a_k) . d and M_jk = a_j . F^T a_k / |a_j|^2; band 2 is a quadratic form
    d^T A_k d with traceless symmetric A_k, which the SH basis spans orthogonally under the
    Frobenius product, so M_jk = <A_j, F^T A_k F> / <A_j, A_j> (trace F^T A F = trace A = 0
    for any orthonormal F, mirrored or not). Equal to a least-squares projection on sampled
    directions up to rounding (tests/test_post.py), at a fraction of its cost.
    """
    a, q = _FORMS
    f = np.asarray(frames, dtype=np.float64)
    n = len(f)
    m = np.zeros((n, 9, 9))
    m[:, 0, 0] = 1.0
    # M1_jk = a_j^T F^T a_k / |a_j|^2 = sum_ab F_ba a_j[a] a_k[b] / C1^2: one (n, 9) x (9, 9)
    w1 = np.einsum("ja,kb->bajk", a, a).reshape(9, 9) / shmod.C1**2
    m[:, 1:4, 1:4] = (f.reshape(n, 9) @ w1).reshape(n, 3, 3)
    # M2_jk = sum A_j[i, l] F_ai F_bl A_k[a, b] / |A_j|^2 with K[(a, b), (i, l)] = F_ai F_bl
    q9 = q.reshape(5, 9)
    k = (f[:, :, None, :, None] * f[:, None, :, None, :]).reshape(n * 9, 9)
    x = (k @ q9.T).reshape(n, 9, 5).transpose(0, 2, 1).reshape(n * 5, 9)  # [n, j, (a, b)]
    norm = np.einsum("ja,ja->j", q9, q9)
    m[:, 4:, 4:] = (x @ q9.T).reshape(n, 5, 5) / norm[None, :, None]
    return m


# --------------------------------------------------------------------------------------------
# seams


@dataclass
class Seams:
    """Seam samples: bilinear lookups on side A and side B that should agree.

    mesh : (s, 2) int32 mesh index (into the lists given to find_seams) of side A and B.
    taps : (s, 2, 4, 2) int32 texel (x, y) of the 4 bilinear taps per side.
    weights : (s, 2, 4) float64 bilinear weights (0 for taps outside the image).
    position : (s, 3) float64 world position of the sample (on the shared 3-D edge).
    resolutions : resolution (w, h) of each mesh's lightmap.
    edges : number of seam edges found.
    """

    mesh: np.ndarray
    taps: np.ndarray
    weights: np.ndarray
    position: np.ndarray
    resolutions: list
    edges: int = 0

    def __len__(self) -> int:
        return int(len(self.mesh))


def _bilinear_taps(p: np.ndarray, res) -> tuple[np.ndarray, np.ndarray]:
    """Taps (m, 4, 2) and weights (m, 4) of bilinear lookups at pixel coords p (m, 2)."""
    w, h = res
    q = p - 0.5
    x0 = np.floor(q[:, 0]).astype(np.int64)
    y0 = np.floor(q[:, 1]).astype(np.int64)
    fx = q[:, 0] - x0
    fy = q[:, 1] - y0
    taps = np.stack(
        [np.stack([x0, y0], 1), np.stack([x0 + 1, y0], 1), np.stack([x0, y0 + 1], 1),
         np.stack([x0 + 1, y0 + 1], 1)],
        axis=1,
    )  # fmt: skip
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    inside = (taps[..., 0] >= 0) & (taps[..., 0] < w) & (taps[..., 1] >= 0) & (taps[..., 1] < h)
    return np.where(inside[..., None], taps, 0), np.where(inside, wts, 0.0)


def _weld(keys: np.ndarray) -> np.ndarray:
    """Index of each row of ``keys (n, 3)`` int64 among the distinct rows in lexicographic
    order (what ``np.unique(keys, axis=0, return_inverse=True)`` returns, by one lexsort)."""
    if len(keys) == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
    k = keys[order]
    new = np.ones(len(k), bool)
    new[1:] = (k[1:] != k[:-1]).any(axis=1)
    out = np.empty(len(k), np.int64)
    out[order] = np.cumsum(new) - 1
    return out


def find_seams(
    meshes: MeshData | list[MeshData],
    resolutions,
    *,
    samples_per_texel: float = 2.0,
    max_normal_angle: float = SEAM_MAX_NORMAL_ANGLE,
    weld_tolerance: float | None = None,
) -> Seams:
    """Find UV seams: 3-D edges shared by two triangles whose lightmap UVs differ there (within
    one mesh, or between meshes: pass a list; positions are welded within ``weld_tolerance``,
    default 1e-6 of the scene's bounding-box diagonal).

    Edges whose shading normals differ by more than ``max_normal_angle`` degrees at either
    endpoint (hard creases, walls meeting floors) are skipped. Each seam edge is sampled
    ``samples_per_texel`` times per texel of its longer UV side; each sample gives a pair of
    bilinear lookups (side A, side B) at the same 3-D point.
    """
    if isinstance(meshes, MeshData):
        meshes = [meshes]
        resolutions = [resolutions]
    meshes = list(meshes)
    resolutions = [tuple(int(r) for r in res) for res in resolutions]
    if len(meshes) != len(resolutions):
        raise UsageError(f"{len(meshes)} meshes but {len(resolutions)} resolutions")
    for m in meshes:
        if m.uv is None:
            raise InputError(f"{m.path}: mesh has no lightmap UV set {m.uv_name!r}")
    if not meshes:
        return _empty_seams(resolutions)

    all_pts = np.concatenate([np.asarray(m.points, np.float64) for m in meshes])
    diag = float(np.linalg.norm(all_pts.max(0) - all_pts.min(0))) if len(all_pts) else 1.0
    tol = weld_tolerance if weld_tolerance is not None else 1e-6 * max(diag, 1e-30)
    welded = _weld(np.round(all_pts / tol).astype(np.int64))
    offsets = np.cumsum([0] + [len(m.points) for m in meshes])

    # Half-edges, mesh by mesh, corner i -> i + 1 of every triangle (corner-major): the order
    # fixes which two half-edges pair up on an edge shared by more than two triangles.
    tri_off = np.cumsum([0] + [len(m.triangles) for m in meshes])
    tri_mesh = np.repeat(np.arange(len(meshes)), np.diff(tri_off))
    wtri = np.concatenate(
        [welded[offsets[mi] + np.asarray(m.triangles, np.int64)] for mi, m in enumerate(meshes)]
    ).reshape(-1, 3)
    corner = np.concatenate(
        [np.repeat(np.arange(3), n) for n in np.diff(tri_off)]
    )  # corner i of each half-edge
    tri = np.concatenate(
        [np.tile(np.arange(lo, hi), 3) for lo, hi in zip(tri_off[:-1], tri_off[1:], strict=True)]
    )
    a_ = wtri[tri, corner]
    b_ = wtri[tri, (corner + 1) % 3]
    keep = np.nonzero(a_ != b_)[0]
    tri, corner, a_, b_ = tri[keep], corner[keep], a_[keep], b_[keep]
    lo, hi = np.minimum(a_, b_), np.maximum(a_, b_)
    # one int64 key per 3-D edge; a stable sort keeps equal edges in half-edge order
    order = np.argsort(lo * (int(welded.max(initial=0)) + 1) + hi, kind="stable")
    tri, corner, lo, hi, swap = tri[order], corner[order], lo[order], hi[order], (a_ > b_)[order]
    same_edge = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    i0 = np.nonzero(same_edge)[0]  # pairs (i0, i0 + 1) of half-edges of one 3-D edge
    i1 = i0 + 1
    # per-corner attributes, gathered for the paired half-edges only; endpoint "a" is the
    # lower welded vertex of the edge (the two half-edges run in opposite directions)
    px = np.concatenate([uv_to_pixel(m.uv, resolutions[mi]) for mi, m in enumerate(meshes)])
    nrm = np.concatenate([np.asarray(m.normals, np.float64) for m in meshes])
    pts = np.concatenate([np.asarray(m.points, np.float64)[m.triangles] for m in meshes])

    def ends(h):
        t, c = tri[h], corner[h]
        ca = np.where(swap[h], (c + 1) % 3, c)
        cb = np.where(swap[h], c, (c + 1) % 3)
        return t, ca, cb

    (t0_, a0, b0), (t1_, a1, b1) = ends(i0), ends(i1)

    def unit(v):
        return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)

    differs = tri_mesh[t0_] != tri_mesh[t1_]
    uv_gap = np.maximum(
        np.linalg.norm(px[t0_, a0] - px[t1_, a1], axis=1),
        np.linalg.norm(px[t0_, b0] - px[t1_, b1], axis=1),
    )
    differs |= uv_gap > SEAM_UV_EPS
    cos_max = np.cos(np.radians(max_normal_angle))
    smooth = (np.einsum("ki,ki->k", unit(nrm[t0_, a0]), unit(nrm[t1_, a1])) >= cos_max) & (
        np.einsum("ki,ki->k", unit(nrm[t0_, b0]), unit(nrm[t1_, b1])) >= cos_max
    )
    sel = np.nonzero(differs & smooth)[0]
    if len(sel) == 0:
        return _empty_seams(resolutions)
    t0_, a0, b0, t1_, a1, b1 = (v[sel] for v in (t0_, a0, b0, t1_, a1, b1))
    he = {
        "mesh": np.concatenate([tri_mesh[t0_], tri_mesh[t1_]]),
        "pa": np.concatenate([px[t0_, a0], px[t1_, a1]]),
        "pb": np.concatenate([px[t0_, b0], px[t1_, b1]]),
        "p3a": pts[t0_, a0],
        "p3b": pts[t0_, b0],
    }
    i0 = np.arange(len(sel))
    i1 = i0 + len(sel)
    len_a = np.linalg.norm(he["pb"][i0] - he["pa"][i0], axis=1)
    len_b = np.linalg.norm(he["pb"][i1] - he["pa"][i1], axis=1)
    count = np.maximum(1, np.ceil(samples_per_texel * np.maximum(len_a, len_b))).astype(np.int64)
    edge = np.repeat(np.arange(len(i0)), count)
    start = np.cumsum(count) - count
    s = (np.arange(len(edge)) - start[edge] + 0.5) / count[edge]
    e0, e1 = i0[edge], i1[edge]
    taps = np.zeros((len(edge), 2, 4, 2), np.int64)
    wts = np.zeros((len(edge), 2, 4))
    mesh_ids = np.stack([he["mesh"][e0], he["mesh"][e1]], axis=1)
    for side, e in enumerate((e0, e1)):
        p = he["pa"][e] + s[:, None] * (he["pb"][e] - he["pa"][e])
        for mi in np.unique(mesh_ids[:, side]):
            rows = mesh_ids[:, side] == mi
            t_, w_ = _bilinear_taps(p[rows], resolutions[mi])
            taps[rows, side] = t_
            wts[rows, side] = w_
    position = he["p3a"][e0] + s[:, None] * (he["p3b"][e0] - he["p3a"][e0])
    return Seams(
        mesh=mesh_ids.astype(np.int32),
        taps=taps.astype(np.int32),
        weights=wts,
        position=position,
        resolutions=resolutions,
        edges=int(len(i0)),
    )


def _empty_seams(resolutions) -> Seams:
    return Seams(
        mesh=np.zeros((0, 2), np.int32),
        taps=np.zeros((0, 2, 4, 2), np.int32),
        weights=np.zeros((0, 2, 4)),
        position=np.zeros((0, 3)),
        resolutions=list(resolutions),
    )


def _as_lists(values, texels):
    single = isinstance(texels, Texels)
    if single:
        return [np.asarray(values)], [texels], True
    return [np.asarray(v) for v in values], list(texels), False


def _seam_system(vals, txs, seams: Seams):
    """Unknown rows (global), per-sample columns (s, 8) into the unknowns and signed weights."""
    if len(txs) != len(seams.resolutions):
        raise InputError(f"{len(txs)} texel sets but the seams were found for "
                         f"{len(seams.resolutions)} meshes")  # fmt: skip
    for t, res in zip(txs, seams.resolutions):
        if tuple(t.resolution) != tuple(res):
            raise InputError(f"texels at {t.resolution} but seams found at {res}")
    offsets = np.cumsum([0] + [len(t) for t in txs])
    cols = np.full((len(seams), 2, 4), -1, np.int64)
    for side in range(2):
        for mi in np.unique(seams.mesh[:, side]) if len(seams) else []:
            rows = seams.mesh[:, side] == mi
            idx = texel_index(txs[mi], seams.taps[rows, side])
            cols[rows, side] = np.where(idx >= 0, idx + offsets[mi], -1)
    wts = np.where(cols >= 0, seams.weights, 0.0)
    tot = wts.sum(axis=2)
    good = (tot > 1e-6).all(axis=1)
    wts = wts[good] / tot[good][..., None]  # taps on uncovered texels: renormalize over the rest
    cols = cols[good]
    signed = np.concatenate([wts[:, 0], -wts[:, 1]], axis=1)  # (s, 8)
    cols = cols.reshape(len(cols), 8)
    signed = np.where(cols >= 0, signed, 0.0)
    return cols, signed, offsets


def _gather_world(vals, txs, rows, offsets, rotate):
    """Flattened (m, k) values of global texel rows, SH rotated to world space if asked."""
    mesh_of = np.searchsorted(offsets, rows, side="right") - 1
    local = rows - offsets[mesh_of]
    shape = vals[0].shape[1:]
    out = np.zeros((len(rows), int(np.prod(shape))))
    mats = np.zeros((len(rows), 9, 9)) if rotate else None
    for mi in np.unique(mesh_of):
        sel = mesh_of == mi
        v = vals[mi][local[sel]].astype(np.float64)
        if rotate:
            m = sh_frame_matrices(txs[mi].frame[local[sel]])
            mats[sel] = m
            v = np.einsum("nab,ncb->nca", m, v)
        out[sel] = v.reshape(len(v), -1)
    return out, mats, mesh_of, local


def seam_mismatch(values, texels, seams: Seams, *, rotate: bool | None = None) -> np.ndarray:
    """Per-sample difference (s, k) between the bilinear lookups on the two sides of each seam
    sample (in world space for SH when ``rotate``); samples with no covered taps are dropped."""
    vals, txs, _ = _as_lists(values, texels)
    rotate = _auto_rotate(vals, rotate)
    cols, signed, offsets = _seam_system(vals, txs, seams)
    rows, inv = np.unique(np.where(cols >= 0, cols, cols.max(initial=0)), return_inverse=True)
    x, *_ = _gather_world(vals, txs, rows, offsets, rotate)
    return np.einsum("sj,sjk->sk", signed, x[inv.reshape(cols.shape)])


def _auto_rotate(vals, rotate):
    is_sh = all(v.ndim == 3 and v.shape[1:] == (3, 9) for v in vals)
    if rotate is None:
        return is_sh
    if rotate and not is_sh:
        raise InputError("rotate=True needs SH values of shape (n, 3, 9)")
    return rotate


def stitch(
    values,
    texels,
    seams: Seams,
    *,
    rotate: bool | None = None,
    data_weight: float = 0.01,
):
    """Make bilinear lookups agree across seams, changing texels as little as possible.

    values : per-texel array (n, ...) with ``texels`` a Texels, or lists of both (one per mesh,
        in the order given to :func:`find_seams`). Radiance SH (n, 3, 9) is rotated into world
        space with each texel's frame first (``rotate`` None = auto), since the two sides of a
        seam have different tangent frames; other arrays are stitched as they are.

    Solves, per channel, the least-squares problem of Castano's seam stitching (The Witness):
    minimize sum_samples (A_s x - B_s x)^2 + data_weight * sum_texels (x - x0)^2, where A_s, B_s
    are the bilinear lookups of a seam sample on its two sides (taps on uncovered texels are
    dropped and the rest renormalized, as dilation will fill them from the same texels).
    The normal equations (Q + data_weight I) x = data_weight x0 are solved exactly by one
    sparse Cholesky factorisation shared by every channel (:mod:`usdahd.numerics.cholesky`,
    nested-dissection order on the texels' 3-D positions): the work follows the number of
    texels under seam taps, not the number of channels times an iteration count.
    Only texels under a seam tap change. Returns arrays like ``values`` (new objects).

    With rotation, Y10 and Y20 (:data:`LOCAL_COEFFS`) are then solved again in each texel's
    own frame (the same factorisation) and replace the world-space result: a viewer
    interpolates the stored coefficients and evaluates them at the pixel's normal, so across a
    seam (where both sides share the normal, their tangents differ by a rotation about it)
    these two, invariant under that rotation, must agree as stored. In world space they agree
    only where the taps' normals do: on a curved surface sampled by small charts the decoded
    I_z stepped by ~3 % of its level across seams (``python -m benchmarks.seams step``).
    """
    vals, txs, single = _as_lists(values, texels)
    rotate = _auto_rotate(vals, rotate)
    if data_weight <= 0:
        raise UsageError(f"stitch data_weight must be positive, got {data_weight}")
    out = [v.copy() for v in vals]
    cols, signed, offsets = _seam_system(vals, txs, seams)
    if len(cols) == 0:
        return out[0] if single else out
    from usdahd.numerics import cholesky  # numba kernels: loaded only when there are seams

    flat_cols = cols.ravel()
    rows, inv = np.unique(flat_cols[flat_cols >= 0], return_inverse=True)
    lc = np.full(flat_cols.shape, -1, np.int64)
    lc[flat_cols >= 0] = inv
    lc = lc.reshape(cols.shape)
    x0, mats, mesh_of, local = _gather_world(vals, txs, rows, offsets, rotate)
    m = len(rows)
    # normal matrix Q = sum_s c_s c_s^T as sorted COO (row-major: CSR), plus data_weight I
    ok = lc >= 0
    pair = ok[:, :, None] & ok[:, None, :]
    ii = np.repeat(lc[:, :, None], 8, axis=2)[pair]
    jj = np.repeat(lc[:, None, :], 8, axis=1)[pair]
    vv = (signed[:, :, None] * signed[:, None, :])[pair]
    diag_keys = np.arange(m, dtype=np.int64) * (m + 1)
    key, kinv = np.unique(np.concatenate([ii * m + jj, diag_keys]), return_inverse=True)
    qv = np.bincount(
        kinv.ravel(), weights=np.concatenate([vv, np.full(m, data_weight)]), minlength=len(key)
    )
    qi, qj = key // m, key % m
    indptr = np.searchsorted(qi, np.arange(m + 1))
    position = np.zeros((m, 3))
    for mi in np.unique(mesh_of):
        sel = mesh_of == mi
        position[sel] = txs[mi].position[local[sel]]
    perm = cholesky.nested_dissection(position, indptr, qj)
    solver = cholesky.factor(indptr, qj, qv, perm)
    x = solver.solve(data_weight * x0)
    if rotate:  # I_z and c20 as the viewer interpolates them: in each texel's own frame
        inv = (np.arange(3)[:, None] * 9 + np.array(LOCAL_COEFFS)[None]).ravel()
        x0_local = _gather_world(vals, txs, rows, offsets, False)[0][:, inv]
        x_local = solver.solve(data_weight * x0_local)

    for mi in np.unique(mesh_of):
        sel = mesh_of == mi
        v = x[sel].reshape(-1, *vals[mi].shape[1:])
        if rotate:
            v = np.einsum("nba,ncb->nca", mats[sel], v)  # M^T: world -> tangent
            v[:, :, LOCAL_COEFFS] = x_local[sel].reshape(-1, 3, len(LOCAL_COEFFS))
        out[mi][local[sel]] = v.astype(out[mi].dtype)
    return out[0] if single else out
