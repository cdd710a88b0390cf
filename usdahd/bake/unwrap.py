"""Lightmap UV unwrapping with xatlas for meshes that have no lightmap UV set.

xatlas's requested atlas resolution is a target, not a cap (facts.md): we always set
``texels_per_unit`` ourselves, leave xatlas's resolution at 0 (one atlas, never several pages),
and check the size that comes back.

UV convention: xatlas's pixel y axis points down the image; our rows also count down from the
top (``usdahd.bake.types``), so ``v = 1 - y / height``. With this flip xatlas charts come out
counter-clockwise in UV (not mirrored), so tangent frames are right-handed.

Polygons stay whole (issue 37): the UVs are authored as a faceVarying primvar, one UV per
polygon corner, but xatlas charts triangles and cuts quads and n-gons between charts. Pass 1
(:func:`_chart_pass`) lets xatlas chart and parameterise the triangles, then lays every polygon
it cut out again inside one chart; pass 2 (:func:`_run_pack`) has xatlas pack those charts as
a UV mesh. The result gives every polygon corner one UV (``unrepresentable_corners`` is 0), so
the layer holds exactly the UVs the bake traced with. docs/texels.md has the why and the
figures.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake import unwrap_worker
from usdahd.bake.texels import MAX_RESOLUTION
from usdahd.bake.unwrap_worker import stop_worker
from usdahd.errors import BakeError, InputError, UsageError
from usdahd.numerics.charts import (
    ChartRects,
    destretch,
    extend_into,
    layout,
    overlaps,
    project_polygon,
    self_overlap,
    split_polygons,
    split_rings,
    unfold_polygon,
    widen_thin,
)
from usdahd.numerics.triangles import triangle_areas
from usdahd.scene.types import MeshData

__all__ = [
    "CHART_MIN_WIDTH",
    "CHART_PADDING",
    "PACK_EFFICIENCY",
    "pack_part",
    "stop_worker",
    "unwrap",
]

#: Attempts at shrinking texels_per_unit until the atlas fits a requested resolution.
MAX_ATTEMPTS = 8
#: Rough packing efficiency of xatlas charts (atlas area / chart area), used only for the first
#: guess of texels_per_unit and the early size check; the real size is always measured.
PACK_EFFICIENCY = 0.6
#: Wall-clock limit of one isolated xatlas run, seconds: a fixed allowance (interpreter start-up,
#: imports) plus a per-triangle one. Far above xatlas's real cost (the 82k-triangle icosphere
#: unwraps in seconds); it only turns a wedged native child into an error instead of a bake
#: (and a CI job) that never ends.
UNWRAP_TIMEOUT_S = 300.0
UNWRAP_TIMEOUT_PER_TRIANGLE_S = 2e-3


def _world_area(points: np.ndarray, triangles: np.ndarray) -> float:
    """Total area of the triangles (t, 3) int of ``points`` (n, 3) float64."""
    return float(triangle_areas(points[triangles]).sum())


#: Pass 1 scales the mesh so its bounding-box diagonal is this long: xatlas's epsilons are
#: absolute (its area epsilon is FLT_EPSILON), so a mesh as authored loses its small
#: triangles: xatlas put 7,301 of the 92,416 triangles of OpenChessSet's chessboard (metres)
#: in no chart (they got no texel), and produced no atlas at all for a 0.1 mm-wide mesh.
NORMALIZED_DIAGONAL = 100.0
#: Side (texels) pass 1 packs its charts into: only their shapes are kept, so it only needs to
#: be large enough that xatlas's rounding of each chart to whole texels stays small (it is
#: undone, see destretch) and small enough to pack quickly.
CHART_PASS_SIDE = 1024
#: Pass 2 packs at this fraction of the asked density: xatlas rounds every chart's extent up
#: to whole texels (stretching it), and a chart exactly n texels wide must not become n + 1
#: through float rounding.
SHRINK = 1.0 - 1e-5
#: Pass 2 places charts with xatlas's brute-force search (every position, the one that keeps
#: the atlas smallest) instead of its random candidate positions: measured with the automatic
#: density (``usdahd bake STAGE --dry-run``, covered texels / map texels over every unwrapped
#: map), classroom 54.6 % -> 58.9 %, Sponza 43.3 % -> 46.6 %, at no measurable cost in time
#: (docs/scenes.md, "Atlas pages"). Deterministic like the default search.
PACK_BRUTE_FORCE = True
#: xatlas bilinear ring (see CHART_PADDING).
PACK_BILINEAR = True
#: Texels of padding around each chart (``xatlas.PackOptions.padding``), on top of xatlas's
#: bilinear ring (``bilinear=True``: every texel a bilinear tap inside a chart reads is that
#: chart's own). xatlas dilates each chart's bilinear footprint by the padding and packs the
#: dilated images disjoint, so two charts' footprints are at least 2 x padding texels apart:
#: 1 leaves 2 free texels between them (each chart dilates into its own), 2 left 4. Measured
#: with the automatic density (covered / map texels over every map), classroom 58.9 % ->
#: 74.9 %, Sponza 46.6 % -> 56.6 % (docs/scenes.md, "Atlas pages"): at 3-8 texels per metre
#: most charts are a few texels wide and the padding was most of their maps.
CHART_PADDING = 1
#: A chart is a ring (:func:`split_rings`) when it covers less than a fraction of its
#: smallest bounding rectangle: the frame of a window, an arch's moulding, a walkway around a
#: courtyard. xatlas packs such a chart as one piece and rarely fills its hole with the map's
#: other charts (Sponza's ``object23_lib_0``: 40 frames, 18.6 % of its 275x279 map covered;
#: cut into their sides, 51 % of 190x168). Pass 2 packs the mesh with the rings of each
#: fraction here cut and with none, and keeps the smallest map (:func:`_pack`): cutting is
#: not always smaller (the classroom's maps grew 7 % with every ring cut), and the fractions
#: differ per mesh (Sponza's walls pack smallest at 0.5, its floors at 0.8).
RING_SOLIDITY = (0.5, 0.8)
#: xatlas ChartOptions pass 1 is run with (at a texel density), the smallest map wins.
CHART_OPTIONS: tuple[dict, ...] = ({},)
#: Texels across (the short side of its smallest bounding rectangle) that every chart of an
#: unwrap at a texel density gets at least (:func:`usdahd.numerics.charts.widen_thin`):
#: narrower charts are stretched across, so a sliver (a moulding's face under a texel wide at
#: a level's 3-8 texels per metre) covers texels of its own instead of sharing one or two rows
#: with its gutter ring. ``unwrap(min_chart_width=...)`` asks for one floor.
CHART_MIN_WIDTH = 2.0
#: The floors an unwrap at a texel density tries by default (:func:`_pack` keeps the best
#: layout by :data:`FILL_WEIGHT`).
CHART_MIN_WIDTHS = (CHART_MIN_WIDTH, 4.0)
#: Pass 1 runs with each of these xatlas ChartOptions (at a texel density): the default, and
#: one that grows charts further across creases (the slivers of Sponza's mouldings and vault
#: ribs join their neighbours: ``object32_lib_0`` 160x180 -> 108x112 texels).
CHART_OPTIONS: tuple[dict, ...] = ({}, {"max_cost": 8.0, "normal_deviation_weight": 1.0})
#: At a texel density the layout kept (chart options x rings cut x width floors) is the one
#: with the most covered texels less FILL_WEIGHT x its map texels: a layout's extra map
#: texels must each bring FILL_WEIGHT covered texels or more (an atlas page's fill = covered
#: texels / page texels; docs/scenes.md, "Atlas pages").
FILL_WEIGHT = 0.7
#: A candidate layout whose texel density spreads more than this (:func:`_spread`, the
#: measure of ``usdahd validate``'s ``TexelDensity`` warning, which warns above 4) is not
#: kept while one within it is (else the least spread): stretched slivers and merged charts
#: must not make a map that validate warns about (Sponza's ``object27_lib_0`` and
#: ``object28_lib_0`` reached 4.5 and 4.0 without this check).
DENSITY_SPREAD_MAX = 3.5


def _chart_pass(points, triangles, corner, face, path, chart_options=None):
    """Pass 1: xatlas cuts the mesh into charts and parameterises them; every polygon that
    xatlas cut through (its triangles in two charts) is made whole again, in the chart that
    holds most of its area when it fits there without overlap, else as a chart of its own.

    Returns (uv (t, 3, 2) float64 in pass-1 texels, labels (t,) int64 chart of each triangle,
    scale: pass-1 texels per world unit, stats dict)."""
    import xatlas

    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    k = NORMALIZED_DIAGONAL / max(float(np.linalg.norm(hi - lo)), 1e-30)
    q = np.ascontiguousarray((p - lo) * k, dtype=np.float32)
    tpu = CHART_PASS_SIDE * np.sqrt(PACK_EFFICIENCY / _world_area(q.astype(np.float64), triangles))
    atlas = unwrap_worker.new_atlas()
    atlas.add_mesh(q, triangles)
    pack = xatlas.PackOptions()
    pack.padding = 0
    pack.texels_per_unit = float(tpu)
    pack.resolution = 0
    pack.bruteForce = False
    options = xatlas.ChartOptions()
    for name, value in (chart_options or {}).items():
        setattr(options, name, value)
    atlas.generate(options, pack)
    if atlas.atlas_count != 1:
        raise BakeError(f"{path}: xatlas produced {atlas.atlas_count} atlases, expected 1")
    vmap, idx, uvs = atlas.get_mesh(0)
    idx = np.asarray(idx, dtype=np.int64)
    if idx.shape != triangles.shape or not np.array_equal(np.asarray(vmap)[idx], triangles):
        raise BakeError(f"{path}: xatlas changed the triangle list; cannot map UVs back")
    size = np.array([atlas.width, atlas.height], dtype=np.float64)
    uv = np.asarray(uvs, dtype=np.float64)[idx] * size
    vchart = np.asarray(atlas.get_mesh_vertex_assignment(0)[1], dtype=np.int64)
    vchart[vchart >= 2**31] = -1  # "in no chart" (uint32 -1)
    tchart = vchart[idx]
    labels = np.where(
        (tchart >= 0).all(axis=1) & (tchart == tchart[:, :1]).all(axis=1), tchart[:, 0], -1
    )
    uv = destretch(uv, labels, q.astype(np.float64)[triangles], tpu)
    corner = np.asarray(corner, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    key = np.concatenate(
        [np.repeat(labels[:, None, None], 3, axis=1).astype(np.float64), uv], axis=2
    )
    split = split_polygons(corner, face, key)
    split = np.union1d(split, np.unique(face[labels < 0]))
    stats = {
        "charts_xatlas": int(atlas.chart_count),
        "split_polygons": int(len(split)),
        "extended": 0,
        "own_chart": 0,
    }
    if len(split):
        order = np.argsort(face, kind="stable")
        starts = np.searchsorted(face[order], split)
        ends = np.searchsorted(face[order], split, side="right")
        world = 0.5 * np.linalg.norm(
            np.cross(
                p[triangles[:, 1]] - p[triangles[:, 0]], p[triangles[:, 2]] - p[triangles[:, 0]]
            ),
            axis=1,
        )
        next_label = int(labels.max()) + 1
        for s, e in zip(starts, ends):
            tris = order[s:e]
            laid = None
            charts = labels[tris]
            if (charts >= 0).any():
                ids = np.unique(charts[charts >= 0])
                weight = np.array([world[tris[charts == c]].sum() for c in ids])
                chart = int(ids[np.argmax(weight)])
                laid = extend_into(p, triangles, tris, corner, uv, labels, chart)
                if laid is not None:
                    moved = labels[tris] != chart
                    others = uv[labels == chart]
                    if self_overlap(laid) or any(overlaps(t, others) for t in laid[moved]):
                        laid = None
            if laid is not None:
                stats["extended"] += 1
            else:
                chart = next_label
                next_label += 1
                laid = unfold_polygon(p, triangles, tris, corner, k * tpu)
                if laid is None or self_overlap(laid):
                    flat = project_polygon(p, triangles[tris], k * tpu)
                    if laid is None or not self_overlap(flat):
                        laid = flat
                stats["own_chart"] += 1
            labels[tris] = chart
            uv[tris] = laid
    return uv, labels, k * tpu, stats


#: Pass 1 results kept (:func:`_charts`) for the meshes unwrapped last: the plan unwraps one
#: mesh again into a square or a minimum map (usdahd.pipeline.plan), from the same charts.
CHART_CACHE_SIZE = 4
_chart_cache: dict = {}


def _charts(points, triangles, corner, face, path, options):
    """Pass 1 with the xatlas ChartOptions ``options`` and the candidate labellings of its
    charts (as they are, and with the rings of each :data:`RING_SOLIDITY` cut, duplicates
    dropped): (uv1, labels, scale, stats, rects, candidates), ``rects`` the
    :class:`ChartRects` of uv1 shared by every candidate. Cached by the mesh's bytes and
    ``options`` (the last :data:`CHART_CACHE_SIZE`): pass 1 is deterministic, and nothing
    downstream writes into its arrays."""
    key = _chart_key(points, triangles, corner, face, options)
    got = _chart_cache.pop(key, None)
    if got is None:
        uv1, labels, scale, stats = _chart_pass(points, triangles, corner, face, path, options)
        rects = ChartRects(uv1)
        candidates = [labels]
        for solidity in RING_SOLIDITY:
            cut = split_rings(uv1, labels, face, solidity, rects)
            if not any(np.array_equal(cut, c) for c in candidates):
                candidates.append(cut)
        for a in (uv1, labels, *candidates):
            a.flags.writeable = False
        got = (uv1, labels, scale, stats, rects, candidates)
    _chart_cache[key] = got
    while len(_chart_cache) > CHART_CACHE_SIZE:
        _chart_cache.pop(next(iter(_chart_cache)))
    uv1, labels, scale, stats, rects, candidates = got
    return uv1, labels, scale, dict(stats), rects, candidates


def _chart_key(points, triangles, corner, face, options):
    """:func:`_charts`' cache key."""
    import hashlib

    digest = hashlib.blake2b(digest_size=20)
    for a in (points, triangles, corner, face):
        a = np.ascontiguousarray(a)
        digest.update(repr((a.dtype.str, a.shape)).encode())
        digest.update(a.tobytes())
    # the module's settings and helpers pass 1 depends on are part of the key (a test that
    # patches one of them must not get an earlier mesh's charts)
    settings = (NORMALIZED_DIAGONAL, CHART_PASS_SIDE, PACK_EFFICIENCY, RING_SOLIDITY)
    helpers = (_chart_pass, destretch, extend_into, overlaps, project_polygon, self_overlap)
    helpers += (split_polygons, split_rings, unfold_polygon)
    return (digest.digest(), repr(sorted((options or {}).items())), settings, helpers)


