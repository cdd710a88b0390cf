"""Numba light sampling: the lights of :mod:`usdahd.scene.lights` packed into flat tables.

:func:`pack_lights` flattens the numpy light objects into a :class:`LightTable`; the scalar
``@njit`` routines below (:func:`light_sample`, :func:`light_intersect`, :func:`light_pdf`)
mirror the numpy ``sample``/``intersect``/``pdf`` methods of :mod:`usdahd.scene.lights` line by
line (parity: tests/test_lights.py, tests/test_kernel_parity.py). The parameter rows are named
in :mod:`usdahd.bake.kernels.layout`.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.kernels import cache  # noqa: F401  (numba cache locators, before any @njit)
from usdahd.bake.kernels.cache import helper
from usdahd.bake.kernels.layout import (
    KIND_CYLINDER,
    KIND_DISK,
    KIND_DISTANT,
    KIND_DOME,
    KIND_POINT,
    KIND_RECT,
    KIND_SPHERE,
    LIGHT_KINDS,
    LIGHT_PARAMS,
    N_PAR,
    PAR_AREA,
    PAR_AXIS,
    PAR_CENTER,
    PAR_COS_MAX,
    PAR_CYL_E1,
    PAR_CYL_E2,
    PAR_DIRECTION,
    PAR_DOME_H,
    PAR_DOME_INV_ROT,
    PAR_DOME_PIX,
    PAR_DOME_PMF,
    PAR_DOME_ROT,
    PAR_DOME_TEXTURED,
    PAR_DOME_W,
    PAR_EX,
    PAR_EY,
    PAR_GINV,
    PAR_HALF_LENGTH,
    PAR_IMP_CAP,
    PAR_IMP_CENTER,
    PAR_IMP_FALLOFF,
    PAR_IMP_NORMAL,
    PAR_IMP_R2,
    PAR_IMP_SCALE,
    PAR_NORMAL,
    PAR_OMC,
    PAR_PLANE_N,
    PAR_RADIANCE,
    PAR_RADIUS,
    PAR_RECT_ORTHO,
    LightArrays,
    LightSample,
)
from usdahd.numerics.sampling import SPHERICAL_RECT_MAX_SR, SPHERICAL_RECT_MIN_SR
from usdahd.scene.lights import FALLOFF_CONSTANT, FALLOFF_FRONT

__all__ = [
    "light_importance",
    "light_intersect",
    "light_pdf",
    "light_sample",
    "nb_basis_apply",
    "pack_lights",
    "search_right",
]

# ----------------------------------------------------------------------------- native tables
# The same lights as flat arrays for the numba integrator (usdahd.bake.integrate), one scalar
# routine per operation below mirroring the numpy methods of usdahd.scene.lights line by line.
# Each light class declares and writes its own parameters (``FIELDS``, ``pack``).


class LightBlocks:
    """The per-pixel tables lights share (dome images and their sampling tables, emissive
    triangle tables): ``add`` appends equal-length blocks and returns their offset. Row 0 is
    a dummy (img 0, pmf 0, cdf 1), so no light's offset is 0."""

    def __init__(self):
        self.img, self.pmf, self.cdf = [np.zeros((1, 3))], [np.zeros(1)], [np.ones(1)]
        self.size = 1

    def add(self, img, pmf, cdf) -> int:
        """Append (k, 3), (k,), (k,) blocks; returns the offset of their first row."""
        at = self.size
        self.img.append(img)
        self.pmf.append(pmf)
        self.cdf.append(cdf)
        self.size += len(pmf)
        return at


