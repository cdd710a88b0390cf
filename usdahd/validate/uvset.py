"""Rule ``UVSet``: the lightmap UV primvar exists, lies in [0, 1] and does not overlap."""

from __future__ import annotations

import math

import numpy as np

from usdahd.numerics.raster import fan_triangulate, uv_to_pixel
from usdahd.usd import inspect, schema
from usdahd.validate.findings import Finding, _Rule
from usdahd.validate.options import OPTIONS

# ------------------------------------------------------------------------------ rule 7: UVSet


def texel_coverage(uv: np.ndarray, resolution: tuple[int, int]) -> np.ndarray:
    """How many triangles cover each texel centre: (h, w) int32 (row 0 = top, v = 1).

    uv : (t, 3, 2) float. A centre on an edge counts for one side only (top-left rule), so
    triangles sharing an edge do not double-count it.
    """
    w, h = resolution
    px = uv_to_pixel(uv, (w, h))
    return _coverage_kernel(np.ascontiguousarray(px), int(w), int(h))


def _coverage_kernel_py(px, w, h):
    count = np.zeros((h, w), np.int32)
    for t in range(px.shape[0]):
        ax, ay = px[t, 0]
        bx, by = px[t, 1]
        cx, cy = px[t, 2]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0 or not math.isfinite(area):
            continue
        if area < 0.0:  # make every triangle counter-clockwise in pixel space
            bx, by, cx, cy = cx, cy, bx, by
        x0 = max(int(math.floor(min(ax, bx, cx) - 0.5)), 0)
        x1 = min(int(math.ceil(max(ax, bx, cx) - 0.5)), w - 1)
        y0 = max(int(math.floor(min(ay, by, cy) - 0.5)), 0)
        y1 = min(int(math.ceil(max(ay, by, cy) - 0.5)), h - 1)
        e = ((ax, ay, bx, by), (bx, by, cx, cy), (cx, cy, ax, ay))
        for y in range(y0, y1 + 1):
            qy = y + 0.5
            for x in range(x0, x1 + 1):
                qx = x + 0.5
                inside = True
                for k in range(3):
                    sx, sy, ex, ey = e[k]
                    f = (ex - sx) * (qy - sy) - (ey - sy) * (qx - sx)
                    if f < 0.0:
                        inside = False
                        break
                    if f == 0.0:  # top-left rule: keep edges going up or exactly left
                        dy, dx = ey - sy, ex - sx
                        if not (dy < 0.0 or (dy == 0.0 and dx < 0.0)):
                            inside = False
                            break
                if inside:
                    count[y, x] += 1
    return count


try:
    from numba import njit

    _coverage_kernel = njit(cache=True, fastmath=False)(_coverage_kernel_py)
except ImportError:  # pragma: no cover
    _coverage_kernel = _coverage_kernel_py


def check_uv_set(prim) -> list[Finding]:
    """Rule UVSet (see RULES)."""
    r = _Rule("UVSet", prim)
    try:
        results = schema.read_results(prim, validate=False)
    except Exception:
        return r.out
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
        cov = texel_coverage(uv, results.resolution)
        covered = int((cov > 0).sum())
        over = int((cov > 1).sum())
        if covered and over > OPTIONS.uv_overlap * covered:
            ys, xs = np.nonzero(cov > 1)
            r.error(
                "UVOverlap",
                f"{over} of {covered} covered texels ({100.0 * over / covered:.2g}%) lie in "
                f"more than one triangle of primvars:{name}, first at texel ({xs[0]}, {ys[0]}); "
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
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        w, h = results.resolution
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * w * h
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