def _repeats_earlier(points, triangles, corner, face, k, uv1, labels) -> bool:
    """Whether the charts of CHART_OPTIONS[k] are those of an earlier option this process
    already made (a box's charts are the same with every option): the same candidates packed
    again cannot win, since a later candidate must score strictly higher."""
    for j in range(k):
        got = _chart_cache.get(_chart_key(points, triangles, corner, face, CHART_OPTIONS[j]))
        if got is not None and np.array_equal(got[0], uv1) and np.array_equal(got[1], labels):
            return True
    return False


class _Packs:
    """:func:`_run_pack` results of one :func:`_pack` call by their inputs' bytes: two
    candidates that come out the same (a floor that widens no chart more than the floor below
    it, at the densities a requested map size tries) are packed once. xatlas's pack is
    deterministic, so the result is the one a second run would give."""

    def __init__(self):
        self.done: dict[bytes, tuple] = {}
        self.calls = 0

    def __call__(self, verts, indices, texels_per_unit, padding):
        import hashlib

        digest = hashlib.blake2b(digest_size=20)
        for a in (verts, indices):
            digest.update(repr((a.dtype.str, a.shape)).encode())
            digest.update(np.ascontiguousarray(a).tobytes())
        digest.update(repr((float(texels_per_unit), int(padding))).encode())
        key = digest.digest()
        if key not in self.done:
            self.calls += 1
            self.done[key] = _run_pack(verts, indices, texels_per_unit, padding)
        return self.done[key]


