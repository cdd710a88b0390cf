"""Planning a bake: each mesh's resolved settings, UV set (authored, reused from the previous
unwrap, or unwrapped now) and lightmap resolution (given, or from the texel density), as a
:class:`PrimJob` the later stages fill in.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from usdahd.errors import BakeError, InputError, UsageError
from usdahd.numerics.raster import UV_OVERLAP_LIMIT
from usdahd.numerics.triangles import triangle_areas, uv_areas
from usdahd.pipeline.density import mesh_extent
from usdahd.pipeline.settings import (
    DENSITY_MAX_RESOLUTION,
    MAX_RESOLUTION,
    MIN_RESOLUTION,
    RESOLUTION_MULTIPLE,
    UV_DEGENERATE_LIMIT,
    UV_OUTSIDE_LIMIT,
    BakeOptions,
    authored_inputs,
    record_time,
    resolve_settings,
)
from usdahd.scene.hashing import shape_digest

if TYPE_CHECKING:
    from usdahd.bake.types import Texels
    from usdahd.scene.types import ComputedNormals, MeshData
    from usdahd.usd.schema import BakeResults

__all__ = [
    "PrimJob",
    "REFIT_SETTINGS",
    "plan_job",
    "prop_cap",
    "refit_source",
    "settings_as_stored",
    "settings_resolution_given",
]


@dataclass
class PrimJob:
    """One mesh to bake: its plan, then what each stage adds (``n`` covered texels, ``t``
    triangles; :mod:`usdahd.pipeline.stages` fills in the trace-and-write fields).

    A job with ``mesh`` None keeps a previous bake of a prim not re-planned this run
    (``previous`` set, ``report`` status ``kept``).
    """

    # -- the plan (plan.py, run.py)
    path: str  #: prim path
    mesh: MeshData | None  #: the triangulated mesh (its ``uv`` set to the lightmap UVs)
    settings: dict[str, Any]  #: resolved settings (settings.resolve_settings, record_time)
    resolution: tuple[int, int] = (0, 0)  #: lightmap (width, height)
    unwrapped: bool = False  #: the UVs come from xatlas (authored in the output layer)
    #: the map's size before a prop rule raised it (TOUCHING_LIMIT, CHART_MIN_TEXELS), else None
    raised_from: tuple[int, int] | None = None
    #: (t, 3, 2) float32 per-corner UVs to author when unwrapped, else None
    uv_primvar_values: np.ndarray | None = None
    #: normals the scene reader computed, authored in the output layer (None: authored ones)
    normals: ComputedNormals | None = None
    content_hash: str = ""  #: hash of every input of this prim's bake (scene.hashing)
    parts: dict[str, str] = field(default_factory=dict)  #: part name -> hash (what changed)
    #: the prim's entry of the bake report (status, reason, warnings, notes, timings)
    report: dict[str, Any] = field(default_factory=dict)
    previous: BakeResults | None = None  #: an unchanged previous bake, kept as it is
    fallback: BakeResults | None = None  #: the previous bake, kept if this one fails
    refit_from: str | None = None  #: SH sidecar of the previous bake to refit from (no tracing)
    # -- the stages (stages.py)
    texels: Texels | None = None  #: the covered texels (rasterised when planned or traced)
    #: (n, 3, 9) float32 radiance SH per texel (RGB x 9 coefficients)
    sh: np.ndarray | None = None
    #: integrator statistics (bake.integrate.bake_texels): "rays" int, "invalid" (n,) bool, ...
    stats: dict[str, Any] = field(default_factory=dict)
    charts: np.ndarray | None = None  #: (n,) int32 UV chart id per texel
    results: BakeResults | None = None  #: what this bake wrote (set once written)


def _texels_per_unit(settings: dict, scene) -> float:
    """Schema texel density is per metre; the mesh is in stage units."""
    return float(settings["texel_density"]) * float(scene.meters_per_unit or 1.0)


def _round_up(n: int, multiple: int) -> int:
    return -(-int(n) // multiple) * multiple


def _auto_density(settings: dict) -> bool:
    """Whether the prim's texel density is the stage's automatic one (texel budget)."""
    return "min_resolution" in settings and settings.get("texel_density") is not None


def _uv_problem(texels) -> str | None:
    """Why a rasterised UV set cannot hold a lightmap, or None if it can."""
    st = texels.stats
    covered = max(len(texels), 1)
    if len(texels) == 0:
        return "covers no texel"
    if st.get("overlap_texels", 0) > UV_OVERLAP_LIMIT * covered:
        return f"overlaps itself on {100 * st['overlap_texels'] / covered:.0f}% of its texels"
    if st.get("uv_outside_fraction", 0.0) > UV_OUTSIDE_LIMIT:
        return f"has {100 * st['uv_outside_fraction']:.1f}% of its UVs outside [0,1]"
    return None


#: An authored UV set on the automatic density is unwrapped instead when more than this share
#: of its covered texels lie next to a texel of another UV chart at the planned size: a texture
#: UV layout packs charts edge to edge with no gutter, so a bilinear lookup there mixes two
#: unrelated surfaces (a lit top and a dark underside) and charts a few texels wide are all
#: border (docs/texels.md, "Texture UVs as lightmap UVs"). The samples' lightmap layouts, whose
#: box faces are about a texel apart at their planned size, reach 16 % (validated against
#: Cycles as they are); a chart 8 texels wide touching neighbours on both sides, 25 %.
TOUCHING_LIMIT = 0.25
#: A map raised for touching texels (TOUCHING_LIMIT) is doubled until at most this share of
#: its texels touch another chart (or the prop cap is reached): the chess set's board and rooks
#: still had 17 % at 64x64.
TOUCHING_TARGET = 0.05
#: Share of an authored UV set's area whose charts' width decides whether the set is too fine
#: for its lightmap (:func:`narrow_chart_width`): the narrowest charts holding 10 % of it.
NARROW_SHARE = 0.1
#: Texels across (:func:`narrow_chart_width`) the narrow charts of an unwrapped map on the
#: automatic density get at least: a chart narrower than this is mostly border texels, whose
#: bilinear footprint reaches the gutter.
CHART_MIN_TEXELS = 4
#: Largest side the two rules above raise a map to (props: a chess piece, a teapot); the
#: stage's texel budget lowers it (:func:`prop_cap`).
PROP_MAX_RESOLUTION = 128


def prop_cap(headroom: int, prims: int) -> int:
    """The largest side (a multiple of RESOLUTION_MULTIPLE, at most PROP_MAX_RESOLUTION) a map
    on the automatic density may be raised to for its charts: even if every one of the
    ``prims`` on it got a whole extra map that large, they would add at most ``headroom``
    texels (the texel budget less the planned texels; 0 when the plan fills the budget)."""
    side = int(np.sqrt(max(int(headroom), 0) / max(int(prims), 1)))
    side -= side % RESOLUTION_MULTIPLE
    return max(min(side, PROP_MAX_RESOLUTION), 0)


def narrow_chart_width(uv: np.ndarray, share: float = NARROW_SHARE) -> float:
    """The width in UV units (2 x area / perimeter: a strip's width, a disc's radius) below which
    the UV charts (texels.uv_charts) holding ``share`` of the UV set's area lie: the width of
    its narrow charts, a lightmap of side N giving them N times this many texels across."""
    from usdahd.bake.texels import uv_charts

    uv = np.asarray(uv, np.float64)
    if len(uv) == 0:
        return 0.0
    ch = uv_charts(uv).astype(np.int64)
    k = int(ch.max()) + 1
    area = np.bincount(ch, uv_areas(uv), k)
    ends = np.stack([uv, uv[:, [1, 2, 0]]], axis=2).reshape(-1, 4)  # (3t, 2 endpoints x 2)
    swap = (ends[:, 0] > ends[:, 2]) | ((ends[:, 0] == ends[:, 2]) & (ends[:, 1] > ends[:, 3]))
    key = np.where(swap[:, None], ends[:, [2, 3, 0, 1]], ends)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    border = count[inv.ravel()] == 1  # an edge no other triangle of its chart shares
    length = np.hypot(ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1])
    perimeter = np.bincount(np.repeat(ch, 3)[border], length[border], k)
    width = 2.0 * area / np.maximum(perimeter, 1e-300)
    order = np.argsort(width, kind="stable")
    cum = np.cumsum(area[order])
    if cum[-1] <= 0:
        return 0.0
    return float(width[order][min(np.searchsorted(cum, share * cum[-1]), k - 1)])


def touching_share(mesh, texels) -> float:
    """The share of ``texels`` (rasterised through ``mesh.uv``) whose 3 x 3 neighbourhood, the
    footprint of a bilinear lookup, holds a texel of another UV chart (texels.chart_ids)."""
    from usdahd.bake.texels import chart_ids

    n = len(texels)
    if n == 0:
        return 0.0
    w, h = (int(r) for r in texels.resolution)
    grid = np.full((h + 2, w + 2), -1, np.int64)
    xy = np.asarray(texels.xy, np.int64)
    ch = chart_ids(mesh)[np.asarray(texels.triangle, np.int64)].astype(np.int64)
    grid[xy[:, 1] + 1, xy[:, 0] + 1] = ch
    touch = np.zeros(n, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx or dy:
                other = grid[xy[:, 1] + 1 + dy, xy[:, 0] + 1 + dx]
                touch |= (other >= 0) & (other != ch)
    return float(touch.mean())


def settings_resolution_given(job: PrimJob) -> bool:
    """Whether the resolution came from a flag or schema input rather than a texel density."""
    return job.settings.get("texel_density") is None


def _degenerate_uv_share(mesh, uv: np.ndarray, res) -> str | None:
    """A problem string when zero-area UV triangles cover more than UV_DEGENERATE_LIMIT of the
    mesh's surface (those triangles would get no lightmap texel at all)."""
    texel_area = uv_areas(uv) * res[0] * res[1]
    p = np.asarray(mesh.points, np.float64)[np.asarray(mesh.triangles, np.int64)]
    world = triangle_areas(p)
    total = world.sum()
    if total <= 0:
        return None
    share = world[texel_area < 1e-6].sum() / total
    if share > UV_DEGENERATE_LIMIT:
        return f"has zero-area UV triangles on {100 * share:.0f}% of the surface"
    return None


