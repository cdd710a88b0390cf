"""Scalar shading helpers of the native integrator: light choice, MIS weights, shadow rays and
UsdLux light linking (numba twins of :class:`usdahd.bake.reference.ReferenceCtx`'s methods).

``lt`` is the :class:`~usdahd.bake.kernels.layout.LightArrays` of
:func:`usdahd.bake.kernels.lights.pack_lights`, ``tb`` the tracer's
:class:`~usdahd.bake.kernels.layout.NativeTables`. Parity: tests/test_kernel_parity.py.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.kernels import cache  # noqa: F401  (numba cache locators, before any @njit)
from usdahd.bake.kernels.cache import helper
from usdahd.bake.kernels.layout import (
    KIND_EMISSIVE,
    MAT_EMISSION,
    MODE_BSDF,
    MODE_MIS,
    MODE_NEE,
    PAR_EM_COUNT,
    PAR_EM_PDF_AREA,
    PAR_EM_TABLE,
    PAR_EM_TRI,
    PATH_X,
    RAY_D,
    RAY_O,
    RAY_TFAR,
    TEX_EMISSION,
    LightSample,
)
from usdahd.bake.kernels.lights import light_importance, light_sample, search_right
from usdahd.bake.kernels.trace import (
    nb_emission,
    nb_hit_point,
    nb_trace,
    nb_transmittance,
    nb_transmittance_rays,
)
from usdahd.bake.reference import LIGHT_SELECTION_FLOOR, LINK_MAX_CROSSINGS, SHADOW_SHORTEN

__all__ = [
    "link_occluded",
    "lit",
    "nee_pick",
    "nee_sample",
    "put3",
    "put_ray",
    "ray_sel",
    "shadow1",
    "shadow_rays",
    "visibility",
    "w_bsdf",
    "w_light",
]


@helper
def nee_sample(kind, p, img, pmf, cdf, tb, x, y, z, u0, u1):
    """``light_sample`` for every kind, including the emissive triangles (``EmissiveTriangles``
    .sample: triangle by power, uniform point, emission looked up in the material tables):
    a :class:`~usdahd.bake.kernels.layout.LightSample`."""
    if kind != KIND_EMISSIVE:
        return light_sample(kind, p, img, pmf, cdf, x, y, z, u0, u1)
    base, ne = int(p[PAR_EM_TABLE]), int(p[PAR_EM_COUNT])
    k = search_right(cdf, base, ne, u0)
    lo = cdf[base + k - 1] if k > 0 else 0.0
    pk = pmf[base + k]
    uu = min(max((u0 - lo) / max(pk, 1e-300), 0.0), 1.0)
    su = np.sqrt(uu)
    bu, bv = 1.0 - su, u1 * su
    tri = int(pmf[int(p[PAR_EM_TRI]) + k])
    qx, qy, qz = nb_hit_point(tb, tri, bu, bv)
    wx, wy, wz = qx - x, qy - y, qz - z
    dist = np.sqrt(wx * wx + wy * wy + wz * wz)
    inv = 1.0 / max(dist, 1e-300)
    dx, dy, dz = wx * inv, wy * inv, wz * inv
    g = tb.geom_normal
    cos_l = -(dx * g[tri, 0] + dy * g[tri, 1] + dz * g[tri, 2])
    if tb.tri_one_sided[tri] == 0:  # doubleSided: both faces emit
        cos_l = abs(cos_l)
    if not cos_l > 0.0:
        return LightSample(dx, dy, dz, dist, 0.0, 0.0, 0.0, 0.0)
    pdf = pmf[int(p[PAR_EM_PDF_AREA]) + tri] * dist * dist / cos_l
    mq = tb.tri_material[tri]
    if tb.mat_tex[mq, TEX_EMISSION] < 0:
        mc = tb.mat_const
        r, gg, b = mc[mq, MAT_EMISSION], mc[mq, MAT_EMISSION + 1], mc[mq, MAT_EMISSION + 2]
    else:
        r, gg, b = nb_emission(tb, tri, bu, bv)
    return LightSample(dx, dy, dz, dist, r, gg, b, pdf)


@helper
def w_light(mode, pl, pb):
    """``reference._w_light`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return power(pl, pb)
    return 1.0 if mode == MODE_NEE else 0.0


@helper
def w_bsdf(mode, pb, pl):
    """``reference._w_bsdf`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return power(pb, pl)
    return 1.0 if mode == MODE_BSDF else 0.0


@helper
def power(a, b):
    """The power heuristic (beta 2) weight of strategy a (``reference._power``)."""
    den = a * a + b * b
    return a * a / den if den > 0.0 else 0.0


@helper
def shadow1(ox, oy, oz, px, py, pz, dx, dy, dz, dist):
    """``reference._shadow`` for one ray: returns (dx, dy, dz, tfar)."""
    if not np.isfinite(dist):
        return dx, dy, dz, np.inf
    wx, wy, wz = px + dist * dx - ox, py + dist * dy - oy, pz + dist * dz - oz
    ln = np.sqrt(wx * wx + wy * wy + wz * wz)
    if not ln > 0.0:
        return dx, dy, dz, 0.0
    return wx / ln, wy / ln, wz / ln, ln * (1.0 - SHADOW_SHORTEN)


@helper
def put3(a, j, col, x, y, z):
    """``a[j, col:col + 3] = (x, y, z)`` (a named 3-slot field of a row record)."""
    a[j, col] = x
    a[j, col + 1] = y
    a[j, col + 2] = z