def _run_pack(verts, indices, texels_per_unit, padding):
    """Pass 2: xatlas packs the charts of the UV mesh at a fixed texel density (single atlas;
    resolution left at 0). Returns (w, h, uv (t, 3, 2) float64 in texels, chart count)."""
    import xatlas

    atlas = unwrap_worker.new_atlas()
    atlas.add_uv_mesh(verts, indices)
    pack = xatlas.PackOptions()
    pack.padding = int(padding)
    pack.bilinear = PACK_BILINEAR
    pack.texels_per_unit = float(texels_per_unit)
    pack.resolution = 0
    pack.bruteForce = PACK_BRUTE_FORCE
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count != 1:
        raise BakeError(f"xatlas produced {atlas.atlas_count} atlases, expected 1")
    vmap, idx, uvs = atlas.get_mesh(0)
    idx = np.asarray(idx, dtype=np.int64)
    if not np.array_equal(idx, indices) or not np.array_equal(vmap, np.arange(len(verts))):
        raise BakeError("xatlas changed the UV mesh while packing it")
    vchart = np.asarray(atlas.get_mesh_vertex_assignment(0)[1], dtype=np.int64)
    vchart[vchart >= 2**31] = -1
    out = np.asarray(uvs, dtype=np.float64) * np.array([atlas.width, atlas.height], np.float64)
    if (vchart < 0).any():
        _place_ignored(verts, idx, vchart, out)
    return atlas.width, atlas.height, out[idx], atlas.chart_count