def _density_resolution(mesh, settings, scene, job: PrimJob) -> tuple[int, int]:
    from usdahd.bake.texels import resolution_for_density

    tpu = _texels_per_unit(settings, scene)
    try:
        w, h = resolution_for_density(mesh, tpu, max_resolution=MAX_RESOLUTION)
    except UsageError as exc:
        mpu = float(scene.meters_per_unit or 1.0)
        raise UsageError(
            f"{exc}; the stage's metersPerUnit is {mpu:g}, so {settings['texel_density']:g} "
            f"texels per metre are {tpu:.3g} per stage unit: check metersPerUnit, or pass "
            "--resolution"
        ) from None
    n = _sized(w, settings, job)
    if n is None:
        # On the automatic density the budget counted this clamp: a note, not a warning.
        kind = "notes" if _auto_density(settings) else "warnings"
        job.report.setdefault(kind, []).append(
            f"texel density {settings['texel_density']:g}/m needs {w}x{h}; clamped to "
            f"{DENSITY_MAX_RESOLUTION} (pass --resolution or author ahdLightmap:resolution)"
        )
        return DENSITY_MAX_RESOLUTION, DENSITY_MAX_RESOLUTION
    return n, n


def _sized(n: int, settings: dict, job: PrimJob) -> int | None:
    """A density-derived side ``n`` as baked: at least the automatic density's minimum (with a
    note), rounded up to a multiple of RESOLUTION_MULTIPLE; None above DENSITY_MAX_RESOLUTION."""
    if n > DENSITY_MAX_RESOLUTION:
        return None
    out = n
    if _auto_density(settings):
        low = int(settings.get("min_resolution") or MIN_RESOLUTION)
        if n < low:
            out = low
            job.report.setdefault("notes", []).append(
                f"the stage's texel density {settings['texel_density']:g}/m gives {n}x{n}; "
                f"raised to the minimum {low}x{low} (a denser map than its neighbours; pass "
                "--texel-density or author ahdLightmap:texelDensity to keep one density)"
            )
    return min(
        _round_up(out, int(settings.get("resolution_multiple") or 1)), DENSITY_MAX_RESOLUTION
    )


