"""Numba twins of the :class:`usdahd.bake.trace.Tracer` queries, per ray, for the fused kernel.

``tb`` is the :class:`usdahd.bake.kernels.layout.NativeTables` of
:meth:`usdahd.bake.trace.Tracer.native_tables`, ``st`` a (1,) uint64 splitmix64 state, ``scene``
the RTCScene address (:attr:`Tracer.native_handle`), ``rec``/``pk`` the scratch records of
:mod:`usdahd.bake.kernels.embree`. Parity with the numpy methods: tests/test_kernel_parity.py
and tests/test_trace.py.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.kernels import (
    cache,  # noqa: F401  (numba cache locators, before any @njit)
    embree,
)
from usdahd.bake.kernels.cache import helper
from usdahd.bake.kernels.layout import (
    HIT_NG,
    HIT_T,
    HIT_TRI,
    HIT_U,
    HIT_V,
    MAT_ALBEDO,
    MAT_OPACITY,
    MAT_THRESHOLD,
    RAY_D,
    RAY_O,
    RAY_TFAR,
    TEX_ALBEDO,
    TEX_EMISSION,
    TEX_OPACITY,
    TraceHit,
)
from usdahd.bake.trace import MAX_TRANSMIT
from usdahd.numerics.offsets import FLT_EPS, OFFSET_ULPS

__all__ = [
    "OFFSET_PER_UNIT",
    "nb_albedo",
    "nb_emission",
    "nb_hit_point",
    "nb_offset",
    "nb_random",
    "nb_shading_normal",
    "nb_trace",
    "nb_trace_rays",
    "nb_transmittance",
    "nb_transmittance_rays",
]

# ----------------------------------------------------------------------------- numba side
# Scalar per-ray versions of the methods above for the fused integrator kernel; ``tb`` is the
# NativeTables returned by ``Tracer.native_tables()``, ``st`` a (1,) uint64 random state.

_U64 = np.uint64
#: Tracer.offset's floor per unit of the point's largest coordinate (same product, same bits).
OFFSET_PER_UNIT = OFFSET_ULPS * FLT_EPS


@helper
def nb_random(st):
    """Next float64 in [0, 1) from the splitmix64 state ``st[0]`` (advanced in place)."""
    z = st[0] + _U64(0x9E3779B97F4A7C15)
    st[0] = z
    z = (z ^ (z >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> _U64(27))) * _U64(0x94D049BB133111EB)
    z = z ^ (z >> _U64(31))
    return np.float64(z >> _U64(11)) * (1.0 / 9007199254740992.0)


@helper
def nb_offset(scale, px, py, pz, nx, ny, nz, dx, dy, dz):
    """:meth:`Tracer.offset` for one ray (``scale``: the point's triangle's ``tri_offset``
    or the texel's own offset)."""
    s = 1.0 if nx * dx + ny * dy + nz * dz >= 0.0 else -1.0
    sc = s * max(scale, OFFSET_PER_UNIT * max(abs(px), abs(py), abs(pz)))
    return px + sc * nx, py + sc * ny, pz + sc * nz


@helper
def _wrap(i, n, mode):
    if mode == 1:
        return min(max(i, 0), n - 1)
    if mode == 2:
        i = i % (2 * n)
        return 2 * n - 1 - i if i >= n else i
    return i % n


@helper
def _bilinear(data, off, w, c, ch, xs0, xs1, ys0, ys1, fx, fy):
    return (
        data[off + (ys0 * w + xs0) * c + ch] * (1 - fx) * (1 - fy)
        + data[off + (ys0 * w + xs1) * c + ch] * fx * (1 - fy)
        + data[off + (ys1 * w + xs0) * c + ch] * (1 - fx) * fy
        + data[off + (ys1 * w + xs1) * c + ch] * fx * fy
    )


@helper
def nb_texture(tb, k, s, t):
    """Texture ``k`` at uv (s, t): ((v0, v1, v2, v3), count) the selected channels (bilinear,
    scale/bias, missing channels padded as :meth:`usdahd.scene.types.Texture.sample`)."""
    data, info, chan, sb = tb.tex_data, tb.tex_info, tb.tex_chan, tb.tex_sb
    off, h, w, c = info[k, 0], info[k, 1], info[k, 2], info[k, 3]
    x = s * w - 0.5
    y = (1.0 - t) * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    xi, yi = int(x0), int(y0)
    xs0, xs1 = _wrap(xi, w, info[k, 4]), _wrap(xi + 1, w, info[k, 4])
    ys0, ys1 = _wrap(yi, h, info[k, 5]), _wrap(yi + 1, h, info[k, 5])
    out = (0.0, 0.0, 0.0, 0.0)
    for j in range(info[k, 6]):
        q = chan[k, j]
        if q < c:
            v = _bilinear(data, off, w, c, q, xs0, xs1, ys0, ys1, fx, fy)
        elif c == 1 and q < 3:
            v = _bilinear(data, off, w, c, np.int64(0), xs0, xs1, ys0, ys1, fx, fy)
        else:
            v = 1.0
        v = np.float64(np.float32(v * sb[k, q] + sb[k, 4 + q]))
        if j == 0:
            out = (v, out[1], out[2], out[3])
        elif j == 1:
            out = (out[0], v, out[2], out[3])
        elif j == 2:
            out = (out[0], out[1], v, out[3])
        else:
            out = (out[0], out[1], out[2], v)
    return out, info[k, 6]


# Component indices as int64 values, not literals: numba compiles a helper once per argument
# type, and a literal 0 is a type of its own (Literal[int](0)), so each constant index would
# make another specialisation of the same code.
_I0, _I1, _I2 = np.int64(0), np.int64(1), np.int64(2)


@helper
def _bary(a, tri, u, v, i):
    """Component ``i`` of per-corner data ``a`` (t, 3, c) at barycentrics (1 - u - v, u, v)."""
    w0 = 1.0 - u - v
    return w0 * a[tri, 0, i] + u * a[tri, 1, i] + v * a[tri, 2, i]


@helper
def _uv(tb, tri, u, v):
    tc = tb.tri_texcoord
    return _bary(tc, tri, u, v, _I0), _bary(tc, tri, u, v, _I1)


@helper
def _material_rgb(tb, tri, u, v, which):
    # which: TEX_ALBEDO or TEX_EMISSION; its constant rgb starts at column 3 * which
    m = tb.tri_material[tri]
    k = tb.mat_tex[m, which]
    mc = tb.mat_const
    if k < 0:
        c0 = MAT_ALBEDO + 3 * which
        return mc[m, c0], mc[m, c0 + 1], mc[m, c0 + 2]
    s, t = _uv(tb, tri, u, v)
    val, nch = nb_texture(tb, k, s, t)
    if nch == 1:
        return val[0], val[0], val[0]
    return val[0], val[1], val[2]


@helper
def nb_albedo(tb, tri, u, v):
    """:meth:`Tracer.albedo_at` for one hit: (r, g, b) clipped to [0, 1]."""
    r, g, b = _material_rgb(tb, tri, u, v, np.int64(TEX_ALBEDO))
    return min(max(r, 0.0), 1.0), min(max(g, 0.0), 1.0), min(max(b, 0.0), 1.0)


@helper
def nb_emission(tb, tri, u, v):
    """:meth:`Tracer.emission_at` for one hit: (r, g, b)."""
    return _material_rgb(tb, tri, u, v, np.int64(TEX_EMISSION))


@helper
def _opacity(tb, tri, u, v):
    """:meth:`Tracer._opacity` for one hit: (opacity, threshold) as float32."""
    m = tb.tri_material[tri]
    mc = tb.mat_const
    k = tb.mat_tex[m, TEX_OPACITY]
    op = mc[m, MAT_OPACITY]
    if k >= 0:
        s, t = _uv(tb, tri, u, v)
        op = nb_texture(tb, k, s, t)[0][0]
    return np.float32(op), np.float32(mc[m, MAT_THRESHOLD])


@helper
def nb_transmits(tb, tri, u, v, st):
    """:meth:`Tracer._transmits` for one hit (consumes a random number when stochastic)."""
    op, th = _opacity(tb, tri, u, v)
    if th > 0:
        return op < th
    if op < 1.0:
        return nb_random(st) >= op
    return False


@helper
def nb_transmission(tb, tri, u, v):
    """:meth:`Tracer._transmission` for one hit: the fraction of light passing it."""
    op, th = _opacity(tb, tri, u, v)
    if th > 0:
        return 1.0 if op < th else 0.0
    return min(max(1.0 - np.float64(op), 0.0), 1.0)


@helper
def nb_hit_point(tb, tri, u, v):
    w = tb.verts
    return _bary(w, tri, u, v, _I0), _bary(w, tri, u, v, _I1), _bary(w, tri, u, v, _I2)


@helper
def nb_shading_normal(tb, tri, u, v):
    cn = tb.corner_normal
    nx, ny = _bary(cn, tri, u, v, _I0), _bary(cn, tri, u, v, _I1)
    nz = _bary(cn, tri, u, v, _I2)
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    if ln > 1e-12:
        return nx / ln, ny / ln, nz / ln
    g = tb.geom_normal
    return g[tri, 0], g[tri, 1], g[tri, 2]


@helper
def _pass_through(scene, rec, tb, tri, u, v, dx, dy, dz, tfar, travelled, t):
    """Continue a ray past its hit on ``tri`` at barycentrics (u, v), ``t`` beyond the
    ``travelled`` distance: (t, tri, u, v, travelled) of its next hit (tri -1: none)."""
    # barycentrics rounded to float32 as Embree reports them (float64: one specialisation)
    uf, vf = np.float64(np.float32(u)), np.float64(np.float32(v))
    px, py, pz = nb_hit_point(tb, tri, uf, vf)
    g = tb.geom_normal
    sc = tb.tri_offset[tri]
    qx, qy, qz = nb_offset(sc, px, py, pz, g[tri, 0], g[tri, 1], g[tri, 2], dx, dy, dz)
    done = travelled + t
    h = embree.intersect1(scene, rec, qx, qy, qz, dx, dy, dz, tfar - done)
    return np.float64(h.t), h.tri, np.float64(h.u), np.float64(h.v), done


@helper
def nb_trace(scene, rec, tb, transmission, st, ox, oy, oz, dx, dy, dz, tfar):
    """:meth:`Tracer.intersect` for one ray: a :class:`~usdahd.bake.kernels.layout.TraceHit`
    (tri -1 on miss; the unit geometric normal from Embree's hit record, so no per-triangle
    table is read)."""
    h = embree.intersect1(scene, rec, ox, oy, oz, dx, dy, dz, tfar)
    t, tri, u, v = h.t, h.tri, h.u, h.v
    rays = 1
    if not transmission:
        if tri < 0:
            return TraceHit(np.inf, tri, 0.0, 0.0, 0.0, 0.0, 1.0, rays)
        gx, gy, gz = embree.hit_normal(rec)
        return TraceHit(np.float64(t), tri, np.float64(u), np.float64(v), gx, gy, gz, rays)
    t = np.float64(t)
    u = np.float64(u)
    v = np.float64(v)
    travelled = 0.0
    for _ in range(MAX_TRANSMIT):
        if tri < 0 or not nb_transmits(tb, tri, u, v, st):
            break
        t, tri, u, v, travelled = _pass_through(
            scene, rec, tb, tri, u, v, dx, dy, dz, tfar, travelled, t
        )
        rays += 1
    if tri < 0:
        return TraceHit(np.inf, tri, u, v, 0.0, 0.0, 1.0, rays)
    gx, gy, gz = embree.hit_normal(rec)
    return TraceHit(np.float64(np.float32(travelled + t)), tri, u, v, gx, gy, gz, rays)


@helper
def nb_transmittance(scene, rec, tb, transmission, ox, oy, oz, dx, dy, dz, tfar):
    """:meth:`Tracer.transmittance` for one shadow ray: (fraction passing, rays traced)."""
    if not transmission:
        return (0.0 if embree.occluded1(scene, rec, ox, oy, oz, dx, dy, dz, tfar) else 1.0), 1
    h = embree.intersect1(scene, rec, ox, oy, oz, dx, dy, dz, tfar)
    rays = 1
    t, tri, u, v = np.float64(h.t), h.tri, np.float64(h.u), np.float64(h.v)
    T = 1.0
    travelled = 0.0
    for _ in range(MAX_TRANSMIT):
        if tri < 0:
            return T, rays
        T *= nb_transmission(tb, tri, u, v)
        if not (T > 0.0):
            return 0.0, rays
        t, tri, u, v, travelled = _pass_through(
            scene, rec, tb, tri, u, v, dx, dy, dz, tfar, travelled, t
        )
        rays += 1
    return (T if tri < 0 else 0.0), rays


@helper
def nb_transmittance_rays(scene, pk, rec, tb, transmission, rays, n, out):
    """:meth:`Tracer.transmittance` for ``rays[:n]`` into ``out[:n]`` (float64). returns rays
    traced (16-ray OCCLUDED packets when nothing in the scene transmits)."""
    if not transmission:
        embree.occluded_rays(scene, pk, rec, rays, n, out)
        for r in range(n):
            out[r] = 0.0 if out[r] else 1.0
        return n
    total = 0
    for r in range(n):
        tr, k = nb_transmittance(
            scene, rec, tb, transmission, rays[r, RAY_O], rays[r, RAY_O + 1], rays[r, RAY_O + 2],
            rays[r, RAY_D], rays[r, RAY_D + 1], rays[r, RAY_D + 2], rays[r, RAY_TFAR],
        )  # fmt: skip
        out[r] = tr
        total += k
    return total


@helper
def nb_trace_rays(scene, pk, rec, tb, transmission, st, rays, n, hits):
    """:meth:`Tracer.intersect` for ``rays[:n]`` into ``hits[:n]`` (the row layouts of
    :func:`usdahd.bake.kernels.embree.intersect_rays`): 16-ray packets, or one ray at a time
    through :func:`nb_trace` when the scene has transmissive surfaces. returns rays traced."""
    if not transmission:
        embree.intersect_rays(scene, pk, rec, rays, n, hits)
        return n
    total = 0
    for r in range(n):
        h = nb_trace(
            scene, rec, tb, transmission, st, rays[r, RAY_O], rays[r, RAY_O + 1],
            rays[r, RAY_O + 2], rays[r, RAY_D], rays[r, RAY_D + 1], rays[r, RAY_D + 2],
            rays[r, RAY_TFAR],
        )  # fmt: skip
        hits[r, HIT_T], hits[r, HIT_TRI], hits[r, HIT_U], hits[r, HIT_V] = h.t, h.tri, h.u, h.v
        hits[r, HIT_NG], hits[r, HIT_NG + 1], hits[r, HIT_NG + 2] = h.gx, h.gy, h.gz
        total += h.rays
    return total