def _place_ignored(verts, idx, vchart, out) -> None:
    """xatlas ignores zero-area UV triangles when it packs a UV mesh and leaves the vertices
    only they use where they were (in pass 2's input layout, i.e. anywhere in the atlas).
    Put each such vertex (in ``out``, in place) on a packed vertex of one of its triangles:
    the triangle keeps zero area (it gets no texel either way) and stays inside its chart; a
    triangle with no packed vertex at all collapses onto texel (0, 0)."""
    lost = vchart < 0
    for f in np.flatnonzero(lost[idx].any(axis=1)):
        tri = idx[f]
        keep = tri[~lost[tri]]
        targets = tri[lost[tri]]
        out[targets] = out[keep[0]] if len(keep) else 0.0
        lost[targets] = False


def _pack(
    points,
    triangles,
    corner,
    face,
    texels_per_unit,
    target,
    padding,
    max_resolution,
    path,
    min_width=(0.0,),
):
    """The xatlas part of :func:`unwrap`: returns (w, h, uv (t, 3, 2) texels, target, stats).

    Pass 2 packs the charts as pass 1 made them and, for each fraction of
    :data:`RING_SOLIDITY` that changes them, with those rings cut into their sides
    (:func:`split_rings`); pass 1 runs with each of :data:`CHART_OPTIONS`, and each candidate
    is packed with the charts narrower than each floor of ``min_width`` (texels) widened to it
    (:func:`widen_thin`). With ``texels_per_unit`` the layout with the most covered texels
    less :data:`FILL_WEIGHT` x map texels wins (then the smaller map); with a ``target`` map
    the one covering most texels (then the highest density; the first of equals). One
    :func:`pack_part` per chart option, then :func:`_choose`: the isolated run hands the
    parts to worker processes (:data:`UNWRAP_WORKERS`)."""
    args = (points, triangles, corner, face, texels_per_unit, target, padding, max_resolution)
    args += (path, min_width)
    return _choose([pack_part(*args, k) for k in range(len(CHART_OPTIONS))], args)


