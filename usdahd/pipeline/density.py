"""The automatic texel density: each mesh's extent, the stage's ceiling by size, the densest
step of the ladder whose maps fit the texel budget, and the shared density that steps the
prims the prop rules left alone up towards the raised ones (docs/texels.md, "What decides a
prim's lightmap size"). numpy only; meshes are read through ``points``, ``triangles``, ``uv``.
"""

from __future__ import annotations

import numpy as np

from usdahd.numerics.triangles import triangle_areas, uv_areas
from usdahd.pipeline.settings import (
    DENSITY_AUTO_MAX,
    DENSITY_LADDER,
    DENSITY_MAX_RESOLUTION,
    MIN_RESOLUTION,
    RESOLUTION_MULTIPLE,
)

__all__ = [
    "SHARED_DENSITY_MAX_RATIO",
    "SHARED_DENSITY_SHARE",
    "STAGE_MIN_TEXELS",
    "auto_texel_density",
    "density_ceiling",
    "mesh_extent",
    "planned_texels",
    "shared_density",
    "snap_density",
    "stage_extent",
]


def mesh_extent(mesh, meters_per_unit: float) -> float:
    """sqrt(world area / UV area) in metres: the side of a map at 1 texel per metre. The UV
    area is the lightmap UV set's when it has one, else xatlas's rough packing efficiency
    (bake.unwrap.PACK_EFFICIENCY)."""
    from usdahd.bake.unwrap import PACK_EFFICIENCY

    p = np.asarray(mesh.points, np.float64)[np.asarray(mesh.triangles, np.int64)]
    world = triangle_areas(p).sum()
    uv_area = PACK_EFFICIENCY
    if mesh.uv is not None:
        uv = np.asarray(mesh.uv, np.float64)
        if np.isfinite(uv).all():
            a = uv_areas(uv).sum()
            if 1e-12 < a <= 1.0:
                uv_area = a
    mpu = float(meters_per_unit or 1.0)
    return float(np.sqrt(max(world, 0.0) / uv_area)) * mpu


#: Texels the automatic density puts at least across the largest side of the stage (the
#: bounds of the prims on it), within the texel budget: a tabletop stage (the chess set's
#: 0.7 m, the shader ball's 1 m studio) would get only 11-16 texels across at the 16/m
#: ceiling, fewer than its contact shadows need (docs/texels.md, "A floor by stage size";
#: measured in docs/scenes.md). Stages of 8 m and more keep DENSITY_AUTO_MAX.
STAGE_MIN_TEXELS = 128


def stage_extent(meshes, meters_per_unit: float) -> float:
    """The largest side in metres of the axis-aligned bounds of ``meshes``' points (world
    space); 0 for no points."""
    lo, hi = None, None
    for m in meshes:
        p = np.asarray(m.points, np.float64)
        if p.size == 0 or not np.isfinite(p).all():
            continue
        a, b = p.min(axis=0), p.max(axis=0)
        lo = a if lo is None else np.minimum(lo, a)
        hi = b if hi is None else np.maximum(hi, b)
    if lo is None:
        return 0.0
    return float((hi - lo).max()) * float(meters_per_unit or 1.0)


def density_ceiling(extent: float, texels: int = STAGE_MIN_TEXELS) -> float:
    """The densest step the automatic density starts from on a stage whose largest side is
    ``extent`` metres (:func:`stage_extent`): DENSITY_AUTO_MAX, or the first step of the same
    ladder above it (DENSITY_AUTO_MAX / DENSITY_LADDER^j) that puts ``texels`` across that
    side, so a small stage is not held to 16/m."""
    if not extent > 0 or DENSITY_AUTO_MAX * extent >= texels:
        return DENSITY_AUTO_MAX
    j = int(np.ceil(np.log(texels / (DENSITY_AUTO_MAX * extent)) / -np.log(DENSITY_LADDER)))
    d = snap_density(DENSITY_AUTO_MAX * DENSITY_LADDER ** (-j))
    while d * extent < texels - 1e-9:  # the 4-digit snap can land just below
        j += 1
        d = snap_density(DENSITY_AUTO_MAX * DENSITY_LADDER ** (-j))
    return d