def pack_lights(lights, n_meshes: int = 0) -> LightArrays:
    """Flatten Light objects into :class:`~usdahd.bake.kernels.layout.LightArrays` (order
    preserved): per light its kind, the common fields (radiance, selection bound) and the
    fields its class declares and packs (:meth:`usdahd.scene.lights.Light.pack`); light
    linking masks over ``n_meshes`` scene meshes (``lit_meshes`` / ``shadow_meshes``)."""
    n = len(lights)
    kinds = {cls: i for i, cls in enumerate(LIGHT_KINDS)}
    kind = np.zeros(n, np.int64)
    par = np.zeros((max(n, 1), N_PAR))
    blocks = LightBlocks()
    nm = max(int(n_meshes), 1)
    recv = np.ones((max(n, 1), nm), bool)
    cast = np.ones((max(n, 1), nm), bool)
    shadow_linked = np.zeros(n, bool)
    for i, lt in enumerate(lights):
        kind[i] = kinds[type(lt)]

        def fill(rec, lt=lt):
            rec.radiance = lt.radiance
            bd = lt.bound()
            rec.imp_falloff, rec.imp_scale, rec.imp_r2 = bd.falloff, bd.scale, bd.r2
            rec.imp_cap, rec.imp_center, rec.imp_normal = bd.cap, bd.center, bd.normal
            lt.pack(rec, blocks)

        LIGHT_PARAMS.pack(par[i], lt.KIND, fill)
        if lt.lit_meshes is not None:
            recv[i] = False
            recv[i, np.asarray(lt.lit_meshes, np.int64)] = True
        if lt.shadow_meshes is not None:
            shadow_linked[i] = True
            cast[i] = False
            cast[i, np.asarray(lt.shadow_meshes, np.int64)] = True
    return LightArrays(
        kind=kind,
        par=par,
        img=np.ascontiguousarray(np.concatenate(blocks.img), np.float64),
        pmf=np.concatenate(blocks.pmf).astype(np.float64),
        cdf=np.concatenate(blocks.cdf).astype(np.float64),
        delta=np.array([bool(lt.delta) for lt in lights], bool),
        infinite=np.array([bool(lt.infinite) for lt in lights], bool),
        sampled=np.array([bool(lt.sampled) for lt in lights], bool),
        recv=recv,
        shadow_linked=shadow_linked,
        cast=cast,
    )


TWO_PI = 2.0 * np.pi
_INF = np.inf


