"""The numba integrator: the estimator of :class:`usdahd.bake.reference.ReferenceCtx` per texel,
tracing through libembree4 from numba (backend "native", driven by ``integrate._NativeCtx``).

Entry points: :func:`native_pass` (one pass of samples for a set of texels, on one thread),
:func:`native_result` (the per-texel SH solve, twin of ``reference.Accum.result``) and
:func:`native_work` (per-thread scratch). Flat array slots are named in
:mod:`usdahd.bake.kernels.layout`.
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
    CFG_BOUNCES,
    CFG_EMISSION,
    CFG_EMISSIVE_LIGHT,
    CFG_REGRESSION,
    CFG_STRATEGY,
    CFG_TRANSMISSION,
    HIT_NG,
    HIT_T,
    HIT_TRI,
    HIT_U,
    HIT_V,
    KIND_DISTANT,
    KIND_DOME,
    KIND_EMISSIVE,
    MAT_ALBEDO,
    MAT_EMISSION,
    MODE_BSDF,
    MODE_MIS,
    MODE_NEE,
    PAR_COS_MAX,
    PAR_DIRECTION,
    PAR_DOME_TEXTURED,
    PAR_EM_COUNT,
    PAR_EM_PDF_AREA,
    PAR_EM_TABLE,
    PAR_EM_TRI,
    PAR_OMC,
    PAR_RADIANCE,
    PATH_BETA,
    PATH_COLS,
    PATH_D,
    PATH_DEPTH,
    PATH_O,
    PATH_PDF,
    PATH_SAMPLE,
    PATH_SEL,
    PATH_X,
    TEX_ALBEDO,
    TEX_EMISSION,
)
from usdahd.bake.kernels.lights import (
    light_importance,
    light_intersect,
    light_pdf,
    light_sample,
    nb_basis_apply,
    search_right,
)
from usdahd.bake.kernels.trace import (
    _OFFSET_PER_UNIT,
    nb_albedo,
    nb_emission,
    nb_hit_point,
    nb_offset,
    nb_random,
    nb_shading_normal,
    nb_trace_rays,
    nb_transmittance,
    nb_transmittance_rays,
)
from usdahd.bake.reference import (
    ALL_LIGHTS_MAX,
    G_HEMI,
    LIGHT_SELECTION_FLOOR,
    LIGHT_SHIFT,
    RR_DEPTH,
    SHADOW_SHORTEN,
)
from usdahd.numerics import sh as shmod


@njit(cache=True, nogil=True, error_model="numpy")
def native_result(ids, gram, hemi, nee, delta, count, back, regression, out, bf):
    """``Accum.result`` for texels ``ids`` (into ``out`` (n,3,9) f32 and ``bf`` (n,) f32):
    the same solve (9x9 LU with partial pivoting, 1e-9 ridge) per texel, on the threads."""
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
#: Register-fed Gram sums of the native pass (see :func:`_gram_unpack`).
GRAM_SUMS = 45


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
def _nee_sample(kind, p, img, pmf, cdf, tb, x, y, z, u0, u1):
    """``light_sample`` for every kind, including the emissive triangles (``EmissiveTriangles``
    .sample: triangle by power, uniform point, emission looked up in the material tables).
    returns (dx, dy, dz, dist, r, g, b, pdf)."""
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
        return dx, dy, dz, dist, 0.0, 0.0, 0.0, 0.0
    pdf = pmf[int(p[PAR_EM_PDF_AREA]) + tri] * dist * dist / cos_l
    mq = tb.tri_material[tri]
    if tb.mat_tex[mq, TEX_EMISSION] < 0:
        mc = tb.mat_const
        r, gg, b = mc[mq, MAT_EMISSION], mc[mq, MAT_EMISSION + 1], mc[mq, MAT_EMISSION + 2]
    else:
        r, gg, b = nb_emission(tb, tri, bu, bv)
    return dx, dy, dz, dist, r, gg, b, pdf


@helper
def _wl(mode, pl, pb):
    """``_w_light`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return _pw(pl, pb)
    return 1.0 if mode == MODE_NEE else 0.0


@helper
def _wb(mode, pb, pl):
    """``_w_bsdf`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return _pw(pb, pl)
    return 1.0 if mode == MODE_BSDF else 0.0


