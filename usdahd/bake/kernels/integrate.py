"""The numba integrator: the estimator of :class:`usdahd.bake.reference.ReferenceCtx` per texel,
tracing through libembree4 from numba (backend "native", driven by ``integrate.NativeCtx``).

Entry points: :func:`native_pass` (one pass of samples for a set of texels, on one thread),
:func:`native_result` (the per-texel SH solve, twin of ``reference.Accum.result``) and
:func:`native_work` (per-thread scratch). The paths behind each hemisphere sample are traced
by :func:`usdahd.bake.kernels.paths.trace_paths`. Every record (arrays, rows, configuration)
is declared in :mod:`usdahd.bake.kernels.layout`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from usdahd.bake.kernels import (
    cache,  # noqa: F401  (numba cache locators, before any @njit)
    embree,
)
from usdahd.bake.kernels.cache import helper
from usdahd.bake.kernels.layout import (
    CFG_LINKED,
    CFG_REGRESSION,
    CFG_SHADOW_LINKED,
    CFG_STRATEGY,
    CFG_TEXEL_MESH,
    CFG_TRANSMISSION,
    GRAM_FIRST,
    GRAM_PAIRS,
    GRAM_SUMS,
    GRAM_WSUM,
    HIT_NG,
    HIT_TRI,
    PATH_BETA,
    PATH_D,
    PATH_DEPTH,
    PATH_MESH,
    PATH_O,
    PATH_PDF,
    PATH_SAMPLE,
    PATH_SEL,
    PATH_X,
    SVAL_DIR,
    SVAL_RGB,
    NativeWork,
)
from usdahd.bake.kernels.lights import light_sample
from usdahd.bake.kernels.paths import trace_paths
from usdahd.bake.kernels.shading import (
    lit,
    nee_pick,
    nee_sample,
    put3,
    put_ray,
    shadow1,
    shadow_rays,
    visibility,
    w_light,
)
from usdahd.bake.kernels.trace import nb_offset, nb_random, nb_trace_rays
from usdahd.bake.reference import ALL_LIGHTS_MAX, G_HEMI, LIGHT_SHIFT
from usdahd.numerics import sh as shmod

__all__ = ["native_pass", "native_result", "native_work"]


@njit(cache=True, nogil=True, error_model="numpy")
def native_result(ids, acc, regression, out, bf):
    """``Accum.result`` for texels ``ids`` of ``acc`` (:class:`~usdahd.bake.kernels.layout
    .AccumArrays`) into ``out`` (n,3,9) f32 and ``bf`` (n,) f32: the same solve (9x9 LU with
    partial pivoting, 1e-9 ridge) per texel, on the threads."""
    gram, hemi, nee, delta, count, back = (
        acc.gram,
        acc.hemi,
        acc.nee,
        acc.delta,
        acc.count,
        acc.back,
    )
    a = np.empty((9, 12))
    for ii in range(ids.shape[0]):
        i = ids[ii]
        c = max(count[i], 1)
        inv = 1.0 / c
        for ch in range(3):
            for k in range(9):
                out[i, ch, k] = np.float32(
                    hemi[i, ch, k] * inv + nee[i, ch, k] * inv + delta[i, ch, k]
                )
        bf[i] = np.float32(back[i] * inv)
        if not (regression and count[i] >= 16):
            continue
        for r in range(9):
            for k in range(9):
                a[r, k] = gram[i, r, k] * inv + (1e-9 if r == k else 0.0)
            for ch in range(3):
                a[r, 9 + ch] = hemi[i, ch, r] * inv
        for col in range(9):  # Gaussian elimination, partial pivoting
            piv = col
            for r in range(col + 1, 9):
                if abs(a[r, col]) > abs(a[piv, col]):
                    piv = r
            if piv != col:
                for k in range(12):
                    a[col, k], a[piv, k] = a[piv, k], a[col, k]
            for r in range(col + 1, 9):
                f = a[r, col] / a[col, col]
                for k in range(col, 12):
                    a[r, k] -= f * a[col, k]
        for r in range(8, -1, -1):
            for ch in range(3):
                v = a[r, 9 + ch]
                for k in range(r + 1, 9):
                    v -= a[r, k] * a[k, 9 + ch]
                a[r, 9 + ch] = v / a[r, r]
        for ch in range(3):
            for k in range(9):
                v = 0.0
                for m in range(9):
                    v += G_HEMI[k, m] * a[m, 9 + ch]
                out[i, ch, k] = np.float32(v + nee[i, ch, k] * inv + delta[i, ch, k])


# ----------------------------------------------------------------------------- native kernel
# The same estimator as ``reference.ReferenceCtx``, in numba, tracing through libembree4 directly
# (backend "native"). Each call handles the texels ``ids`` of one chunk for one pass and adds into
# the ``Accum`` arrays at those rows only, so threads given disjoint ``ids`` never touch the same
# memory. Per texel it is a small wavefront: the pass's hemisphere rays (all from one origin), the
# texel's light-sample shadow rays, and then each bounce's shadow and continuation rays are traced
# as 16-ray packets (:func:`usdahd.bake.kernels.embree.intersect_rays`). Random numbers: one
# splitmix64 stream per texel (state in ``rng_state``), so results do not depend on threads or on
# how texels are split among them. Helpers are plain ``@njit`` functions: LLVM inlines the small
# ones when the kernel is linked (numba-level ``inline="always"`` cost ~3x the compile time for no
# run-time gain).

_C0, _C1, _C2, _C20, _C22 = shmod.C0, shmod.C1, shmod.C2, shmod.C20, shmod.C22
_LUM = (float(shmod.LUMINANCE[0]), float(shmod.LUMINANCE[1]), float(shmod.LUMINANCE[2]))
_IZ = float(shmod.IZ_FROM_L10)
_TWO_PI = 2.0 * np.pi
_4PI = 4.0 * np.pi
_INV_4PI = 1.0 / (4.0 * np.pi)


@helper
def _sh9(Y, x, y, z):
    Y[0] = _C0
    Y[1] = -_C1 * y
    Y[2] = _C1 * z
    Y[3] = -_C1 * x
    Y[4] = _C2 * x * y
    Y[5] = -_C2 * y * z
    Y[6] = _C20 * (3.0 * z * z - 1.0)
    Y[7] = -_C2 * x * z
    Y[8] = _C22 * (x * x - y * y)


@helper
def _texel_delta(scene, tb, lt, delta_idx, cfg, tex, i, delta, work):
    """Exact delta-light terms of texel ``i`` of ``tex`` (one shadow ray per light) into
    ``delta``. returns rays."""
    kind, par, img, pmf, cdf = lt.kind, lt.par, lt.img, lt.pmf, lt.cdf
    rec, st, Y = work.rec, work.st, work.Y
    eps, transmission = tex.E[i], cfg[CFG_TRANSMISSION] != 0.0
    linked, tmesh = cfg[CFG_LINKED] != 0.0, int(cfg[CFG_TEXEL_MESH])
    px, py, pz = tex.P[i, 0], tex.P[i, 1], tex.P[i, 2]
    ngx, ngy, ngz = tex.NG[i, 0], tex.NG[i, 1], tex.NG[i, 2]
    f = tex.F[i]
    rays = 0
    for jj in range(delta_idx.shape[0]):
        j = delta_idx[jj]
        ls = light_sample(kind[j], par[j], img, pmf, cdf, px, py, pz, 0.0, 0.0)
        dx, dy, dz = ls.dx, ls.dy, ls.dz
        lz = f[2, 0] * dx + f[2, 1] * dy + f[2, 2] * dz
        if not (lz > 0.0 and dx * ngx + dy * ngy + dz * ngz > 0.0):
            continue
        if linked and not lit(lt, j, tmesh):
            continue
        qx, qy, qz = nb_offset(eps, px, py, pz, ngx, ngy, ngz, dx, dy, dz)
        sx, sy, sz, tf = shadow1(qx, qy, qz, px, py, pz, dx, dy, dz, ls.dist)
        tr, k = visibility(scene, rec, tb, lt, j, transmission, st, qx, qy, qz, sx, sy, sz, tf)
        rays += k
        if not (tr > 0.0):
            continue
        r, g, b = tr * ls.r, tr * ls.g, tr * ls.b
        lx = f[0, 0] * dx + f[0, 1] * dy + f[0, 2] * dz
        ly = f[1, 0] * dx + f[1, 1] * dy + f[1, 2] * dz
        _sh9(Y, lx, ly, lz)
        for c9 in range(9):
            delta[i, 0, c9] += r * Y[c9]
            delta[i, 1, c9] += g * Y[c9]
            delta[i, 2, c9] += b * Y[c9]
    return rays


@helper
def _gram_unpack(gram, i, G):
    """Add the Gram sums ``G`` (``layout.GRAM``) to ``gram[i]`` and zero ``G``: the first
    sums sum w Y_a (a = 1..8), the pairs the upper triangle of sum w Y_a Y_b (a <= b, row by
    row), the weight sum sum w, with w = 1/p per sample (row 0 of the Gram is C0 times the
    first sums)."""
    gram[i, 0, 0] += _C0 * _C0 * G[GRAM_WSUM]
    q = GRAM_PAIRS
    for a in range(1, 9):
        v = _C0 * G[GRAM_FIRST + a - 1]
        gram[i, 0, a] += v
        gram[i, a, 0] += v
        for b9 in range(a, 9):
            v = G[q]
            gram[i, a, b9] += v
            if b9 != a:
                gram[i, b9, a] += v
            q += 1
    for q in range(GRAM_SUMS):
        G[q] = 0.0


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def native_pass(scene, tb, lt, lists, cfg, tex, ids, pts, rng_state, do_delta, acc, work):
    """One pass of ``s`` hemisphere (+ light) samples for texels ``ids`` of a chunk.

    scene : the RTCScene address; tb : :class:`~usdahd.bake.kernels.layout.NativeTables`;
    lt, lists : :class:`~usdahd.bake.kernels.layout.LightArrays`, ``LightLists``; cfg : the
    ``CFG_*`` row; tex : the chunk's :class:`~usdahd.bake.kernels.layout.TexelArrays`;
    pts : the pass's :class:`~usdahd.bake.kernels.layout.PassPoints` (s rows); rng_state :
    (n,) uint64 per-texel random state; acc : ``Accum.arrays``
    (:class:`~usdahd.bake.kernels.layout.AccumArrays`); work : per-thread scratch from
    :func:`native_work`. Compiled without the NRT (``_nrt=False``): no allocation and no
    reference counting in the hot loop.
    returns : rays traced.
    """
    kind, par, img, pmf, cdf = lt.kind, lt.par, lt.img, lt.pmf, lt.cdf
    delta_idx, area_idx = lists.delta, lists.area
    hemi, nee, count, back = acc.hemi, acc.nee, acc.count, acc.back
    P, NG, F, E = tex.P, tex.NG, tex.F, tex.E
    r2h, r2n = pts.r2h, pts.r2n
    s = r2h.shape[0]
    linked, tmesh = cfg[CFG_LINKED] != 0.0, cfg[CFG_TEXEL_MESH]
    shadow_linked = cfg[CFG_SHADOW_LINKED] != 0.0
    transmission = cfg[CFG_TRANSMISSION] != 0.0
    regression = cfg[CFG_REGRESSION] != 0.0
    mode = int(cfg[CFG_STRATEGY])
    n_area = area_idx.shape[0]
    every = n_area <= ALL_LIGHTS_MAX  # every light gets every texel light sample
    # else each sample picks one by the bound at the texel (PATH_SEL -2: shading.nee_pick over
    # ``lists.area`` at PATH_X, for the MIS of the hemisphere rays)
    sel_area = 1.0 if every else -2.0
    rec, pk, st, Y, G, H = work.rec, work.pk, work.st, work.Y, work.G, work.H
    ps, rays, hits, srays, sval = work.ps, work.rays, work.hits, work.srays, work.sval
    sidx, slight, occ, R, loc, yl = work.sidx, work.slight, work.occ, work.R, work.loc, work.yl
    traced = 0
    for ii in range(ids.shape[0]):
        i = ids[ii]
        st[0] = rng_state[i]
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        ngx, ngy, ngz = NG[i, 0], NG[i, 1], NG[i, 2]
        f = F[i]
        eps = E[i]
        if do_delta:
            traced += _texel_delta(scene, tb, lt, delta_idx, cfg, tex, i, acc.delta, work)
        cp0 = nb_random(st)
        cp1 = nb_random(st)
        c1, s1 = np.cos(_TWO_PI * cp1), np.sin(_TWO_PI * cp1)
        # every traced hemisphere ray leaves from the same offset origin (d . ng > 0)
        qx, qy, qz = nb_offset(eps, px, py, pz, ngx, ngy, ngz, ngx, ngy, ngz)
        m = np.int64(0)
        for k in range(s):
            u0 = r2h[k, 0] + cp0
            u0 = u0 - 1.0 if u0 >= 1.0 else u0
            lz = 0.5 * (np.sqrt(1.0 + 8.0 * u0) - 1.0)  # sampling.texel_hemisphere
            sn = np.sqrt(max(1.0 - lz * lz, 0.0))
            # phi = 2 pi (r2 + cp1): angle addition with the pass's precomputed cos/sin
            lx = sn * (r2h[k, 2] * c1 - r2h[k, 3] * s1)
            ly = sn * (r2h[k, 3] * c1 + r2h[k, 2] * s1)
            loc[k, 0], loc[k, 1], loc[k, 2] = lx, ly, lz
            R[k, 0] = R[k, 1] = R[k, 2] = 0.0
            yl[k] = 0.0
            dx = lx * f[0, 0] + ly * f[1, 0] + lz * f[2, 0]
            dy = lx * f[0, 1] + ly * f[1, 1] + lz * f[2, 1]
            dz = lx * f[0, 2] + ly * f[1, 2] + lz * f[2, 2]
            if dx * ngx + dy * ngy + dz * ngz > 0.0:
                put_ray(rays, m, qx, qy, qz, dx, dy, dz, np.inf)
                put3(ps, m, PATH_O, qx, qy, qz)
                put3(ps, m, PATH_D, dx, dy, dz)
                put3(ps, m, PATH_BETA, 1.0, 1.0, 1.0)
                ps[m, PATH_PDF] = (1.0 + 2.0 * lz) * _INV_4PI
                ps[m, PATH_SEL] = sel_area
                put3(ps, m, PATH_X, px, py, pz)
                ps[m, PATH_MESH] = tmesh
                ps[m, PATH_DEPTH] = 0.0
                ps[m, PATH_SAMPLE] = k
                m += 1
        n_back = 0
        if m:
            traced += nb_trace_rays(scene, pk, rec, tb, transmission, st, rays, m, hits)
            for j in range(m):
                # a back face of a one-sided triangle: the texel may be inside geometry
                if hits[j, HIT_TRI] >= 0.0 and tb.tri_one_sided[int(hits[j, HIT_TRI])] != 0:
                    if (
                        ps[j, PATH_D] * hits[j, HIT_NG]
                        + ps[j, PATH_D + 1] * hits[j, HIT_NG + 1]
                        + ps[j, PATH_D + 2] * hits[j, HIT_NG + 2]
                        > 0
                    ):
                        n_back += 1
            traced += trace_paths(scene, tb, lt, lists, cfg, m, work)
        # light samples at the texel, MIS with the texel hemisphere: with ``every``, one round
        # per light (each light gets all s samples), else one round, a light picked per sample
        cn0 = nb_random(st) if n_area else 0.0
        cn1 = nb_random(st) if n_area else 0.0
        rounds = n_area if every else (1 if n_area else 0)
        for rd in range(rounds):
            ns = np.int64(0)
            for k in range(s):
                u0 = r2n[k, 0] + cn0 + rd * LIGHT_SHIFT
                u0 = u0 - np.floor(u0)
                u1 = r2n[k, 1] + cn1 + rd * LIGHT_SHIFT
                u1 = u1 - np.floor(u1)
                psel = 1.0
                if every:
                    j = area_idx[rd]
                else:
                    j, psel = nee_pick(par, area_idx, px, py, pz, nb_random(st))
                ls = nee_sample(kind[j], par[j], img, pmf, cdf, tb, px, py, pz, u0, u1)
                dx, dy, dz, pdf = ls.dx, ls.dy, ls.dz, ls.pdf
                r, g, b = ls.r, ls.g, ls.b
                lz = f[2, 0] * dx + f[2, 1] * dy + f[2, 2] * dz
                if (
                    pdf > 0.0
                    and lz > 0.0
                    and dx * ngx + dy * ngy + dz * ngz > 0.0
                    and (r > 0.0 or g > 0.0 or b > 0.0)
                    and (not linked or lit(lt, j, int(tmesh)))
                ):
                    ox, oy, oz = nb_offset(eps, px, py, pz, ngx, ngy, ngz, dx, dy, dz)
                    sx, sy, sz, tf = shadow1(ox, oy, oz, px, py, pz, dx, dy, dz, ls.dist)
                    put_ray(srays, ns, ox, oy, oz, sx, sy, sz, tf)
                    pl = pdf * psel
                    wgt = w_light(mode, pl, (1.0 + 2.0 * lz) * _INV_4PI) / pl
                    put3(sval, ns, SVAL_RGB, r * wgt, g * wgt, b * wgt)
                    put3(
                        sval, ns, SVAL_DIR,
                        f[0, 0] * dx + f[0, 1] * dy + f[0, 2] * dz,
                        f[1, 0] * dx + f[1, 1] * dy + f[1, 2] * dz,
                        lz,
                    )  # fmt: skip
                    sidx[ns] = k
                    slight[ns] = j
                    ns += 1
            if ns:
                traced += shadow_rays(scene, pk, rec, tb, lt, transmission, shadow_linked, st,
                                      srays, slight, ns, occ)  # fmt: skip
                for q in range(ns):
                    tr = occ[q]
                    if not (tr > 0.0):
                        continue
                    _sh9(Y, sval[q, SVAL_DIR], sval[q, SVAL_DIR + 1], sval[q, SVAL_DIR + 2])
                    r = tr * sval[q, SVAL_RGB]
                    g = tr * sval[q, SVAL_RGB + 1]
                    b = tr * sval[q, SVAL_RGB + 2]
                    for c9 in range(9):
                        nee[i, 0, c9] += r * Y[c9]
                        nee[i, 1, c9] += g * Y[c9]
                        nee[i, 2, c9] += b * Y[c9]
                    yl[sidx[q]] += _IZ * (_LUM[0] * r + _LUM[1] * g + _LUM[2] * b) * Y[2]
        # SH sums of the hemisphere samples (weights 1/p, p = sampling.texel_hemisphere_pdf)
        ys = 0.0
        ys2 = 0.0
        yh = 0.0  # the even-numbered samples' share (Accum.iz_variance_halves)
        for k in range(s):
            _sh9(Y, loc[k, 0], loc[k, 1], loc[k, 2])
            wp = _4PI / (1.0 + 2.0 * loc[k, 2])
            for c in range(3):
                w = wp * R[k, c]
                for a in range(9):
                    H[9 * c + a] += w * Y[a]
            if regression:  # sum w Y_a and the upper triangle of w Y Y^T (GRAM_* slots)
                G[GRAM_WSUM] += wp
                q = GRAM_PAIRS
                for a in range(1, 9):
                    wa = wp * Y[a]
                    G[GRAM_FIRST + a - 1] += wa
                    for b in range(a, 9):
                        G[q] += wa * Y[b]
                        q += 1
            lum = _LUM[0] * R[k, 0] + _LUM[1] * R[k, 1] + _LUM[2] * R[k, 2]
            ylum = wp * _IZ * lum * Y[2] + yl[k]
            ys += ylum
            ys2 += ylum * ylum
            if k % 2 == 0:
                yh += ylum
        for c in range(3):
            for c9 in range(9):
                hemi[i, c, c9] += H[9 * c + c9]
                H[9 * c + c9] = 0.0
        acc.y_sum[i] += ys
        acc.y_sq[i] += ys2
        acc.y_half[i] += yh
        back[i] += n_back
        count[i] += s
        rng_state[i] = st[0]
        if regression:
            _gram_unpack(acc.gram, i, G)
    return traced


def native_work(s) -> NativeWork:
    """Per-thread scratch of :func:`native_pass` for passes of ``s`` samples
    (:class:`~usdahd.bake.kernels.layout.NativeWork`)."""
    return NativeWork.alloc({"rec": embree.new_scratch(), "pk": embree.new_packet()}, s=s)