@helper
def nb_basis_apply(nx, ny, nz, lx, ly, lz):
    """local (lx,ly,lz) in the Duff et al. frame around unit n -> world direction."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + sign * nx * nx * a, sign * b, -sign * nx
    bx, by, bz = b, sign + ny * ny * a, -ny
    return (
        lx * tx + ly * bx + lz * nx,
        lx * ty + ly * by + lz * ny,
        lx * tz + ly * bz + lz * nz,
    )


@helper
def _cone(ax, ay, az, omc, u0, u1):
    # numba twin of numerics.sampling.cone_local (the one cone rule), turned onto the axis
    z = 1.0 - u0 * omc
    phi = TWO_PI * u1
    s = np.sqrt(max(u0 * omc * (1.0 + z), 0.0))
    return nb_basis_apply(ax, ay, az, s * np.cos(phi), s * np.sin(phi), z)


@helper
def _sphere_hit_t(p, ox, oy, oz, dx, dy, dz):
    cx, cy, cz = ox - p[PAR_CENTER], oy - p[PAR_CENTER + 1], oz - p[PAR_CENTER + 2]
    b = cx * dx + cy * dy + cz * dz
    c = cx * cx + cy * cy + cz * cz - p[PAR_RADIUS] * p[PAR_RADIUS]
    disc = b * b - c
    if disc >= 0.0 and c > 0.0:
        t = -b - np.sqrt(disc)
        if t > 0.0:
            return t
    return _INF


@helper
def _sphere_omc(p, x, y, z):
    wx, wy, wz = p[PAR_CENTER] - x, p[PAR_CENTER + 1] - y, p[PAR_CENTER + 2] - z
    d2 = wx * wx + wy * wy + wz * wz
    r2 = p[PAR_RADIUS] * p[PAR_RADIUS]
    outside = d2 > r2
    sin2 = r2 / d2 if outside else 1.0
    cos_max = np.sqrt(max(1.0 - sin2, 0.0))
    return wx, wy, wz, d2, outside, sin2 / (1.0 + cos_max)


@helper
def _cyl_hit(p, ox, oy, oz, dx, dy, dz):
    ax, ay, az = p[PAR_AXIS], p[PAR_AXIS + 1], p[PAR_AXIS + 2]
    cx, cy, cz = ox - p[PAR_CENTER], oy - p[PAR_CENTER + 1], oz - p[PAR_CENTER + 2]
    oa = cx * ax + cy * ay + cz * az
    da = dx * ax + dy * ay + dz * az
    opx, opy, opz = cx - oa * ax, cy - oa * ay, cz - oa * az
    dpx, dpy, dpz = dx - da * ax, dy - da * ay, dz - da * az
    a = dpx * dpx + dpy * dpy + dpz * dpz
    b = opx * dpx + opy * dpy + opz * dpz
    c = opx * opx + opy * opy + opz * opz - p[PAR_RADIUS] * p[PAR_RADIUS]
    disc = b * b - a * c
    if not (a > 1e-18 and disc >= 0.0 and c > 0.0):
        return False, _INF, 0.0, 0.0, 0.0
    t = (-b - np.sqrt(disc)) / a
    hx, hy, hz = cx + t * dx, cy + t * dy, cz + t * dz
    x = hx * ax + hy * ay + hz * az
    if not (t > 0.0 and abs(x) <= p[PAR_HALF_LENGTH]):
        return False, _INF, 0.0, 0.0, 0.0
    return True, t, hx - x * ax, hy - x * ay, hz - x * az


@helper
def _planar_hit(kind, p, ox, oy, oz, dx, dy, dz):
    den = dx * p[PAR_PLANE_N] + dy * p[PAR_PLANE_N + 1] + dz * p[PAR_PLANE_N + 2]
    if abs(den) <= 1e-12:
        return False, _INF
    t = (
        (p[PAR_CENTER] - ox) * p[PAR_PLANE_N]
        + (p[PAR_CENTER + 1] - oy) * p[PAR_PLANE_N + 1]
        + (p[PAR_CENTER + 2] - oz) * p[PAR_PLANE_N + 2]
    ) / den
    qx, qy, qz = (
        ox + t * dx - p[PAR_CENTER],
        oy + t * dy - p[PAR_CENTER + 1],
        oz + t * dz - p[PAR_CENTER + 2],
    )
    r0 = qx * p[PAR_EX] + qy * p[PAR_EX + 1] + qz * p[PAR_EX + 2]
    r1 = qx * p[PAR_EY] + qy * p[PAR_EY + 1] + qz * p[PAR_EY + 2]
    a = p[PAR_GINV] * r0 + p[PAR_GINV + 1] * r1
    b = p[PAR_GINV + 2] * r0 + p[PAR_GINV + 3] * r1
    front = -(dx * p[PAR_NORMAL] + dy * p[PAR_NORMAL + 1] + dz * p[PAR_NORMAL + 2]) > 0.0
    if kind == KIND_RECT:
        inside = abs(a) <= 1.0 and abs(b) <= 1.0
    else:
        inside = a * a + b * b <= 1.0
    if t > 0.0 and front and inside:
        return True, t
    return False, _INF


@helper
def _angle(ax, ay, az, bx, by, bz):
    """Angle between unit vectors (``sampling._angle_between``)."""
    if ax * bx + ay * by + az * bz < 0.0:
        sx, sy, sz = ax + bx, ay + by, az + bz
        return np.pi - 2.0 * np.arcsin(min(np.sqrt(sx * sx + sy * sy + sz * sz) / 2.0, 1.0))
    sx, sy, sz = bx - ax, by - ay, bz - az
    return 2.0 * np.arcsin(min(np.sqrt(sx * sx + sy * sy + sz * sz) / 2.0, 1.0))


@helper
def _unit3(x, y, z):
    n = max(np.sqrt(x * x + y * y + z * z), 1e-300)
    return x / n, y / n, z / n


#: Flags as np.bool_ values, not literals (a literal True/False is a type of its own: one
#: specialisation of the helper per literal).
_NO, _YES = np.bool_(False), np.bool_(True)


@helper
def _sph_rect(p, ox, oy, oz, sample, u0, u1):
    """``sampling.spherical_rectangle`` for one point and a rect light's parameters ``p``.

    returns (solid angle, qx, qy, qz): the sampled point on the rectangle when ``sample``."""
    exl = 2.0 * np.sqrt(
        p[PAR_EX] * p[PAR_EX] + p[PAR_EX + 1] * p[PAR_EX + 1] + p[PAR_EX + 2] * p[PAR_EX + 2]
    )
    eyl = 2.0 * np.sqrt(
        p[PAR_EY] * p[PAR_EY] + p[PAR_EY + 1] * p[PAR_EY + 1] + p[PAR_EY + 2] * p[PAR_EY + 2]
    )
    xx, xy, xz = 2.0 * p[PAR_EX] / exl, 2.0 * p[PAR_EX + 1] / exl, 2.0 * p[PAR_EX + 2] / exl
    yx, yy, yz = 2.0 * p[PAR_EY] / eyl, 2.0 * p[PAR_EY + 1] / eyl, 2.0 * p[PAR_EY + 2] / eyl
    zx, zy, zz = xy * yz - xz * yy, xz * yx - xx * yz, xx * yy - xy * yx
    cx = p[PAR_CENTER] - p[PAR_EX] - p[PAR_EY] - ox
    cy = p[PAR_CENTER + 1] - p[PAR_EX + 1] - p[PAR_EY + 1] - oy
    cz = p[PAR_CENTER + 2] - p[PAR_EX + 2] - p[PAR_EY + 2] - oz
    x0 = cx * xx + cy * xy + cz * xz
    y0 = cx * yx + cy * yy + cz * yz
    z0 = cx * zx + cy * zy + cz * zz
    zs = 1.0
    if z0 > 0.0:
        z0, zs = -z0, -1.0
    x1, y1 = x0 + exl, y0 + eyl
    n0x, n0y, n0z = _unit3(0.0, z0, -y0)
    n1x, n1y, n1z = _unit3(-z0, 0.0, x1)
    n2x, n2y, n2z = _unit3(0.0, -z0, y1)
    n3x, n3y, n3z = _unit3(z0, 0.0, -x0)
    g0 = _angle(-n0x, -n0y, -n0z, n1x, n1y, n1z)
    g1 = _angle(-n1x, -n1y, -n1z, n2x, n2y, n2z)
    g2 = _angle(-n2x, -n2y, -n2z, n3x, n3y, n3z)
    g3 = _angle(-n3x, -n3y, -n3z, n0x, n0y, n0z)
    solid = max(g0 + g1 + g2 + g3 - TWO_PI, 0.0)
    if not sample:
        return solid, 0.0, 0.0, 0.0
    b0, b1 = n0z, n2z
    au = u0 * solid - g2 - g3
    sin_au = np.sin(au)
    fu = (np.cos(au) * b0 - b1) / (sin_au if sin_au != 0.0 else 1e-300)
    cu = 1.0 / np.sqrt(fu * fu + b0 * b0)
    if fu < 0.0:
        cu = -cu
    cu = min(max(cu, -1.0 + 1e-12), 1.0 - 1e-12)
    xu = min(max(-(cu * z0) / np.sqrt(max(1.0 - cu * cu, 0.0)), x0), x1)
    dd = np.sqrt(xu * xu + z0 * z0)
    h0 = y0 / np.sqrt(dd * dd + y0 * y0)
    h1 = y1 / np.sqrt(dd * dd + y1 * y1)
    hv = h0 + u1 * (h1 - h0)
    hv2 = hv * hv
    yv = hv * dd / np.sqrt(max(1.0 - hv2, 1e-300)) if hv2 < 1.0 - 1e-12 else y1
    zw = z0 * zs
    return (
        solid,
        ox + xu * xx + yv * yx + zw * zx,
        oy + xu * xy + yv * yy + zw * zy,
        oz + xu * xz + yv * yz + zw * zz,
    )


@helper
def _rect_candidate(p, ox, oy, oz):
    """``RectLight._solid``'s first test: the solid angle estimated from the centre is large."""
    if p[PAR_RECT_ORTHO] == 0.0:
        return False
    wx, wy, wz = ox - p[PAR_CENTER], oy - p[PAR_CENTER + 1], oz - p[PAR_CENTER + 2]
    d2 = wx * wx + wy * wy + wz * wz
    cos_l = (wx * p[PAR_NORMAL] + wy * p[PAR_NORMAL + 1] + wz * p[PAR_NORMAL + 2]) / np.sqrt(
        max(d2, 1e-300)
    )
    return p[PAR_AREA] * max(cos_l, 0.0) >= SPHERICAL_RECT_MIN_SR * d2