def _choose(parts, args):
    """The best of :func:`pack_part`'s results (an earlier part on equal keys: the order
    of one loop over every candidate), checked as :func:`_pack` promises."""
    texels_per_unit, target, padding, max_resolution, path = args[4:9]
    best = None
    packs = 0
    for part in parts:
        if part is None:
            continue
        packs += part[1][4]["packs"]
        if best is None or part[0] > best[0]:
            best = part
    if best is None:
        raise BakeError(
            f"{path}: could not pack the unwrapped charts into {target[0]}x{target[1]} texels "
            f"(padding {padding}); raise --resolution"
        )
    w, h, uv, size, stats = best[1]
    if texels_per_unit is not None and max(w, h) > max_resolution:
        raise UsageError(
            f"{path}: {texels_per_unit:g} texels per unit gives a {w}x{h} lightmap, "
            f"above the maximum {max_resolution}; lower --texel-density"
        )
    return w, h, uv, size, dict(stats, packs=packs)


def pack_part(
    points,
    triangles,
    corner,
    face,
    texels_per_unit,
    target,
    padding,
    max_resolution,
    path,
    min_width=(0.0,),
    k=0,
):
    """:func:`_pack`'s candidates of the chart option ``CHART_OPTIONS[k]`` only: (key, (w, h,
    uv, target, stats)) of the best of them (the first of equal keys), None when none fits
    (or its charts repeat an earlier option's, :func:`_repeats_earlier`)."""
    world = triangle_areas(np.asarray(points, np.float64)[np.asarray(triangles, np.int64)])
    packs = _Packs()
    uv1, labels, scale, stats, rects, candidates = _charts(
        points, triangles, corner, face, path, CHART_OPTIONS[k]
    )
    if k and _repeats_earlier(points, triangles, corner, face, k, uv1, labels):
        return None
    best = None
    if texels_per_unit is not None:
        density = texels_per_unit / scale * SHRINK
        for lab in candidates:
            for width in min_width:
                uvw, widened = widen_thin(uv1, lab, density, width, rects)
                if width and not widened and width != min_width[0]:
                    continue  # the same charts as a smaller floor
                w, h, uv, _ = packs(*layout(uvw, lab), density, padding)
                spread = _spread(uv, world)
                covered, overlap = _covered(uv, w, h)
                score = covered - FILL_WEIGHT * w * h
                key = (
                    -overlap,
                    spread <= DENSITY_SPREAD_MAX,
                    score if spread <= DENSITY_SPREAD_MAX else -spread,
                    -w * h,
                )
                if best is None or key > best[0]:
                    best = (key, (w, h, uv, (w, h)), lab, widened)
    else:
        area = _world_area(points.astype(np.float64), triangles.astype(np.int64))
        for lab in candidates:
            for width in min_width:
                tpu = min(target) * np.sqrt(PACK_EFFICIENCY / area)
                got = _fit(
                    uv1,
                    lab,
                    scale,
                    tpu,
                    target,
                    padding,
                    path,
                    strict=k == 0 and lab is labels,
                    width=width,
                    rects=rects,
                    packs=packs,
                )
                if got is None:
                    continue
                spread = _spread(got[2], world)
                even = spread <= DENSITY_SPREAD_MAX
                covered, overlap = _covered(got[2], *target)
                score = (-overlap, even, covered if even else -spread, got[3])
                if best is None or score > best[0]:
                    best = (score, (*got[:3], target), lab, got[4])
    if best is None:
        return None
    key, layout_, lab, widened = best
    stats = dict(
        stats, options=k, rings_cut=_rings_cut(labels, lab), widened=widened, packs=packs.calls
    )
    return key, (*layout_, stats)