def _unwrap(job: PrimJob, mesh, settings, scene, prop_side: int = 0) -> None:
    from usdahd.bake.unwrap import CHART_PADDING, unwrap

    info: dict = {}
    low = int(settings.get("min_resolution") or 1) if _auto_density(settings) else 1
    if settings["resolution"]:
        uv, res = unwrap(
            mesh, resolution=int(settings["resolution"]), padding=CHART_PADDING, info=info
        )
    else:
        d = float(settings["texel_density"])
        try:
            if d * mesh_extent(mesh, scene.meters_per_unit) < low:
                raise _Small
            uv, res = unwrap(
                mesh,
                texels_per_unit=_texels_per_unit(settings, scene),
                padding=CHART_PADDING,
                max_resolution=DENSITY_MAX_RESOLUTION,
                info=info,
            )
            if res[0] * res[1] < low * low:
                raise _Small
        except _Small:
            try:
                uv, res = unwrap(mesh, resolution=low, padding=CHART_PADDING, info=info)
            except BakeError:  # more charts than low x low holds: as big as they need
                scale = low / max(d * mesh_extent(mesh, scene.meters_per_unit), 1e-9)
                uv, res = unwrap(
                    mesh,
                    texels_per_unit=_texels_per_unit(settings, scene) * scale,
                    padding=CHART_PADDING,
                    max_resolution=DENSITY_MAX_RESOLUTION,
                    info=info,
                )
                uv, res = _pad_to_multiple(uv, res, 1, minimum=low)
            job.report.setdefault("notes", []).append(
                f"the stage's texel density {d:g}/m gives this mesh fewer than {low}x{low} "
                f"texels; unwrapped into {res[0]}x{res[1]} (the minimum is {low}x{low}; pass "
                "--texel-density or author ahdLightmap:texelDensity to keep one density)"
            )
        except UsageError:
            job.report.setdefault("warnings", []).append(
                f"texel density {settings['texel_density']:g}/m needs an atlas above "
                f"{DENSITY_MAX_RESOLUTION}; packed into {DENSITY_MAX_RESOLUTION}x"
                f"{DENSITY_MAX_RESOLUTION} (pass --resolution to choose)"
            )
            uv, res = unwrap(
                mesh, resolution=DENSITY_MAX_RESOLUTION, padding=CHART_PADDING, info=info
            )
        uv, res = _pad_to_multiple(uv, res, int(settings.get("resolution_multiple") or 1))
        if low > 1:
            uv, res = _widen_charts(job, mesh, uv, res, prop_side, info)
    if info.get("split_polygons"):
        job.report.setdefault("notes", []).append(
            f"the unwrap's charts cut {info['split_polygons']} polygon(s); each is kept whole "
            f"({info['extended']} in a neighbouring chart, {info['own_chart']} as a chart of "
            "its own), so the faceVarying UVs authored are the UVs baked"
        )
    mesh.uv = uv
    job.unwrapped = True
    job.uv_primvar_values = uv
    job.resolution = tuple(int(r) for r in res)