@helper
def _rect_solid(p, ox, oy, oz):
    """Solid angle of a rect light when its solid-angle sampler applies at o, else 0."""
    if not _rect_candidate(p, ox, oy, oz):
        return 0.0
    sr, _, _, _ = _sph_rect(p, ox, oy, oz, _NO, 0.0, 0.0)
    if sr > 0.0 and sr <= SPHERICAL_RECT_MAX_SR:
        return sr
    return 0.0


@helper
def _dome_lookup(p, dx, dy, dz):
    lx = p[PAR_DOME_INV_ROT] * dx + p[PAR_DOME_INV_ROT + 1] * dy + p[PAR_DOME_INV_ROT + 2] * dz
    ly = p[PAR_DOME_INV_ROT + 3] * dx + p[PAR_DOME_INV_ROT + 4] * dy + p[PAR_DOME_INV_ROT + 5] * dz
    lz = p[PAR_DOME_INV_ROT + 6] * dx + p[PAR_DOME_INV_ROT + 7] * dy + p[PAR_DOME_INV_ROT + 8] * dz
    ln = max(np.sqrt(lx * lx + ly * ly + lz * lz), 1e-300)
    lx, ly, lz = lx / ln, ly / ln, lz / ln
    h, w = int(p[PAR_DOME_H]), int(p[PAR_DOME_W])
    lat = np.arcsin(min(max(ly, -1.0), 1.0))
    lon = np.arctan2(lx, lz)
    x = min(max(int((np.pi - lon) / TWO_PI * w), 0), w - 1)
    y = min(max(int((0.5 * np.pi - lat) / np.pi * h), 0), h - 1)
    return x, y, ly