@helper
def _pw(a, b):
    den = a * a + b * b
    return a * a / den if den > 0.0 else 0.0


@helper
def _shadow1(ox, oy, oz, px, py, pz, dx, dy, dz, dist):
    """:func:`_shadow` for one ray: returns (dx, dy, dz, tfar)."""
    if not np.isfinite(dist):
        return dx, dy, dz, np.inf
    wx, wy, wz = px + dist * dx - ox, py + dist * dy - oy, pz + dist * dz - oz
    ln = np.sqrt(wx * wx + wy * wy + wz * wz)
    if not ln > 0.0:
        return dx, dy, dz, 0.0
    return wx / ln, wy / ln, wz / ln, ln * (1.0 - SHADOW_SHORTEN)


@helper
def _set_row(a, j, x0, x1, x2, x3, x4, x5, x6):
    a[j, 0] = x0
    a[j, 1] = x1
    a[j, 2] = x2
    a[j, 3] = x3
    a[j, 4] = x4
    a[j, 5] = x5
    a[j, 6] = x6


@helper
def _nee_pick(par, nee_idx, x, y, z, u):
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
def _nee_sel(par, nee_idx, q, x, y, z):
    """The probability :func:`_nee_pick` at (x, y, z) chooses light ``q`` (for MIS at hits)."""
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
def _ray_sel(par, nee_idx, area_idx, ps, j, sel, q):
    """Selection probability of light ``q`` in the NEE that path row ``j``'s ray is paired
    with (for the MIS weight when the ray hits ``q``): ``sel`` itself when >= 0, else the
    choice made at the point the ray left (PATH_X): over ``nee_idx`` at a vertex (-1), over
    ``area_idx`` at a texel with many lights (-2)."""
    if sel >= 0.0:
        return sel
    lst = nee_idx if sel > -1.5 else area_idx
    return _nee_sel(par, lst, q, ps[j, PATH_X], ps[j, PATH_X + 1], ps[j, PATH_X + 2])