def _widen_charts(job: PrimJob, mesh, uv, res, prop_side: int, info: dict):
    """An unwrap on the automatic density whose narrow charts (:func:`narrow_chart_width`) are
    less than CHART_MIN_TEXELS texels across, unwrapped again into the square map (at most
    ``prop_side``) where they are, with a note; else ``(uv, res)`` unchanged."""
    from usdahd.bake.unwrap import CHART_PADDING, unwrap

    scale = np.asarray(res, np.float64)
    width = narrow_chart_width(np.asarray(uv, np.float64) * scale)
    side = max(int(r) for r in res)
    if width >= CHART_MIN_TEXELS or side >= prop_side:
        return uv, res
    want = int(np.ceil(side * CHART_MIN_TEXELS / max(width, 1e-9)))
    want = min(_round_up(want, RESOLUTION_MULTIPLE), int(prop_side))
    try:
        new_uv, new_res = unwrap(mesh, resolution=want, padding=CHART_PADDING, info=info)
    except BakeError:
        return uv, res
    got = narrow_chart_width(np.asarray(new_uv, np.float64) * np.asarray(new_res, np.float64))
    job.report.setdefault("notes", []).append(
        f"the unwrap's narrowest charts (those holding {100 * NARROW_SHARE:.0f}% of its area) "
        f"were {width:.1f} texels across at {res[0]}x{res[1]}; unwrapped into "
        f"{new_res[0]}x{new_res[1]} instead ({got:.1f} texels; at least {CHART_MIN_TEXELS} "
        f"wanted, maps raised to at most {prop_side}x{prop_side} within the texel budget)"
    )
    job.raised_from = tuple(int(r) for r in res)
    return new_uv, tuple(int(r) for r in new_res)


class _Small(Exception):
    """The automatic density gives an unwrapped mesh less than its minimum map."""