def _spread(uv, world) -> float:
    """Area-weighted 90th / 10th percentile of the texel density (sqrt(UV area / surface
    area)) over the triangles: what ``usdahd validate``'s UVSet rule warns about
    (``TexelDensity`` above 4)."""
    from usdahd.numerics.triangles import uv_areas

    ok = (world > 0) & (uv_areas(uv) > 1e-12)
    if ok.sum() < 2:
        return 1.0
    dens = np.sqrt(uv_areas(uv)[ok] / world[ok])
    order = np.argsort(dens)
    cw = np.cumsum(world[ok][order]) / world[ok].sum()
    p10 = dens[order][np.searchsorted(cw, 0.1)]
    p90 = dens[order][min(np.searchsorted(cw, 0.9), len(cw) - 1)]
    return float(p90 / p10) if p10 > 0 else float("inf")


def _covered(uv, w, h) -> tuple[int, int]:
    """(covered, overlapping) texels of the (t, 3, 2) pixel-space ``uv`` of a w x h map:
    covered conservatively, as the bake rasterises them, and overlapping as ``usdahd
    validate``'s UVOverlap rule counts them (centres strictly inside two triangles;
    :func:`usdahd.numerics.raster.coverage`, the rasteriser's texels without their sample
    points)."""
    from usdahd.numerics.raster import coverage

    flat = np.empty_like(uv)
    flat[..., 0] = uv[..., 0] / w
    flat[..., 1] = 1.0 - uv[..., 1] / h
    ids, overlap_ids = coverage(flat, (w, h))[:2]
    return int(len(ids)), int(len(overlap_ids))


def _rings_cut(labels, lab) -> int:
    """How many of pass 1's charts ``labels`` the labels ``lab`` cut."""
    return int(len(np.unique(labels[lab != labels])))


def _fit(
    uv1, labels, scale, tpu, target, padding, path, *, strict, width=0.0, rects=None, packs=None
):
    """Pass 2 of the charts ``labels`` at the largest density (from ``tpu``, MAX_ATTEMPTS
    tries) whose atlas fits ``target``: (w, h, uv, density) or None. ``strict``: raise when
    the charts are too many for the map at any density (else None). ``width``: charts
    narrower (texels, at each density tried) are widened to it (:func:`widen_thin`); the
    result then ends with the number widened. ``packs``: a :class:`_Packs` to share."""
    packs = _Packs() if packs is None else packs
    best = None
    for _ in range(MAX_ATTEMPTS):
        density = tpu / scale * SHRINK
        uvw, widened = widen_thin(uv1, labels, density, width, rects)
        w, h, uv, charts = packs(*layout(uvw, labels), density, padding)
        if best is None and charts * (1 + padding) ** 2 > target[0] * target[1]:
            if not strict:
                return None
            # every chart takes at least one texel and its padding: no scale fits them
            side = int(np.ceil(np.sqrt(charts) * (1 + padding)))
            raise BakeError(
                f"{path}: xatlas cut this mesh into {charts} charts, which need at least "
                f"{side}x{side} texels with padding {padding}; the lightmap is "
                f"{target[0]}x{target[1]}: raise --resolution"
            )
        fit = max(w / target[0], h / target[1])
        if fit <= 1.0:
            best = (w, h, uv, density, widened)
            if fit > 0.9:
                break
            tpu *= min(1.0 / fit, 1.5) * 0.98
        else:
            if best is not None:
                break
            tpu *= 0.98 / fit
    return best


#: Worker processes an isolated unwrap runs its chart options' parts in (:func:`pack_part`,
#: one option each, at the same time), at most one per chart option and core. 2: on an idle
#: 2-core machine two workers planned Sponza in 13.5 s instead of 19.2 s and the classroom in
#: 21 s instead of 31 s (`usdahd bake classroom.usdc --dry-run`, load 1.1-1.8, 2026-12-06,
#: docs/scenes.md "The plan's cost halved"). It was 1 while xatlas's Destroy deadlocked two
#: workers' plans (3 of 7 classroom plans); atlases now outlive their use
#: (unwrap_worker.ATLAS_RETIRE_S): 0 stalls in 6 two-worker classroom plans at load 6-7.5,
#: where 2 of 2 stalled before.
UNWRAP_WORKERS = 2


