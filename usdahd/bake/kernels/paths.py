"""The path wavefront of the native integrator: ``ReferenceCtx.incoming``/``reflect`` for the
paths of one texel's pass (:func:`trace_paths`, called by
:func:`usdahd.bake.kernels.integrate.native_pass`). Row records are named in
:mod:`usdahd.bake.kernels.layout` (``PATH_*``, ``HIT_*``, ``RAY_*``, ``SVAL_*``).
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.kernels import cache  # noqa: F401  (numba cache locators, before any @njit)
from usdahd.bake.kernels.cache import helper
from usdahd.bake.kernels.layout import (
    CFG_BOUNCES,
    CFG_EMISSION,
    CFG_EMISSIVE_LIGHT,
    CFG_LINKED,
    CFG_SHADOW_LINKED,
    CFG_STRATEGY,
    CFG_TRANSMISSION,
    HIT_NG,
    HIT_T,
    HIT_TRI,
    HIT_U,
    HIT_V,
    KIND_DISTANT,
    KIND_DOME,
    MAT_ALBEDO,
    MAT_EMISSION,
    PAR_COS_MAX,
    PAR_DIRECTION,
    PAR_DOME_TEXTURED,
    PAR_EM_PDF_AREA,
    PAR_OMC,
    PAR_RADIANCE,
    PATH_BETA,
    PATH_D,
    PATH_DEPTH,
    PATH_MESH,
    PATH_O,
    PATH_PDF,
    PATH_SAMPLE,
    PATH_SEL,
    PATH_X,
    SVAL_RGB,
    TEX_ALBEDO,
    TEX_EMISSION,
)
from usdahd.bake.kernels.lights import light_intersect, light_pdf, nb_basis_apply
from usdahd.bake.kernels.shading import (
    link_occluded,
    lit,
    nee_pick,
    nee_sample,
    put3,
    put_ray,
    ray_sel,
    shadow1,
    shadow_rays,
    w_bsdf,
    w_light,
)
from usdahd.bake.kernels.trace import (
    OFFSET_PER_UNIT,
    nb_albedo,
    nb_emission,
    nb_offset,
    nb_random,
    nb_shading_normal,
    nb_trace_rays,
)
from usdahd.bake.reference import RR_DEPTH

__all__ = ["trace_paths"]


@helper
def trace_paths(scene, tb, lt, lists, cfg, n, work):
    """``ReferenceCtx.incoming`` as a wavefront over the ``n`` paths in rows [0, n) of ``ps`` whose
    first hits are ``hits`` (the layout of ``embree.intersect_rays``), in the arrays of
    ``work`` (:class:`~usdahd.bake.kernels.layout.NativeWork`): each path's radiance is added
    to ``R[k]`` (k its sample index). Per bounce, every live path makes one NEE shadow ray
    (``srays``, value ``sval``, sample ``sidx``, light ``slight``) and one cosine continuation
    ray (``rays``; live rows are compacted to the front); both sets are traced as packets.
    Hit points are o + t d (no vertex fetch; error ~1e-7 t, far below the ray offset).
    With light linking (``cfg[CFG_LINKED]``), a light reaches a path's radiance only where it
    lights the mesh the ray left (``PATH_MESH``) or the vertex's mesh, and a shadow-linked
    light's visibility passes through the meshes that do not cast its shadows.
    returns : rays traced."""
    kind, par, img, pmf, cdf = lt.kind, lt.par, lt.img, lt.pmf, lt.cdf
    ldelta, linf, lsampled = lt.delta, lt.infinite, lt.sampled
    pk, rec, st, ps, rays, hits = work.pk, work.rec, work.st, work.ps, work.rays, work.hits
    srays, sval, sidx, slight, occ, R = (work.srays, work.sval, work.sidx, work.slight,
                                         work.occ, work.R)  # fmt: skip
    linked = cfg[CFG_LINKED] != 0.0
    shadow_linked = cfg[CFG_SHADOW_LINKED] != 0.0
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
            src = int(ps[j, PATH_MESH]) if linked else -1
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
                if linked:
                    if not lit(lt, q, src):
                        continue
                    if lt.shadow_linked[q]:  # only casting meshes stand between
                        blocked, k2 = link_occluded(scene, rec, tb, lt, q, transmission, st,
                                                    ox, oy, oz, dx, dy, dz, tl)  # fmt: skip
                        traced += k2
                        if not blocked and (r != 0.0 or g != 0.0 or b != 0.0):
                            w = 1.0
                            if lsampled[q]:
                                sq = ray_sel(par, nee_idx, area_idx, ps, j, sel, q)
                                pl = light_pdf(kind[q], par[q], pmf, ox, oy, oz, dx, dy, dz, tl)
                                w = w_bsdf(mode, pdf_dir, pl * sq)
                            Lr += br * w * r
                            Lg += bg * w * g
                            Lb += bb * w * b
                        continue
                if (miss if linf[q] else tl < t) and (r != 0.0 or g != 0.0 or b != 0.0):
                    w = 1.0
                    if lsampled[q]:
                        sq = ray_sel(par, nee_idx, area_idx, ps, j, sel, q)
                        pl = light_pdf(kind[q], par[q], pmf, ox, oy, oz, dx, dy, dz, tl) * sq
                        w = w_bsdf(mode, pdf_dir, pl)
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
                        sq = ray_sel(par, nee_idx, area_idx, ps, j, sel, em_q)
                        pe = sq * pmf[em_pdf + tri] * t * t / max(abs(cos_in), 1e-300)
                        w = w_bsdf(mode, pdf_dir, pe)
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
                sc = max(tb.tri_offset[tri], OFFSET_PER_UNIT * t)
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
                vmesh = tb.tri_mesh[tri] if linked else -1  # the vertex's mesh (linking)
                if n_nee:
                    q, psel = nee_pick(par, nee_idx, px, py, pz, nb_random(st))
                    u0 = nb_random(st)
                    u1 = nb_random(st)
                    ls = nee_sample(kind[q], par[q], img, pmf, cdf, tb, px, py, pz, u0, u1)
                    lx, ly, lz, dist, pdf = ls.dx, ls.dy, ls.dz, ls.dist, ls.pdf
                    r, g, b = ls.r, ls.g, ls.b
                    cos = lx * nx + ly * ny + lz * nz
                    if (
                        cos > 0.0
                        and lx * gx + ly * gy + lz * gz > 0.0
                        and pdf > 0.0
                        and (r > 0.0 or g > 0.0 or b > 0.0)
                        and (not linked or lit(lt, q, vmesh))
                    ):
                        if ldelta[q]:
                            f = cos / np.pi / psel
                        else:
                            pl = pdf * psel
                            f = w_light(mode, pl, cos / np.pi) * cos / np.pi / pl
                        qx, qy, qz = nb_offset(sc, px, py, pz, gx, gy, gz, lx, ly, lz)
                        sx, sy, sz, tf = shadow1(qx, qy, qz, px, py, pz, lx, ly, lz, dist)
                        put_ray(srays, ns, qx, qy, qz, sx, sy, sz, tf)
                        put3(sval, ns, SVAL_RGB, br * r * f, bg * g * f, bb * b * f)
                        sidx[ns] = k
                        slight[ns] = q
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
                put_ray(rays, nn, ox, oy, oz, dx, dy, dz, np.inf)
                put3(ps, nn, PATH_O, ox, oy, oz)
                put3(ps, nn, PATH_D, dx, dy, dz)
                put3(ps, nn, PATH_BETA, br, bg, bb)
                ps[nn, PATH_PDF] = cz / np.pi
                ps[nn, PATH_SEL] = -1.0  # the selection of this vertex, at PATH_X
                put3(ps, nn, PATH_X, px, py, pz)
                ps[nn, PATH_MESH] = vmesh
                ps[nn, PATH_DEPTH] = depth
                ps[nn, PATH_SAMPLE] = k
                nn += 1
            R[k, 0] += Lr
            R[k, 1] += Lg
            R[k, 2] += Lb
        if ns:
            traced += shadow_rays(scene, pk, rec, tb, lt, transmission, shadow_linked, st, srays,
                                  slight, ns, occ)  # fmt: skip
            for q in range(ns):
                tr = occ[q]  # the fraction of the light's sample that arrives
                if tr > 0.0:
                    k = sidx[q]
                    R[k, 0] += tr * sval[q, SVAL_RGB]
                    R[k, 1] += tr * sval[q, SVAL_RGB + 1]
                    R[k, 2] += tr * sval[q, SVAL_RGB + 2]
        if nn:
            traced += nb_trace_rays(scene, pk, rec, tb, transmission, st, rays, nn, hits)
        n = nn
    return traced