@helper
def search_right(cdf, base, n, u):
    """``sampling.sample_discrete`` on the block ``cdf[base:base + n]``:
    ``min(searchsorted(block, u, side="right"), n - 1)``."""
    lo_i, hi_i = 0, n
    while lo_i < hi_i:
        mid = (lo_i + hi_i) // 2
        if cdf[base + mid] <= u:
            lo_i = mid + 1
        else:
            hi_i = mid
    return min(lo_i, n - 1)


@helper
def _area_sample(p, wx, wy, wz, nx, ny, nz):
    """An area light's sample towards the point at offset (wx, wy, wz) from the query, whose
    emitting side has normal n: a :class:`~usdahd.bake.kernels.layout.LightSample` with the
    area-measure pdf converted to solid angle (zero value and pdf from the back side)."""
    dist = np.sqrt(wx * wx + wy * wy + wz * wz)
    inv = 1.0 / max(dist, 1e-300)
    dx, dy, dz = wx * inv, wy * inv, wz * inv
    cos_l = -(dx * nx + dy * ny + dz * nz)
    if cos_l > 0.0:
        r, g, b = p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        return LightSample(dx, dy, dz, dist, r, g, b, dist * dist / (p[PAR_AREA] * cos_l))
    return LightSample(dx, dy, dz, dist, 0.0, 0.0, 0.0, 0.0)