@helper
def _paths(scene, pk, rec, tb, lt, lists, cfg, st, n, ps, rays, hits, srays, sval, sidx, occ, R):
    """``ReferenceCtx.incoming`` as a wavefront over the ``n`` paths in rows [0, n) of ``ps`` whose
    first hits are ``hits`` (the layout of ``embree.intersect_rays``): each path's
    radiance is added to ``R[k]`` (k its sample index). Per bounce, every live path makes one
    NEE shadow ray (``srays``, value ``sval``, sample ``sidx``) and one cosine continuation ray
    (``rays``; live rows are compacted to the front); both sets are traced as packets.
    Hit points are o + t d (no vertex fetch; error ~1e-7 t, far below the ray offset).
    returns : rays traced."""
    kind, par, img, pmf, cdf, ldelta, linf, lsampled = lt
    nee_idx, visible_idx, area_idx = lists.nee, lists.visible, lists.area
    tri_mat, mat_const, mat_tex = tb.tri_material, tb.mat_const, tb.mat_tex
    bounces = int(cfg[CFG_BOUNCES])
    transmission, has_em = cfg[CFG_TRANSMISSION] != 0.0, cfg[CFG_EMISSION] != 0.0
    em_q = int(cfg[CFG_EMISSIVE_LIGHT])  # the emissive-triangles light (-1: none)
    mode = int(cfg[CFG_STRATEGY])
    em_pdf = int(par[em_q, PAR_EM_PDF_AREA]) if em_q >= 0 else 0
    n_nee = nee_idx.shape[0]
    n_vis = visible_idx.shape[0]
    traced = 0
    while n > 0:
        nn = np.int64(0)  # live paths kept (nn <= j: row j is read before row nn is written)
        ns = np.int64(0)  # shadow rays (np.int64: no Literal[int](0) specializations)
        for j in range(n):
            ox, oy, oz = ps[j, PATH_O], ps[j, PATH_O + 1], ps[j, PATH_O + 2]
            dx, dy, dz = ps[j, PATH_D], ps[j, PATH_D + 1], ps[j, PATH_D + 2]
            br, bg, bb = ps[j, PATH_BETA], ps[j, PATH_BETA + 1], ps[j, PATH_BETA + 2]
            pdf_dir, sel = ps[j, PATH_PDF], ps[j, PATH_SEL]
            depth = int(ps[j, PATH_DEPTH])
            k = int(ps[j, PATH_SAMPLE])
            t, tri, u, v = hits[j, HIT_T], int(hits[j, HIT_TRI]), hits[j, HIT_U], hits[j, HIT_V]
            gx, gy, gz = hits[j, HIT_NG], hits[j, HIT_NG + 1], hits[j, HIT_NG + 2]
            miss = tri < 0
            Lr = Lg = Lb = 0.0
            for jj in range(n_vis):
                q = visible_idx[jj]
                kq = kind[q]
                # distant lights and uniform domes inline (the common sky); others called
                if kq == KIND_DISTANT:
                    pd = PAR_DIRECTION
                    hit = (
                        par[q, PAR_OMC] > 0.0
                        and dx * par[q, pd] + dy * par[q, pd + 1] + dz * par[q, pd + 2]
                        >= par[q, PAR_COS_MAX]
                    )
                    tl = np.inf
                    r, g, b = (
                        par[q, PAR_RADIANCE],
                        par[q, PAR_RADIANCE + 1],
                        par[q, PAR_RADIANCE + 2],
                    )
                elif kq == KIND_DOME and par[q, PAR_DOME_TEXTURED] == 0.0:
                    hit, tl = True, np.inf
                    r, g, b = (
                        par[q, PAR_RADIANCE],
                        par[q, PAR_RADIANCE + 1],
                        par[q, PAR_RADIANCE + 2],
                    )
                else:
                    hit, tl, r, g, b = light_intersect(kq, par[q], img, ox, oy, oz, dx, dy, dz)
                if not hit:
                    continue
                if (miss if linf[q] else tl < t) and (r != 0.0 or g != 0.0 or b != 0.0):
                    w = 1.0
                    if lsampled[q]:
                        sq = _ray_sel(par, nee_idx, area_idx, ps, j, sel, q)
                        pl = light_pdf(kind[q], par[q], pmf, ox, oy, oz, dx, dy, dz, tl) * sq
                        w = _wb(mode, pdf_dir, pl)
                    Lr += br * w * r
                    Lg += bg * w * g
                    Lb += bb * w * b
            for _once in range(1):  # a block to break out of
                if miss:
                    break
                cos_in = dx * gx + dy * gy + dz * gz
                mq = tri_mat[tri]  # constant materials inline, textured ones called
                if has_em and (cos_in < 0.0 or tb.tri_one_sided[tri] == 0):
                    if mat_tex[mq, TEX_EMISSION] < 0:
                        er = mat_const[mq, MAT_EMISSION]
                        eg = mat_const[mq, MAT_EMISSION + 1]
                        eb = mat_const[mq, MAT_EMISSION + 2]
                    else:
                        er, eg, eb = nb_emission(tb, tri, u, v)
                    w = 1.0
                    if em_q >= 0:  # MIS against the emitter's light samples
                        sq = _ray_sel(par, nee_idx, area_idx, ps, j, sel, em_q)
                        pe = sq * pmf[em_pdf + tri] * t * t / max(abs(cos_in), 1e-300)
                        w = _wb(mode, pdf_dir, pe)
                    Lr += br * er * w
                    Lg += bg * eg * w
                    Lb += bb * eb * w
                if depth + 1 > bounces:
                    break
                if mat_tex[mq, TEX_ALBEDO] < 0:
                    ar = min(max(mat_const[mq, MAT_ALBEDO], 0.0), 1.0)
                    ag = min(max(mat_const[mq, MAT_ALBEDO + 1], 0.0), 1.0)
                    ab = min(max(mat_const[mq, MAT_ALBEDO + 2], 0.0), 1.0)
                else:
                    ar, ag, ab = nb_albedo(tb, tri, u, v)
                if not (ar > 0.0 or ag > 0.0 or ab > 0.0):
                    break
                if depth + 1 > RR_DEPTH:
                    rr = min(max(max(ar, ag, ab), 0.05), 1.0)
                    if not (nb_random(st) < rr):
                        break
                    ar, ag, ab = ar / rr, ag / rr, ab / rr
                px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
                # the triangle's ray offset, and as many ulps of t (o + t d's error grows
                # with t; Tracer.offset, reference.ReferenceCtx.incoming)
                sc = max(tb.tri_offset[tri], _OFFSET_PER_UNIT * t)
                nx, ny, nz = nb_shading_normal(tb, tri, u, v)
                side = 1.0 if cos_in < 0.0 else -1.0
                gx, gy, gz = gx * side, gy * side, gz * side
                nx, ny, nz = nx * side, ny * side, nz * side
                if not (nx * gx + ny * gy + nz * gz > 0.0):
                    nx, ny, nz = gx, gy, gz
                br, bg, bb = br * ar, bg * ag, bb * ab
                depth += 1
                # next-event estimation: one light chosen by its importance here
                # (scene.lights.selection_pmf), its shadow ray queued
                if n_nee:
                    q, psel = _nee_pick(par, nee_idx, px, py, pz, nb_random(st))
                    u0 = nb_random(st)
                    u1 = nb_random(st)
                    lx, ly, lz, dist, r, g, b, pdf = _nee_sample(
                        kind[q], par[q], img, pmf, cdf, tb, px, py, pz, u0, u1
                    )
                    cos = lx * nx + ly * ny + lz * nz
                    if (
                        cos > 0.0
                        and lx * gx + ly * gy + lz * gz > 0.0
                        and pdf > 0.0
                        and (r > 0.0 or g > 0.0 or b > 0.0)
                    ):
                        if ldelta[q]:
                            f = cos / np.pi / psel
                        else:
                            pl = pdf * psel
                            f = _wl(mode, pl, cos / np.pi) * cos / np.pi / pl
                        qx, qy, qz = nb_offset(sc, px, py, pz, gx, gy, gz, lx, ly, lz)
                        sx, sy, sz, tf = _shadow1(qx, qy, qz, px, py, pz, lx, ly, lz, dist)
                        _set_row(srays, ns, qx, qy, qz, sx, sy, sz, tf)
                        sval[ns, 0] = br * r * f
                        sval[ns, 1] = bg * g * f
                        sval[ns, 2] = bb * b * f
                        sidx[ns] = k
                        ns += 1
                # continuation ray (also the MIS partner of the NEE sample)
                if not (n_vis > 0 or has_em or depth < bounces):
                    break
                # cosine-weighted (Malley): a uniform point of the unit disk, by rejection
                while True:
                    a = 2.0 * nb_random(st) - 1.0
                    b = 2.0 * nb_random(st) - 1.0
                    r2 = a * a + b * b
                    if r2 < 1.0:
                        break
                cz = np.sqrt(1.0 - r2)
                dx, dy, dz = nb_basis_apply(nx, ny, nz, a, b, cz)
                if not (dx * gx + dy * gy + dz * gz > 0.0):
                    break
                ox, oy, oz = nb_offset(sc, px, py, pz, gx, gy, gz, dx, dy, dz)
                _set_row(rays, nn, ox, oy, oz, dx, dy, dz, np.inf)
                _set_row(ps, nn, ox, oy, oz, dx, dy, dz, br)
                ps[nn, PATH_BETA + 1] = bg
                ps[nn, PATH_BETA + 2] = bb
                ps[nn, PATH_PDF] = cz / np.pi
                ps[nn, PATH_SEL] = -1.0  # the selection of this vertex, at PATH_X
                ps[nn, PATH_X], ps[nn, PATH_X + 1], ps[nn, PATH_X + 2] = px, py, pz
                ps[nn, PATH_DEPTH] = depth
                ps[nn, PATH_SAMPLE] = k
                nn += 1
            R[k, 0] += Lr
            R[k, 1] += Lg
            R[k, 2] += Lb
        if ns:
            traced += nb_transmittance_rays(scene, pk, rec, tb, transmission, srays, ns, occ)
            for q in range(ns):
                tr = occ[q]  # the fraction of the light's sample that arrives
                if tr > 0.0:
                    k = sidx[q]
                    R[k, 0] += tr * sval[q, 0]
                    R[k, 1] += tr * sval[q, 1]
                    R[k, 2] += tr * sval[q, 2]
        if nn:
            traced += nb_trace_rays(scene, pk, rec, tb, transmission, st, rays, nn, hits)
        n = nn
    return traced