@helper
def put_ray(rays, j, ox, oy, oz, dx, dy, dz, tfar):
    """Ray row ``j`` (``RAY_*`` slots): origin, direction, tfar."""
    put3(rays, j, RAY_O, ox, oy, oz)
    put3(rays, j, RAY_D, dx, dy, dz)
    rays[j, RAY_TFAR] = tfar


@helper
def nee_pick(par, nee_idx, x, y, z, u):
    """``scene.lights.selection_pmf`` at the vertex (x, y, z), sampled with ``u`` in [0, 1):
    returns (light index q, its selection probability)."""
    n = nee_idx.shape[0]
    tot = 0.0
    for j in range(n):
        tot += light_importance(par[nee_idx[j]], x, y, z)
    uni = LIGHT_SELECTION_FLOOR / n
    keep = (1.0 - LIGHT_SELECTION_FLOOR) / tot if tot > 0.0 else 0.0
    if keep == 0.0:
        uni = 1.0 / n
    acc = 0.0
    for j in range(n):
        q = nee_idx[j]
        pj = uni + keep * light_importance(par[q], x, y, z)
        acc += pj
        if u < acc or j == n - 1:
            return q, pj
    return nee_idx[n - 1], uni  # not reached (n >= 1)


@helper
def nee_sel(par, nee_idx, q, x, y, z):
    """The probability :func:`nee_pick` at (x, y, z) chooses light ``q`` (for MIS at hits)."""
    n = nee_idx.shape[0]
    tot = 0.0
    for j in range(n):
        tot += light_importance(par[nee_idx[j]], x, y, z)
    if not (tot > 0.0):
        return 1.0 / n
    return LIGHT_SELECTION_FLOOR / n + (1.0 - LIGHT_SELECTION_FLOOR) * (
        light_importance(par[q], x, y, z) / tot
    )


@helper
def ray_sel(par, nee_idx, area_idx, ps, j, sel, q):
    """Selection probability of light ``q`` in the NEE that path row ``j``'s ray is paired
    with (for the MIS weight when the ray hits ``q``): ``sel`` itself when >= 0, else the
    choice made at the point the ray left (PATH_X): over ``nee_idx`` at a vertex (-1), over
    ``area_idx`` at a texel with many lights (-2)."""
    if sel >= 0.0:
        return sel
    lst = nee_idx if sel > -1.5 else area_idx
    return nee_sel(par, lst, q, ps[j, PATH_X], ps[j, PATH_X + 1], ps[j, PATH_X + 2])


# ----------------------------------------------------------------------------- light linking
@helper
def lit(lt, q, mesh):
    """``ReferenceCtx._lit``: light ``q`` lights receivers of scene mesh ``mesh`` (-1:
    unknown, lit)."""
    return mesh < 0 or lt.recv[q, mesh]


@helper
def link_occluded(scene, rec, tb, lt, q, transmission, st, ox, oy, oz, dx, dy, dz, tfar):
    """``ReferenceCtx._occluded`` for one shadow ray of the shadow-linked light ``q``: only
    meshes its shadowLink includes block it; others are passed through (up to
    LINK_MAX_CROSSINGS surfaces). returns (occluded, rays traced)."""
    rays = 0
    for _ in range(LINK_MAX_CROSSINGS):
        h = nb_trace(scene, rec, tb, transmission, st, ox, oy, oz, dx, dy, dz, tfar)
        rays += h.rays
        if h.tri < 0:
            return False, rays
        if lt.cast[q, tb.tri_mesh[h.tri]]:
            return True, rays
        step = h.t + tb.tri_offset[h.tri]  # a non-caster: continue past it
        ox, oy, oz = ox + step * dx, oy + step * dy, oz + step * dz
        tfar = tfar - step
        if not (tfar > 0.0):
            return False, rays
    return False, rays


@helper
def visibility(scene, rec, tb, lt, q, transmission, st, ox, oy, oz, dx, dy, dz, tfar):
    """``ReferenceCtx._visibility`` for one shadow ray of light ``q``: (fraction of its
    light that arrives, rays traced)."""
    if not lt.shadow_linked[q]:
        return nb_transmittance(scene, rec, tb, transmission, ox, oy, oz, dx, dy, dz, tfar)
    occ, rays = link_occluded(scene, rec, tb, lt, q, transmission, st, ox, oy, oz, dx, dy, dz,
                              tfar)  # fmt: skip
    return (0.0 if occ else 1.0), rays


@helper
def shadow_rays(scene, pk, rec, tb, lt, transmission, shadow_linked, st, srays, slight, n, out):
    """Visibility of the queued shadow rays ``srays[:n]`` (of the lights ``slight[:n]``) into
    ``out[:n]``: 16-ray packets (``nb_transmittance_rays``) unless some light is
    shadow-linked, then one ray at a time through :func:`visibility`. returns rays traced."""
    if not shadow_linked:
        return nb_transmittance_rays(scene, pk, rec, tb, transmission, srays, n, out)
    total = 0
    for r in range(n):
        tr, k = visibility(
            scene, rec, tb, lt, slight[r], transmission, st, srays[r, RAY_O],
            srays[r, RAY_O + 1], srays[r, RAY_O + 2], srays[r, RAY_D], srays[r, RAY_D + 1],
            srays[r, RAY_D + 2], srays[r, RAY_TFAR],
        )  # fmt: skip
        out[r] = tr
        total += k
    return total