@helper
def light_sample(kind, p, img, pmf, cdf, x, y, z, u0, u1):
    """Scalar ``Light.sample``: a :class:`~usdahd.bake.kernels.layout.LightSample`."""
    if kind == KIND_POINT:
        wx, wy, wz = p[PAR_CENTER] - x, p[PAR_CENTER + 1] - y, p[PAR_CENTER + 2] - z
        dist = np.sqrt(wx * wx + wy * wy + wz * wz)
        inv = 1.0 / max(dist, 1e-300)
        s = 1.0 / max(dist * dist, 1e-300)
        return LightSample(
            wx * inv,
            wy * inv,
            wz * inv,
            dist,
            p[PAR_RADIANCE] * s,
            p[PAR_RADIANCE + 1] * s,
            p[PAR_RADIANCE + 2] * s,
            1.0,
        )
    if kind == KIND_SPHERE:
        wx, wy, wz, d2, outside, omc = _sphere_omc(p, x, y, z)
        inv = 1.0 / np.sqrt(max(d2, 1e-300))
        dx, dy, dz = _cone(wx * inv, wy * inv, wz * inv, omc, u0, u1)
        t = _sphere_hit_t(p, x, y, z, dx, dy, dz)
        if not np.isfinite(t):
            t = np.sqrt(d2)
        if outside:
            return LightSample(
                dx,
                dy,
                dz,
                t,
                p[PAR_RADIANCE],
                p[PAR_RADIANCE + 1],
                p[PAR_RADIANCE + 2],
                1.0 / (TWO_PI * max(omc, 1e-300)),
            )
        return LightSample(dx, dy, dz, t, 0.0, 0.0, 0.0, 0.0)
    if kind == KIND_RECT and _rect_candidate(p, x, y, z):
        sr, qx, qy, qz = _sph_rect(p, x, y, z, _YES, u0, u1)  # one set-up: test, then sample
        if sr > 0.0 and sr <= SPHERICAL_RECT_MAX_SR:
            wx, wy, wz = qx - x, qy - y, qz - z
            dist = np.sqrt(wx * wx + wy * wy + wz * wz)
            inv = 1.0 / max(dist, 1e-300)
            dx, dy, dz = wx * inv, wy * inv, wz * inv
            if -(dx * p[PAR_NORMAL] + dy * p[PAR_NORMAL + 1] + dz * p[PAR_NORMAL + 2]) > 0.0:
                return LightSample(
                    dx,
                    dy,
                    dz,
                    dist,
                    p[PAR_RADIANCE],
                    p[PAR_RADIANCE + 1],
                    p[PAR_RADIANCE + 2],
                    1.0 / sr,
                )
            return LightSample(dx, dy, dz, dist, 0.0, 0.0, 0.0, 0.0)
    if kind == KIND_RECT or kind == KIND_DISK:
        if kind == KIND_RECT:
            a, b = 2.0 * u0 - 1.0, 2.0 * u1 - 1.0
        else:
            a0, b0 = 2.0 * u0 - 1.0, 2.0 * u1 - 1.0
            if abs(a0) > abs(b0):
                r = a0
                th = (np.pi / 4) * (b0 / (1.0 if a0 == 0 else a0))
            else:
                r = b0
                th = (np.pi / 2) - (np.pi / 4) * (a0 / (1.0 if b0 == 0 else b0))
            a, b = r * np.cos(th), r * np.sin(th)
        wx = p[PAR_CENTER] + a * p[PAR_EX] + b * p[PAR_EY] - x
        wy = p[PAR_CENTER + 1] + a * p[PAR_EX + 1] + b * p[PAR_EY + 1] - y
        wz = p[PAR_CENTER + 2] + a * p[PAR_EX + 2] + b * p[PAR_EY + 2] - z
        return _area_sample(p, wx, wy, wz, p[PAR_NORMAL], p[PAR_NORMAL + 1], p[PAR_NORMAL + 2])
    if kind == KIND_CYLINDER:
        xx = (2.0 * u0 - 1.0) * p[PAR_HALF_LENGTH]
        phi = TWO_PI * u1
        c, s = np.cos(phi), np.sin(phi)
        rx, ry, rz = (
            c * p[PAR_CYL_E1] + s * p[PAR_CYL_E2],
            c * p[PAR_CYL_E1 + 1] + s * p[PAR_CYL_E2 + 1],
            c * p[PAR_CYL_E1 + 2] + s * p[PAR_CYL_E2 + 2],
        )
        wx = p[PAR_CENTER] + xx * p[PAR_AXIS] + p[PAR_RADIUS] * rx - x
        wy = p[PAR_CENTER + 1] + xx * p[PAR_AXIS + 1] + p[PAR_RADIUS] * ry - y
        wz = p[PAR_CENTER + 2] + xx * p[PAR_AXIS + 2] + p[PAR_RADIUS] * rz - z
        return _area_sample(p, wx, wy, wz, rx, ry, rz)
    if kind == KIND_DISTANT:
        if p[PAR_OMC] <= 0.0:
            return LightSample(
                p[PAR_DIRECTION],
                p[PAR_DIRECTION + 1],
                p[PAR_DIRECTION + 2],
                _INF,
                p[PAR_RADIANCE],
                p[PAR_RADIANCE + 1],
                p[PAR_RADIANCE + 2],
                1.0,
            )
        dx, dy, dz = _cone(
            p[PAR_DIRECTION], p[PAR_DIRECTION + 1], p[PAR_DIRECTION + 2], p[PAR_OMC], u0, u1
        )
        return LightSample(
            dx,
            dy,
            dz,
            _INF,
            p[PAR_RADIANCE],
            p[PAR_RADIANCE + 1],
            p[PAR_RADIANCE + 2],
            1.0 / (TWO_PI * p[PAR_OMC]),
        )
    # textured dome (uniform domes are never sampled)
    h, w = int(p[PAR_DOME_H]), int(p[PAR_DOME_W])
    base = int(p[PAR_DOME_PMF])
    idx = search_right(cdf, base, h * w, u0)
    lo = cdf[base + idx - 1] if idx > 0 else 0.0
    frac = min(max((u0 - lo) / max(pmf[base + idx], 1e-300), 0.0), 1.0 - 1e-12)
    yy, xx = idx // w, idx % w
    theta = np.pi * (yy + frac) / h
    lon = np.pi - TWO_PI * (xx + u1) / w
    lat = 0.5 * np.pi - theta
    lx, ly, lz = np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)
    dx = p[PAR_DOME_ROT] * lx + p[PAR_DOME_ROT + 1] * ly + p[PAR_DOME_ROT + 2] * lz
    dy = p[PAR_DOME_ROT + 3] * lx + p[PAR_DOME_ROT + 4] * ly + p[PAR_DOME_ROT + 5] * lz
    dz = p[PAR_DOME_ROT + 6] * lx + p[PAR_DOME_ROT + 7] * ly + p[PAR_DOME_ROT + 8] * lz
    ln = np.sqrt(dx * dx + dy * dy + dz * dz)
    dx, dy, dz = dx / ln, dy / ln, dz / ln
    pdf = pmf[base + idx] * (h * w) / (2.0 * np.pi * np.pi * max(np.sin(theta), 1e-12))
    q = int(p[PAR_DOME_PIX]) + idx
    return LightSample(
        dx,
        dy,
        dz,
        _INF,
        img[q, 0] * p[PAR_RADIANCE],
        img[q, 1] * p[PAR_RADIANCE + 1],
        img[q, 2] * p[PAR_RADIANCE + 2],
        pdf,
    )