def _pad_to_multiple(
    uv: np.ndarray, res, multiple: int, *, minimum: int = 1
) -> tuple[np.ndarray, tuple[int, int]]:
    """An atlas of ``res`` (w, h) placed in the top-left corner of the next (W, H) that are
    multiples of ``multiple`` and at least ``minimum``: texel (x, y) keeps its place
    (u' = u w / W, 1 - v' = (1 - v) h / H), the new columns and rows on the right and bottom are
    uncovered."""
    w, h = int(res[0]), int(res[1])
    big_w, big_h = (_round_up(max(n, minimum), multiple) for n in (w, h))
    if (big_w, big_h) == (w, h):
        return uv, (w, h)
    out = np.empty_like(uv, dtype=np.float64)
    out[..., 0] = np.asarray(uv[..., 0], np.float64) * (w / big_w)
    out[..., 1] = 1.0 - (1.0 - np.asarray(uv[..., 1], np.float64)) * (h / big_h)
    return out.astype(np.float32), (big_w, big_h)


def _previous_unwrap(old, old_layer, mesh, settings, uv_name: str):
    """UVs an earlier run unwrapped for this mesh, read back from its output layer, when the
    mesh's shape and every unwrap input are unchanged (so a re-run does not call xatlas
    again); else None. returns (uv (t, 3, 2) float32, resolution) or None."""
    from usdahd.usd import author

    if old is None or old_layer is None or old.uv_primvar != uv_name:
        return None
    prev = old.settings or {}
    same = (
        old.part_hashes.get("shape") == shape_digest(mesh).hexdigest()
        and prev.get("texel_density") == settings["texel_density"]
        and prev.get("meters_per_unit") == settings["meters_per_unit"]
        and all(prev.get(k) == settings.get(k) for k in _SIZE_KEYS)
        and (not settings["resolution"] or list(old.resolution) == [settings["resolution"]] * 2)
    )
    if not same:
        return None
    authored = author.authored_default(old_layer, mesh.path, f"primvars:{uv_name}")
    if authored is None:
        return None
    values = np.asarray(authored, dtype=np.float32)
    corner = np.asarray(mesh.corner)
    if values.ndim != 2 or values.shape[1] != 2 or corner.size and corner.max() >= len(values):
        return None
    return values[corner], tuple(int(r) for r in old.resolution)


#: Settings besides the density that decide an unwrap's size (settings.resolve_settings).
_SIZE_KEYS = ("min_resolution", "resolution_multiple")


def _reused_unwrap_problem(mesh, uv: np.ndarray, res) -> tuple[str | None, Texels | None]:
    """Check an unwrap read back from the previous output layer as an authored UV set is
    checked (what the validator's UVSet rule checks): returns (problem or None, its texels).
    An unwrap an older usdahd wrote can overlap itself: xatlas split polygons across charts
    and the faceVarying primvar kept one UV per polygon corner."""
    from usdahd.bake.texels import rasterize

    if not np.isfinite(uv).all():
        return "contains NaN or infinite UVs", None
    if (uv < 0).any() or (uv > 1).any():
        return "leaves [0, 1]", None
    problem = _degenerate_uv_share(mesh, np.asarray(uv, np.float64), res)
    if problem:
        return problem, None
    saved = mesh.uv
    mesh.uv = uv
    try:
        texels = rasterize(mesh, res)
    finally:
        mesh.uv = saved
    return _uv_problem(texels), texels


def _instance_uv_problem(mesh, uv_name: str, problem: str | None) -> None:
    """An instance copy cannot be unwrapped (its UVs live in the prototype, which the output
    layer cannot author without de-instancing): raise InputError naming the prototype mesh
    and the fix when its UV set is missing (``problem`` None) or unusable."""
    ref = getattr(mesh, "instance", None)
    if ref is None:
        return
    if problem is None:
        from usdahd.usd.reader import no_instance_uv_message

        raise InputError(f"{mesh.path}: " + no_instance_uv_message(ref.origin, uv_name, 1))
    raise InputError(
        f"{mesh.path}: the UV set {uv_name!r} of its prototype mesh {ref.origin} {problem}, so "
        "it cannot hold a lightmap and an instance copy cannot be unwrapped; fix the UV set in "
        "the asset or make the instance non-instanceable (instanceable = false)"
    )


