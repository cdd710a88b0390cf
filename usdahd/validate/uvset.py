"""Rule ``UVSet``: the lightmap UV primvar exists, lies in [0, 1] and does not overlap."""

from __future__ import annotations

import math

import numpy as np

from usdahd.numerics.raster import coverage, fan_triangulate
from usdahd.numerics.triangles import triangle_areas, uv_areas
from usdahd.usd import inspect
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import baked_record
from usdahd.validate.options import OPTIONS

__all__ = ["check_uv_set", "overlap_statistic"]

# ------------------------------------------------------------------------------ rule 7: UVSet


def overlap_statistic(uv: np.ndarray, resolution) -> tuple[int, int, np.ndarray]:
    """The baker's UV-overlap statistic (``usdahd.pipeline.plan`` unwraps above
    ``UV_OVERLAP_LIMIT``): covered texels (conservative, as the bake rasterises them), texels
    whose centre lies strictly inside two or more triangles, and those texels' (x, y) (m, 2),
    row-major. Both come from :func:`usdahd.numerics.raster.rasterize_uv`, the baker's own
    rasteriser, so a UV set the baker accepts passes the UVSet rule.

    uv : (t, 3, 2) float, finite. resolution : (w, h).
    """
    w = int(resolution[0])
    covered, ids = coverage(uv, resolution)  # rasterize_uv's texels, without its samples
    return len(covered), len(ids), np.stack([ids % w, ids // w], axis=1)


def check_uv_set(prim) -> list[Finding]:
    """Rule UVSet (see RULES)."""
    r = RuleFindings("UVSet", prim)
    results = baked_record(prim)
    if results is None or not results.uv_primvar:
        return r.out
    name = results.uv_primvar
    ptype = inspect.primvar_type(prim, name)
    if ptype is None:
        r.error(
            "MissingUVSet",
            f"primvars:{name} (ahdLightmap:baked:uvPrimvar) does not exist or has no value",
            "re-bake the prim (the bake authors the UV set it unwrapped) or restore the primvar",
        )
        return r.out
    if not ptype[1]:
        r.error(
            "UVSetType",
            f"primvars:{name} is {ptype[0]}, not a float2/texCoord2f array",
            "author the lightmap UVs as texCoord2f[]",
        )
        return r.out
    uv = inspect.corner_uvs(prim, name)
    if uv is None or uv.size == 0:
        r.error("MissingUVSet", f"primvars:{name} has no values", "re-bake the prim")
        return r.out
    if not np.isfinite(uv).all():
        r.error("NonFiniteUV", f"primvars:{name} holds NaN or Inf", "re-unwrap and re-bake")
        return r.out
    udim = "<UDIM>" in "".join(results.asset_paths.values())
    eps = OPTIONS.uv_epsilon
    if not udim:
        out = (uv < -eps) | (uv > 1.0 + eps)
        if out.any():
            r.error(
                "UVOutOfRange",
                f"{int(out.any(axis=2).any(axis=1).sum())} triangle(s) of primvars:{name} "
                f"leave [0, 1] (range u {uv[..., 0].min():.4g}..{uv[..., 0].max():.4g}, "
                f"v {uv[..., 1].min():.4g}..{uv[..., 1].max():.4g}); a lightmap does not tile",
                "re-unwrap the lightmap UV set into [0, 1] and re-bake",
            )
            return r.out
        covered, over, xy = overlap_statistic(uv, results.resolution)
        if covered and over > OPTIONS.uv_overlap * covered:
            xs, ys = xy[:, 0], xy[:, 1]
            r.error(
                "UVOverlap",
                f"{over} of {covered} covered texels ({100.0 * over / covered:.2g}%) have "
                f"their centre in more than one triangle of primvars:{name}, first at texel "
                f"({xs[0]}, {ys[0]}); "
                f"overlapping charts share (and fight over) lightmap texels",
                "re-unwrap without overlaps (usdahd bake unwraps when the UV set is missing)",
                overlapping=over,
                covered=covered,
                texel=(int(xs[0]), int(ys[0])),
            )
    # Texel density: texels per unit of world area per triangle.
    pts, counts, fvi = inspect.mesh_topology(prim)
    if len(pts) and len(fvi):
        m = inspect.local_to_world(prim)
        wp = pts @ m[:3, :3].T + m[:3, 3]
        tri = wp[fvi[fan_triangulate(counts)[1]]]
        area = triangle_areas(tri)
        w, h = results.resolution
        uv_area = uv_areas(uv) * w * h
        total = float(area.sum())
        if total > 0:
            zero = (uv_area <= 1e-12) & (area > 0)
            if area[zero].sum() > 0.01 * total:
                r.warning(
                    "DegenerateUV",
                    f"{int(zero.sum())} triangle(s) ({100 * area[zero].sum() / total:.2g}% of "
                    f"the surface) have zero area in primvars:{name} and get no lightmap texels",
                    "re-unwrap the lightmap UV set",
                )
            ok = (uv_area > 1e-12) & (area > 0)
            if ok.sum() >= 2:
                dens = np.sqrt(uv_area[ok] / area[ok])
                order = np.argsort(dens)
                cw = np.cumsum(area[ok][order]) / area[ok].sum()
                p10 = dens[order][np.searchsorted(cw, 0.1)]
                p90 = dens[order][min(np.searchsorted(cw, 0.9), len(cw) - 1)]
                spread = float(p90 / p10) if p10 > 0 else math.inf
                if spread > OPTIONS.density_spread:
                    r.warning(
                        "TexelDensity",
                        f"texel density varies {spread:.3g}x across the mesh (area-weighted "
                        f"10th..90th percentile {p10:.3g}..{p90:.3g} texels per unit)",
                        "re-unwrap with uniform texel density",
                        spread=spread,
                    )
    return r.out