@helper
def light_intersect(kind, p, img, ox, oy, oz, dx, dy, dz):
    """Scalar ``Light.intersect``: returns (hit, t, r, g, b)."""
    if kind == KIND_SPHERE:
        t = _sphere_hit_t(p, ox, oy, oz, dx, dy, dz)
        if np.isfinite(t):
            return True, t, p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        return False, _INF, 0.0, 0.0, 0.0
    if kind == KIND_RECT or kind == KIND_DISK:
        hit, t = _planar_hit(kind, p, ox, oy, oz, dx, dy, dz)
        if hit:
            return True, t, p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        return False, _INF, 0.0, 0.0, 0.0
    if kind == KIND_CYLINDER:
        hit, t, _, _, _ = _cyl_hit(p, ox, oy, oz, dx, dy, dz)
        if hit:
            return True, t, p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        return False, _INF, 0.0, 0.0, 0.0
    if kind == KIND_DISTANT:
        if (
            p[PAR_OMC] > 0.0
            and dx * p[PAR_DIRECTION] + dy * p[PAR_DIRECTION + 1] + dz * p[PAR_DIRECTION + 2]
            >= p[PAR_COS_MAX]
        ):
            return True, _INF, p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        return False, _INF, 0.0, 0.0, 0.0
    if kind == KIND_DOME:
        if p[PAR_DOME_TEXTURED] == 0.0:
            return True, _INF, p[PAR_RADIANCE], p[PAR_RADIANCE + 1], p[PAR_RADIANCE + 2]
        x, y, _ = _dome_lookup(p, dx, dy, dz)
        q = int(p[PAR_DOME_PIX]) + y * int(p[PAR_DOME_W]) + x
        return (
            True,
            _INF,
            img[q, 0] * p[PAR_RADIANCE],
            img[q, 1] * p[PAR_RADIANCE + 1],
            img[q, 2] * p[PAR_RADIANCE + 2],
        )
    return False, _INF, 0.0, 0.0, 0.0