def plan_job(
    scene,
    index: int,
    mesh,
    stage,
    opts: BakeOptions,
    report: dict,
    prev=None,
    old_layer=None,
    auto_density: float | None = None,
    prop_side: int = 0,
) -> PrimJob:
    """Resolve a mesh's settings, UVs (unwrapping if needed) and lightmap resolution
    (``auto_density``: the stage's automatic texel density, :func:`auto_texel_density`;
    ``prop_side``: the side a map on it may be raised to for its charts, :func:`prop_cap`)."""
    from usdahd.bake.texels import rasterize
    from usdahd.errors import SchemaError
    from usdahd.usd.stage import prim_at

    try:
        ref = getattr(mesh, "instance", None)  # an instance copy: its prototype's inputs
        authored = authored_inputs(prim_at(stage, ref.source if ref else mesh.path))
    except SchemaError as exc:
        raise InputError(str(exc)) from None
    settings = resolve_settings(opts, authored, scene.meters_per_unit, auto_density)
    record_time(settings, scene)
    if settings["resolution"] and not 1 <= int(settings["resolution"]) <= MAX_RESOLUTION:
        raise UsageError(
            f"{mesh.path}: resolution {settings['resolution']} is outside 1..{MAX_RESOLUTION}; "
            "lower --resolution or ahdLightmap:resolution"
        )
    uv_name = settings["uv"]
    if uv_name != mesh.uv_name:
        tc = scene.texcoords[index].get(uv_name) if index < len(scene.texcoords) else None
        mesh.uv, mesh.uv_name = tc, uv_name
    job = PrimJob(path=mesh.path, mesh=mesh, settings=settings, report=report)
    if mesh.uv is not None:
        uv = np.asarray(mesh.uv, np.float64)
        uv_area = uv_areas(uv).sum()
        texels, problem = None, None
        if not np.isfinite(uv).all():
            problem = "contains NaN or infinite UVs"
        elif uv_area <= 1e-12:
            problem = "has zero area (every UV is the same point or on a line)"
        else:
            if settings["resolution"]:
                res = (int(settings["resolution"]),) * 2
            else:
                res = _density_resolution(mesh, settings, scene, job)
            problem = _degenerate_uv_share(mesh, uv, res)
            if problem is None:
                texels = rasterize(mesh, res)
                problem = _uv_problem(texels)
        layout = None  # a usable UV set that is a poor lightmap layout (texture UVs)
        if problem is None and _auto_density(settings) and opts.unwrap:
            planned = tuple(int(r) for r in res)
            texels, res, layout = _texture_layout(mesh, uv_name, texels, res, prop_side, report)
            if layout is None and tuple(int(r) for r in res) != planned:
                job.raised_from = planned
        if problem is None and layout is None:
            job.texels, job.resolution = texels, res
        else:
            _instance_uv_problem(mesh, uv_name, problem)
            new = f"{uv_name}_lightmap"
            if not opts.unwrap:
                raise InputError(
                    f"{mesh.path}: UV set {uv_name!r} {problem}, so it cannot hold a lightmap; "
                    f"author a lightmap UV set (--uv) or drop --no-unwrap to unwrap into {new!r}"
                )
            kind = "warnings" if layout is None else "notes"
            report.setdefault(kind, []).append(
                f"UV set {uv_name!r} {problem or layout}: unwrapped with xatlas into a new "
                f"primvar {new!r} (authored in the output layer; {uv_name!r} is left as it is)"
            )
            mesh.uv, mesh.uv_name = None, new
            settings["uv"] = new
    if mesh.uv is None:
        _instance_uv_problem(mesh, uv_name, None)
        if not opts.unwrap:
            raise InputError(
                f"{mesh.path}: no lightmap UV primvar {uv_name!r} and unwrapping is off "
                "(--no-unwrap); author the primvar, pick another with --uv, or drop --no-unwrap"
            )
        reuse = _previous_unwrap(
            (prev or {}).get(mesh.path), old_layer, mesh, settings, settings["uv"]
        )
        if reuse is not None:
            why, texels = _reused_unwrap_problem(mesh, *reuse)
            if why:
                report["warnings"].append(
                    f"{mesh.path}: the xatlas unwrap {settings['uv']!r} authored by the "
                    f"previous bake {why}, so it is not reused: unwrapped again into "
                    f"{settings['uv']!r} (the re-bake replaces it)"
                )
                reuse = None
            else:
                job.texels = texels
        if reuse is not None:
            mesh.uv, res = reuse
            job.unwrapped = True
            job.uv_primvar_values = mesh.uv
            job.resolution = res
            report.setdefault("notes", []).append(
                f"no usable UV set {uv_name!r}: reusing the xatlas unwrap {settings['uv']!r} "
                "authored by the previous bake (mesh unchanged)"
            )
        else:
            mesh.uv = None
            _unwrap(job, mesh, settings, scene, prop_side)
    settings["resolution"] = list(job.resolution)
    return job