def _slots() -> int:
    import os

    return max(1, min(UNWRAP_WORKERS, len(CHART_OPTIONS), os.cpu_count() or 1))


def _pack_isolated(args, path):
    """Run :func:`_pack` in worker processes (started on first use, restarted after a crash;
    stopped at interpreter exit): each chart option's :func:`pack_part` in its own worker
    (:data:`UNWRAP_WORKERS`), at the same time, then :func:`_choose` here."""
    import pickle
    import time

    limit = UNWRAP_TIMEOUT_S + UNWRAP_TIMEOUT_PER_TRIANGLE_S * len(args[1])
    slots = _slots()
    parts = list(range(len(CHART_OPTIONS)))
    replies: dict[int, object] = {}
    waves = [parts[i : i + slots] for i in range(0, len(parts), slots)]
    for wave in waves:
        # A worker that dies on a mesh gets one retry in a fresh worker: a death from outside
        # (a signal, memory pressure) then fails no prim, and xatlas's segfaults, which follow
        # the mesh, fail the second time too.
        pending = list(wave)
        for attempt in range(2):
            used = {k: unwrap_worker.slot_worker(wave.index(k), fresh=attempt > 0) for k in pending}
            sent = [k for k in pending if used[k].send(pickle.dumps((*args, k)))]
            end = time.monotonic() + limit
            for k in pending:
                try:
                    replies[k] = used[k].receive(end) if k in sent else None
                except TimeoutError:
                    unwrap_worker.stop_worker()
                    raise BakeError(
                        f"{path}: xatlas did not finish unwrapping this mesh within "
                        f"{limit:.0f} s (the child process was stopped); author a lightmap UV "
                        "set for it and pass it with --uv"
                    ) from None
            dead = [k for k in pending if replies[k] is None]
            if not dead:
                break
            if attempt:
                detail = used[dead[0]].failure()
                for k in dead:
                    used[k].stop()
                    unwrap_worker.forget(wave.index(k))
                raise BakeError(
                    f"{path}: xatlas crashed while unwrapping this mesh ({detail}); "
                    "author a lightmap UV set for it and pass it with --uv"
                )
            pending = dead
    results = []
    for k in parts:
        kind, value = replies[k]
        if kind == "usage":
            raise UsageError(value)
        if kind == "bake":
            raise BakeError(value)
        if kind == "error":
            raise BakeError(f"{path}: unwrapping failed: {value}")
        results.append(value)
    return _choose(results, args)