def auto_texel_density(
    extents, budget: int, *, minimum: int = MIN_RESOLUTION, ceiling: float = DENSITY_AUTO_MAX
) -> tuple[float, int, bool]:
    """The stage's automatic texel density: the largest step ``ceiling`` *
    DENSITY_LADDER^k (k = 0, 1, ...; ``ceiling`` a step of the ladder, DENSITY_AUTO_MAX or
    above it for a small stage, :func:`density_ceiling`) at which the maps of meshes of these
    ``extents``
    (:func:`mesh_extent`), each ceil(density * extent) at least ``minimum``, rounded up to
    RESOLUTION_MULTIPLE and clamped to DENSITY_MAX_RESOLUTION, total at most ``budget``
    texels (steps are snapped to 4 significant digits, as recorded). Returns (density,
    planned texels, fits); ``fits`` is False when even the minimum maps (``minimum``^2 each)
    exceed the budget (then the density is the step where every map is at its minimum).
    For meshes the bake unwraps the extents assume xatlas's rough packing efficiency, so the
    maps it packs can total more than planned (docs/texels.md)."""
    ext = np.asarray(list(extents), np.float64)

    def total(d: float) -> int:
        return planned_texels(d, ext, minimum)

    up = max(int(round(np.log(float(ceiling) / DENSITY_AUTO_MAX) / -np.log(DENSITY_LADDER))), 0)
    d = DENSITY_AUTO_MAX
    for k in range(200):
        d = snap_density(DENSITY_AUTO_MAX * DENSITY_LADDER ** (k - up))
        t = total(d)
        if t <= budget:
            return d, t, True
        if len(ext) == 0 or (d * ext.max() <= minimum):  # every map at its minimum already
            return d, t, False
    return d, total(d), False


def planned_texels(density: float, extents, minimum: int = MIN_RESOLUTION) -> int:
    """Texels of the maps of meshes of these ``extents`` (:func:`mesh_extent`) at ``density``:
    each ceil(density * extent), at least ``minimum``, rounded up to RESOLUTION_MULTIPLE and
    clamped to DENSITY_MAX_RESOLUTION (the automatic density's plan)."""
    ext = np.asarray(list(extents), np.float64)
    n = np.maximum(np.ceil(density * ext - 1e-9), 1)
    n = np.maximum(n, minimum)
    n = np.minimum(-(-n // RESOLUTION_MULTIPLE) * RESOLUTION_MULTIPLE, DENSITY_MAX_RESOLUTION)
    return int((n.astype(np.int64) ** 2).sum())


#: Prims on one stage share one density: when the prop rules (TOUCHING_LIMIT, CHART_MIN_TEXELS)
#: raise maps, the automatic density of the prims they leave alone steps up the ladder (within
#: the texel budget) to at least this share of the raised prims' median density
#: (:func:`shared_density`). The chess set's board, 3-6x coarser than the pieces standing on it
#: (215.3/m against a raised median of 813/m), reads relRMSE 0.0697 against the path tracer at
#: 215.3/m, 0.0597 at 304.4/m and 0.0513 at 362/m, the first step clearly under 0.06: 0.4 x
#: 813 picks it (docs/texels.md, "Prims on one stage share one density").
SHARED_DENSITY_SHARE = 0.4
#: The shared density steps the prims the prop rules left alone up at most this factor (linear;
#: 4x their texels): one small raised prop on a large stage with room in its budget would
#: otherwise step every other prim up to the budget. The chess set needs 1.68 (215.3 -> 362/m).
SHARED_DENSITY_MAX_RATIO = 2.0


def shared_density(
    density: float,
    raised,
    extents,
    fixed_texels: int,
    budget: int,
    *,
    minimum: int = MIN_RESOLUTION,
    share: float = SHARED_DENSITY_SHARE,
    max_ratio: float = SHARED_DENSITY_MAX_RATIO,
) -> float:
    """The automatic density of the prims the prop rules left alone (``extents``, their
    :func:`mesh_extent`), given the densities ``raised`` (texels per metre) that those rules
    gave the other prims on it: the lowest step of the ladder above ``density``
    (DENSITY_AUTO_MAX * DENSITY_LADDER^k) at or above ``share`` times the median of ``raised``,
    or the densest step below it whose maps plus ``fixed_texels`` (the raised maps) fit
    ``budget``. ``density`` itself when nothing was raised, when every map of ``extents`` is at
    ``minimum`` (stepping up changes nothing there), or when the next step does not fit. At
    most ``max_ratio`` x ``density`` (:data:`SHARED_DENSITY_MAX_RATIO`)."""
    ext = np.asarray(list(extents), np.float64)
    raised = np.asarray(list(raised), np.float64)
    if len(raised) == 0 or len(ext) == 0 or not (density * ext > minimum).any():
        return density
    target = share * float(np.median(raised))
    k = int(round(np.log(density / DENSITY_AUTO_MAX) / np.log(DENSITY_LADDER)))
    best = density
    while best < target - 1e-9:
        k -= 1
        step = snap_density(DENSITY_AUTO_MAX * DENSITY_LADDER**k)
        if step > max_ratio * density * (1 + 1e-9):
            break
        if int(fixed_texels) + planned_texels(step, ext, minimum) > budget:
            break
        best = step
    return best


def snap_density(d: float) -> float:
    """The density as recorded in the settings (4 significant digits: a stable hash)."""
    return float(f"{d:.4g}")