def _texture_layout(mesh, uv_name: str, texels, res, prop_side: int, report: dict):
    """Whether a valid authored UV set (on the automatic density) is a usable lightmap layout:
    a texture UV layout packs its charts edge to edge, so at the planned size texels next to
    another chart mix two surfaces in a bilinear lookup (TOUCHING_LIMIT; TOUCHING_TARGET when
    its narrowest charts are under CHART_MIN_TEXELS across: all border). The map is doubled
    (up to ``prop_side``) until few texels touch another chart (TOUCHING_TARGET), keeping the
    asset's UVs (with a note); if even that is not enough the mesh is unwrapped instead, except
    an instance copy (it cannot be, and keeps the largest map). Returns (texels, res, None) to
    bake the UV set at ``res``, or (None, res, why) to unwrap."""
    from usdahd.bake.texels import rasterize

    share = touching_share(mesh, texels)
    if share <= TOUCHING_TARGET:
        return texels, res, None
    side = int(res[0])
    narrow = narrow_chart_width(np.asarray(mesh.uv, np.float64)) * side
    if share <= TOUCHING_LIMIT and narrow >= CHART_MIN_TEXELS:
        return texels, res, None
    first, first_share = tuple(res), share
    why = (
        f"packs its charts with no lightmap gutter (at {first[0]}x{first[1]}, "
        f"{100 * first_share:.0f}% of its texels lie next to another chart's"
        + (
            f", its narrowest charts {narrow:.1f} texels across"
            if narrow < CHART_MIN_TEXELS
            else ""
        )
        + ", so a bilinear lookup there mixes unrelated surfaces)"
    )
    while share > TOUCHING_TARGET and side < prop_side:
        side = min(_round_up(2 * side, RESOLUTION_MULTIPLE), int(prop_side))
        res = (side, side)
        texels = rasterize(mesh, res)
        share = touching_share(mesh, texels)
    instance = getattr(mesh, "instance", None) is not None
    if share > TOUCHING_LIMIT and not instance:
        return None, first, f"{why}, also at {res[0]}x{res[1]} ({100 * share:.0f}%)"
    if res != first or share > TOUCHING_LIMIT:
        fix = (
            "an instance copy cannot be unwrapped, so its map is raised to"
            if share > TOUCHING_LIMIT
            else "its map is raised to"
        )
        report.setdefault("notes", []).append(
            f"UV set {uv_name!r} {why}; {fix} {res[0]}x{res[1]} ({100 * share:.0f}% of its "
            "texels next to another chart's; author a lightmap UV set with gutters to keep the "
            "stage's density)"
        )
    return texels, res, None


#: Settings that only change the fit and encoding of the baked SH, never the SH: a change of
#: only these refits from the previous bake's float32 SH sidecar instead of tracing.
REFIT_SETTINGS = ("model", "ratio", "solver", "padding", "container")


def settings_as_stored(settings: dict) -> dict:
    """Settings as the layer stores them (JSON round trip: tuples become lists)."""
    return json.loads(json.dumps(settings, sort_keys=True, default=str))


def refit_source(job: PrimJob, old, changed: list[str]) -> str | None:
    """The previous bake's SH sidecar when ``job`` differs from it only in REFIT_SETTINGS (same
    geometry, UVs, lights, materials, baker, resolution), and the sidecar is the file that bake
    wrote (digest); else None (trace again)."""
    if not changed or set(changed) != {"settings"}:
        return None
    a, b = settings_as_stored(old.settings), settings_as_stored(job.settings)
    if {k for k in set(a) | set(b) if a.get(k) != b.get(k)} - set(REFIT_SETTINGS):
        return None
    side = old.textures.get("sh")
    if side is None or not Path(side).is_file() or tuple(old.resolution) != tuple(job.resolution):
        return None
    from usdahd.usd import schema

    want = old.digests.get("sh")
    if not want or schema.file_digest(side) != want:
        return None
    return side