def unwrap(
    mesh: MeshData,
    *,
    texels_per_unit: float | None = None,
    resolution: int | tuple[int, int] | None = None,
    padding: int = CHART_PADDING,
    max_resolution: int = MAX_RESOLUTION,
    isolate: bool = True,
    info: dict | None = None,
    min_chart_width: float | None = None,
) -> tuple[np.ndarray, tuple[int, int]]:
    """Unwrap ``mesh`` into one lightmap atlas.

    Give exactly one of ``texels_per_unit`` (world-space texel density; the atlas size is what
    xatlas needs) or ``resolution`` (n or (w, h): the atlas is packed as densely as fits, and
    placed in the top-left corner of a w x h lightmap, so the returned resolution is exactly the
    requested one). ``padding`` is the gutter in texels between charts. ``min_chart_width``
    (texels): every chart narrower is stretched across to it
    (:func:`usdahd.numerics.charts.widen_thin`); 0 for none; None (the default) tries each of
    :data:`CHART_MIN_WIDTHS` and keeps the layout that fills best (:func:`_pack`). ``isolate``
    runs xatlas in a child process (it can segfault on some meshes; that becomes a BakeError).

    Returns ``uv : (t, 3, 2) float32`` per-corner lightmap UVs in [0, 1] (same triangle order as
    ``mesh.triangles``; author them as a faceVarying primvar via ``mesh.corner``: the triangles
    of one polygon (``mesh.face``) give each of its corners the same UV) and
    ``resolution : (w, h)``. xatlas lays out some charts mirrored (about 45 % on the castle
    scene); they are kept as they are (flipping a chart inside its bounding box made it overlap
    interlocking neighbours): their tangent frames are left-handed, b = -cross(n, t), as
    docs/texels.md specifies.
    ``info``, when given, receives pass 1's counts: ``charts_xatlas``, ``split_polygons``
    (polygons xatlas cut), ``extended`` (re-joined to a chart) and ``own_chart``, and pass 2's
    ``rings_cut`` (ring charts packed cut into their sides, :func:`split_rings`),
    ``widened`` (charts stretched to a width floor), ``options`` (the index of the
    :data:`CHART_OPTIONS` kept) and ``packs`` (xatlas pack passes run: the distinct candidate
    layouts tried).
    Deterministic for a given mesh and options.
    Raises UsageError if the atlas would exceed ``max_resolution``.
    """
    if (texels_per_unit is None) == (resolution is None):
        raise UsageError("unwrap needs exactly one of texels_per_unit or resolution")
    points = np.ascontiguousarray(mesh.points, dtype=np.float32)
    triangles = np.ascontiguousarray(mesh.triangles, dtype=np.uint32)
    if len(triangles) == 0:
        raise InputError(f"{mesh.path}: mesh has no triangles to unwrap")
    if not np.isfinite(points).all():
        raise InputError(f"{mesh.path}: points contain NaN or infinity; cannot unwrap")
    area = _world_area(points.astype(np.float64), triangles.astype(np.int64))
    if area <= 0.0:
        raise InputError(f"{mesh.path}: mesh has zero surface area; cannot unwrap")
    if padding < 0:
        raise UsageError(f"unwrap padding must be >= 0, got {padding}")
    min_width = CHART_MIN_WIDTHS if min_chart_width is None else (float(min_chart_width),)
    if not all(np.isfinite(m) and m >= 0 for m in min_width):
        raise UsageError(f"unwrap min_chart_width must be >= 0 texels, got {min_chart_width!r}")

    target = None
    if texels_per_unit is not None:
        if not np.isfinite(texels_per_unit) or texels_per_unit <= 0:
            raise UsageError(f"texel density must be positive, got {texels_per_unit!r}")
        estimate = texels_per_unit * np.sqrt(area / PACK_EFFICIENCY)
        if estimate > 2 * max_resolution:
            raise UsageError(
                f"{mesh.path}: {texels_per_unit:g} texels per unit needs about a "
                f"{estimate:.0f}^2 lightmap, above the maximum {max_resolution}; "
                "lower --texel-density"
            )
        texels_per_unit = float(texels_per_unit)
    else:
        if np.isscalar(resolution):
            target = (int(resolution), int(resolution))
        else:
            target = tuple(int(r) for r in resolution)
        if len(target) != 2 or min(target) < 1 or max(target) > max_resolution:
            raise UsageError(
                f"lightmap resolution {resolution!r} must be n or (w, h) in 1..{max_resolution}"
            )

    corner = np.ascontiguousarray(mesh.corner, dtype=np.int64)
    face = np.ascontiguousarray(mesh.face, dtype=np.int64)
    args = (
        points,
        triangles,
        corner,
        face,
        texels_per_unit,
        target,
        padding,
        max_resolution,
        mesh.path,
        min_width,
    )
    if isolate:
        w, h, pix, target, stats = _pack_isolated(args, mesh.path)
    else:
        w, h, pix, target, stats = _pack(*args)
    if info is not None:
        info.update(stats)
    # pixel coords (y down) -> our lightmap of size target
    uv = np.empty_like(pix)
    uv[..., 0] = pix[..., 0] / target[0]
    uv[..., 1] = 1.0 - pix[..., 1] / target[1]
    uv = uv.astype(np.float32)
    bad = unrepresentable_corners(corner, uv)
    if bad:
        raise BakeError(
            f"{mesh.path}: the unwrap gives {bad} polygon corners two UVs, which a faceVarying "
            "primvar cannot hold (a bug: please report it); author a lightmap UV set for this "
            "mesh and pass it with --uv"
        )
    return uv, (int(target[0]), int(target[1]))


def unrepresentable_corners(corner: np.ndarray, uv: np.ndarray) -> int:
    """How many polygon corners (faceVertex indices, ``corner`` (t, 3)) get more than one
    value from the per-triangle-corner ``uv`` (t, 3, 2): a faceVarying primvar holds one UV per
    polygon corner, so those UVs cannot be authored as they are."""
    c = np.asarray(corner, dtype=np.int64).reshape(-1)
    v = np.asarray(uv).reshape(len(c), -1)
    order = np.lexsort((*v.T[::-1], c))
    c, v = c[order], v[order]
    differ = (c[1:] == c[:-1]) & (v[1:] != v[:-1]).any(axis=1)
    return int(len(np.unique(c[1:][differ])))