@helper
def _texel_delta(scene, rec, tb, lt, delta_idx, cfg, st, i, P, NG, F, E, Y, delta):
    """Exact delta-light terms of texel ``i`` (one shadow ray per light). returns rays."""
    kind, par, img, pmf, cdf = lt.kind, lt.par, lt.img, lt.pmf, lt.cdf
    eps, transmission = E[i], cfg[CFG_TRANSMISSION] != 0.0
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    ngx, ngy, ngz = NG[i, 0], NG[i, 1], NG[i, 2]
    f = F[i]
    rays = 0
    for jj in range(delta_idx.shape[0]):
        j = delta_idx[jj]
        dx, dy, dz, dist, r, g, b, _ = light_sample(
            kind[j], par[j], img, pmf, cdf, px, py, pz, 0.0, 0.0
        )
        lz = f[2, 0] * dx + f[2, 1] * dy + f[2, 2] * dz
        if not (lz > 0.0 and dx * ngx + dy * ngy + dz * ngz > 0.0):
            continue
        qx, qy, qz = nb_offset(eps, px, py, pz, ngx, ngy, ngz, dx, dy, dz)
        sx, sy, sz, tf = _shadow1(qx, qy, qz, px, py, pz, dx, dy, dz, dist)
        tr, k = nb_transmittance(scene, rec, tb, transmission, qx, qy, qz, sx, sy, sz, tf)
        rays += k
        if not (tr > 0.0):
            continue
        r, g, b = tr * r, tr * g, tr * b
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
    """Add the register-fed Gram sums ``G`` (GRAM_SUMS,) to ``gram[i]`` and zero ``G``: slots
    0..7 are sum w Y_a (a = 1..8), 8..43 the upper triangle of sum w Y_a Y_b, 44 sum w, with
    w = 1/p per sample (row 0 of the Gram is C0 times the first sums)."""
    gram[i, 0, 0] += _C0 * _C0 * G[44]
    q = 8
    for a in range(1, 9):
        v = _C0 * G[a - 1]
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
def native_pass(
    scene, tb, lt, lists, cfg, ids, P, NG, F, E, s, r2h, r2n, rng_state, do_delta, acc, work
):
    """One pass of ``s`` hemisphere (+ light) samples for texels ``ids`` of a chunk.

    P, NG : (n,3) f64; F : (n,3,3) f64; E : (n,) f64 ray-origin offsets
    (``Tracer.texel_offsets``); r2h : (s,4) R2 points for the hemisphere with
    cos/sin of 2 pi times their second coordinate; r2n : (s,2) R2 points for the light
    samples; acc : (gram, hemi, nee, delta, count, back, y_sum, y_sq, y_half) of ``Accum``;
    work : per-thread scratch from :func:`native_work` (RTCRayHit record, packet, (1,) uint64
    random state, (9,) basis, (GRAM_SUMS,) zeroed Gram sums, (27,) zeroed hemisphere sums, the
    per-sample wavefront arrays). Compiled without the NRT (``_nrt=False``): no allocation
    and no reference counting in the hot loop.
    returns : rays traced.
    """
    kind, par, img, pmf, cdf, ldelta, linf, lsampled = lt
    delta_idx, area_idx = lists.delta, lists.area
    gram, hemi, nee, delta, count, back, y_sum, y_sq, y_half = acc
    transmission = cfg[CFG_TRANSMISSION] != 0.0
    regression = cfg[CFG_REGRESSION] != 0.0
    mode = int(cfg[CFG_STRATEGY])
    n_area = area_idx.shape[0]
    every = n_area <= ALL_LIGHTS_MAX  # every light gets every texel light sample
    # else each sample picks one by the bound at the texel (PATH_SEL -2: _nee_pick over
    # ``lists.area`` at PATH_X, for the MIS of the hemisphere rays)
    sel_area = 1.0 if every else -2.0
    rec, pk, st, Y, G, H, ps, rays, hits, srays, sval, sidx, occ, R, loc, yl = work
    traced = 0
    for ii in range(ids.shape[0]):
        i = ids[ii]
        st[0] = rng_state[i]
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        ngx, ngy, ngz = NG[i, 0], NG[i, 1], NG[i, 2]
        f = F[i]
        eps = E[i]
        if do_delta:
            traced += _texel_delta(scene, rec, tb, lt, delta_idx, cfg, st, i, P, NG, F, E, Y, delta)
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
                _set_row(rays, m, qx, qy, qz, dx, dy, dz, np.inf)
                _set_row(ps, m, qx, qy, qz, dx, dy, dz, 1.0)
                ps[m, PATH_BETA + 1] = ps[m, PATH_BETA + 2] = 1.0
                ps[m, PATH_PDF] = (1.0 + 2.0 * lz) * _INV_4PI
                ps[m, PATH_SEL] = sel_area
                ps[m, PATH_X], ps[m, PATH_X + 1], ps[m, PATH_X + 2] = px, py, pz
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
            traced += _paths(
                scene, pk, rec, tb, lt, lists, cfg, st, m, ps, rays, hits, srays, sval, sidx,
                occ, R,
            )  # fmt: skip
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
                    j, psel = _nee_pick(par, area_idx, px, py, pz, nb_random(st))
                dx, dy, dz, dist, r, g, b, pdf = _nee_sample(
                    kind[j], par[j], img, pmf, cdf, tb, px, py, pz, u0, u1
                )
                lz = f[2, 0] * dx + f[2, 1] * dy + f[2, 2] * dz
                if (
                    pdf > 0.0
                    and lz > 0.0
                    and dx * ngx + dy * ngy + dz * ngz > 0.0
                    and (r > 0.0 or g > 0.0 or b > 0.0)
                ):
                    ox, oy, oz = nb_offset(eps, px, py, pz, ngx, ngy, ngz, dx, dy, dz)
                    sx, sy, sz, tf = _shadow1(ox, oy, oz, px, py, pz, dx, dy, dz, dist)
                    _set_row(srays, ns, ox, oy, oz, sx, sy, sz, tf)
                    pl = pdf * psel
                    wgt = _wl(mode, pl, (1.0 + 2.0 * lz) * _INV_4PI) / pl
                    sval[ns, 0], sval[ns, 1], sval[ns, 2] = r * wgt, g * wgt, b * wgt
                    sval[ns, 3] = f[0, 0] * dx + f[0, 1] * dy + f[0, 2] * dz
                    sval[ns, 4] = f[1, 0] * dx + f[1, 1] * dy + f[1, 2] * dz
                    sval[ns, 5] = lz
                    sidx[ns] = k
                    ns += 1
            if ns:
                traced += nb_transmittance_rays(scene, pk, rec, tb, transmission, srays, ns, occ)
                for q in range(ns):
                    tr = occ[q]
                    if not (tr > 0.0):
                        continue
                    _sh9(Y, sval[q, 3], sval[q, 4], sval[q, 5])
                    r, g, b = tr * sval[q, 0], tr * sval[q, 1], tr * sval[q, 2]
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
            x, y, z = loc[k, 0], loc[k, 1], loc[k, 2]
            y1, y2, y3 = -_C1 * y, _C1 * z, -_C1 * x
            y4, y5 = _C2 * x * y, -_C2 * y * z
            y6, y7, y8 = _C20 * (3.0 * z * z - 1.0), -_C2 * x * z, _C22 * (x * x - y * y)
            wp = _4PI / (1.0 + 2.0 * z)
            for c in range(3):
                w = wp * R[k, c]
                H[9 * c] += w * _C0
                H[9 * c + 1] += w * y1
                H[9 * c + 2] += w * y2
                H[9 * c + 3] += w * y3
                H[9 * c + 4] += w * y4
                H[9 * c + 5] += w * y5
                H[9 * c + 6] += w * y6
                H[9 * c + 7] += w * y7
                H[9 * c + 8] += w * y8
            if regression:  # upper triangle of w Y Y^T (rows 1..8; row 0 is C0 * sum w Y)
                G[44] += wp
                w1, w2, w3, w4 = wp * y1, wp * y2, wp * y3, wp * y4
                w5, w6, w7, w8 = wp * y5, wp * y6, wp * y7, wp * y8
                G[0] += w1
                G[1] += w2
                G[2] += w3
                G[3] += w4
                G[4] += w5
                G[5] += w6
                G[6] += w7
                G[7] += w8
                G[8] += w1 * y1
                G[9] += w1 * y2
                G[10] += w1 * y3
                G[11] += w1 * y4
                G[12] += w1 * y5
                G[13] += w1 * y6
                G[14] += w1 * y7
                G[15] += w1 * y8
                G[16] += w2 * y2
                G[17] += w2 * y3
                G[18] += w2 * y4
                G[19] += w2 * y5
                G[20] += w2 * y6
                G[21] += w2 * y7
                G[22] += w2 * y8
                G[23] += w3 * y3
                G[24] += w3 * y4
                G[25] += w3 * y5
                G[26] += w3 * y6
                G[27] += w3 * y7
                G[28] += w3 * y8
                G[29] += w4 * y4
                G[30] += w4 * y5
                G[31] += w4 * y6
                G[32] += w4 * y7
                G[33] += w4 * y8
                G[34] += w5 * y5
                G[35] += w5 * y6
                G[36] += w5 * y7
                G[37] += w5 * y8
                G[38] += w6 * y6
                G[39] += w6 * y7
                G[40] += w6 * y8
                G[41] += w7 * y7
                G[42] += w7 * y8
                G[43] += w8 * y8
            lum = _LUM[0] * R[k, 0] + _LUM[1] * R[k, 1] + _LUM[2] * R[k, 2]
            ylum = wp * _IZ * lum * y2 + yl[k]
            ys += ylum
            ys2 += ylum * ylum
            if k % 2 == 0:
                yh += ylum
        for c in range(3):
            for c9 in range(9):
                hemi[i, c, c9] += H[9 * c + c9]
                H[9 * c + c9] = 0.0
        y_sum[i] += ys
        y_sq[i] += ys2
        y_half[i] += yh
        back[i] += n_back
        count[i] += s
        rng_state[i] = st[0]
        if regression:
            _gram_unpack(gram, i, G)
    return traced


def native_work(s):
    """Per-thread scratch of :func:`native_pass` for passes of ``s`` samples."""
    return (
        embree.new_scratch(),
        embree.new_packet(),
        np.zeros(1, np.uint64),
        np.zeros(9),
        np.zeros(GRAM_SUMS),
        np.zeros(27),
        np.zeros((s, PATH_COLS)),
        np.zeros((s, 7)),
        np.zeros((s, 7)),
        np.zeros((s, 7)),
        np.zeros((s, 6)),
        np.zeros(s, np.int64),
        np.zeros(s),  # shadow-ray transmittance
        np.zeros((s, 3)),
        np.zeros((s, 3)),
        np.zeros(s),
    )