@helper
def light_pdf(kind, p, pmf, ox, oy, oz, dx, dy, dz, t):
    """Scalar ``Light.pdf`` (solid angle) of a direction that hit the light at ``t``."""
    if kind == KIND_SPHERE:
        _, _, _, _, outside, omc = _sphere_omc(p, ox, oy, oz)
        return 1.0 / (TWO_PI * max(omc, 1e-300)) if outside else 0.0
    if kind == KIND_RECT or kind == KIND_DISK:
        cos_l = -(dx * p[PAR_NORMAL] + dy * p[PAR_NORMAL + 1] + dz * p[PAR_NORMAL + 2])
        if cos_l > 0.0 and np.isfinite(t):
            if kind == KIND_RECT:
                sr = _rect_solid(p, ox, oy, oz)
                if sr > 0.0:
                    return 1.0 / sr
            return t * t / (p[PAR_AREA] * cos_l)
        return 0.0
    if kind == KIND_CYLINDER:
        hit, t2, rx, ry, rz = _cyl_hit(p, ox, oy, oz, dx, dy, dz)
        cos_l = -(dx * rx + dy * ry + dz * rz) / p[PAR_RADIUS]
        if hit and cos_l > 0.0:
            return t2 * t2 / (p[PAR_AREA] * cos_l)
        return 0.0
    if kind == KIND_DISTANT:
        if (
            p[PAR_OMC] > 0.0
            and dx * p[PAR_DIRECTION] + dy * p[PAR_DIRECTION + 1] + dz * p[PAR_DIRECTION + 2]
            >= p[PAR_COS_MAX]
        ):
            return 1.0 / (TWO_PI * p[PAR_OMC])
        return 0.0
    if kind == KIND_DOME and p[PAR_DOME_TEXTURED] != 0.0:
        x, y, ly = _dome_lookup(p, dx, dy, dz)
        h, w = int(p[PAR_DOME_H]), int(p[PAR_DOME_W])
        sin_t = np.sqrt(min(max(1.0 - ly * ly, 0.0), 1.0))
        return (
            pmf[int(p[PAR_DOME_PMF]) + y * w + x]
            * (h * w)
            / (2.0 * np.pi * np.pi * max(sin_t, 1e-12))
        )
    return 0.0


@helper
def light_importance(p, x, y, z):
    """Scalar ``Bound.importance`` (usdahd.scene.lights) of the light with parameters ``p`` at
    the point (x, y, z): the irradiance bound that chooses which light a vertex samples."""
    f = p[PAR_IMP_FALLOFF]
    if f == FALLOFF_CONSTANT:
        return p[PAR_IMP_CAP]
    wx, wy, wz = x - p[PAR_IMP_CENTER], y - p[PAR_IMP_CENTER + 1], z - p[PAR_IMP_CENTER + 2]
    if f == FALLOFF_FRONT and not (
        wx * p[PAR_IMP_NORMAL] + wy * p[PAR_IMP_NORMAL + 1] + wz * p[PAR_IMP_NORMAL + 2] > 0.0
    ):
        return 0.0
    d2 = max(wx * wx + wy * wy + wz * wz, p[PAR_IMP_R2], 1e-300)
    return min(p[PAR_IMP_CAP], p[PAR_IMP_SCALE] / d2)
