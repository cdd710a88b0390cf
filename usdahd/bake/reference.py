"""The numpy reference path tracer (backend "embreex") and what it shares with the numba kernel.

:class:`ReferenceCtx` is the estimator of :mod:`usdahd.bake.integrate` written with numpy
wavefronts over batched tracer queries (``Tracer.intersect``/``occluded``), including UsdLux
light linking; :mod:`usdahd.bake.kernels.integrate` is its numba port (per-texel, Embree called
from numba). :class:`Accum` holds the per-texel sums both fill, and ``Accum.result`` is the
numpy twin of ``kernels.integrate.native_result`` (tests/test_trace.py). The MIS weights
(:func:`_w_light`/:func:`_w_bsdf`), :func:`_shadow` and the constants below have numba twins in
the kernel (tests/test_kernel_parity.py).
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.kernels.layout import AccumArrays
from usdahd.numerics import sh as shmod
from usdahd.numerics.offsets import FLT_EPS, OFFSET_ULPS
from usdahd.numerics.sampling import (
    cosine_hemisphere,
    orthonormal_basis,
    r2_sequence,
    texel_hemisphere,
    texel_hemisphere_pdf,
    to_local,
    to_world,
)
from usdahd.scene.lights import EmissiveTriangles, selection_pmf

__all__ = [
    "ALL_LIGHTS_MAX",
    "Accum",
    "G_HEMI",
    "LIGHT_SELECTION_FLOOR",
    "LIGHT_SHIFT",
    "LINK_MAX_CROSSINGS",
    "LightGroups",
    "RR_DEPTH",
    "ReferenceCtx",
    "SHADOW_SHORTEN",
    "has_light_linking",
]

#: Reflections before Russian roulette starts (bounces <= RR_DEPTH are never terminated).
RR_DEPTH = 3
#: Adaptive: floor of the convergence test, relative to the chunk's largest Iz.
ADAPTIVE_FLOOR = 1e-3
#: Shadow rays stop short of the light sample by this fraction (avoids hitting the emitter's
#: own supporting geometry, e.g. a RectLight on an emissive quad).
SHADOW_SHORTEN = 1e-4
#: Surfaces a shadow ray of a shadow-linked light passes through (meshes its shadowLink
#: collection excludes) at most; a ray still going after that counts as unoccluded.
LINK_MAX_CROSSINGS = 32
#: Up to this many sampled lights, every light gets every texel light sample (selection noise
#: removed at m shadow rays per sample); beyond, each sample picks one light by
#: ``scene.lights.selection_pmf`` at the texel.
ALL_LIGHTS_MAX = 8
#: At path vertices one light is sampled, chosen by ``scene.lights.selection_pmf``: a share
#: proportional to each light's irradiance bound there plus this uniform floor (so a light
#: the bound underrates keeps probability >= floor / n and a bounded weight). Against the
#: uniform choice it had before, McUsd (sun, textured dome, lava) at 256 spp: relRMSE against
#: Cycles' 1.89x -> 0.97x; floors 0.02 / 0.1 / 0.3 gave 0.71x / 0.76x / 0.90x (with the
#: shadow-ray transmittance), 0.1 kept for the bounded weight (docs/time-to-quality.md).
LIGHT_SELECTION_FLOOR = 0.1
#: Offset of light j's copy of the texel's light-sample points (golden ratio conjugate, both
#: coordinates), so the lights do not share one point pattern.
LIGHT_SHIFT = 0.6180339887498949
#: The hemispherical Gram matrix (9, 9) float64 (one copy: usdahd.numerics.sh).
G_HEMI = shmod.HEMISPHERICAL_GRAM


class LightGroups:
    """Light lists split by how the integrator uses them. With a ``tracer`` whose scene has
    emissive materials, its emissive triangles join as one more sampled light
    (:class:`EmissiveTriangles`); rays reach them as geometry, not through ``visible``."""

    def __init__(self, lights, tracer=None):
        self.all = list(lights)
        self.emissive = None
        if tracer is not None and tracer.has_emission:
            self.emissive = EmissiveTriangles.from_tracer(tracer)
            if self.emissive is not None:
                self.all.append(self.emissive)
        self.delta = [lt for lt in self.all if lt.delta]
        self.area = [lt for lt in self.all if not lt.delta and lt.sampled]  # MIS partners
        self.hit_only = [lt for lt in self.all if not lt.delta and not lt.sampled]
        self.nee = self.delta + self.area  # sampled at secondary vertices
        # can be hit by BSDF rays (emitters are hit as geometry)
        self.visible = [lt for lt in self.area + self.hit_only if lt is not self.emissive]


class Accum:
    """Per-texel running sums (so passes and estimators combine): the arrays of
    :class:`usdahd.bake.kernels.layout.AccumArrays` (``acc.gram``, ``acc.count``, ...; the
    tuple itself, as the native kernel takes it, is ``acc.arrays``)."""

    def __init__(self, n):
        self.arrays = AccumArrays.alloc(n=n)

    def __getattr__(self, name):
        if name == "arrays":  # not yet set (e.g. during unpickling)
            raise AttributeError(name)
        return getattr(self.arrays, name)

    def converged(self, active, tol):
        c = self.count[active].astype(np.float64)
        mean = self.y_sum[active] / c
        var = np.maximum(self.y_sq[active] / c - mean * mean, 0.0)
        se = np.sqrt(var / c)
        base = self.delta[active][:, :, 2] @ shmod.LUMINANCE * shmod.IZ_FROM_L10
        level = np.abs(mean + base)
        floor = ADAPTIVE_FLOOR * (level.max() if len(level) else 0.0)
        return se <= tol * np.maximum(level, floor)

    def iz_variance(self):
        """(n,) float64 variance of each texel's mean per-sample luminance I_z estimate (the
        hemisphere and light-sample terms; delta lights are exact): the unbiased sample
        variance over the count, s^2 / count (0 below 2 samples)."""
        c = self.count.astype(np.float64)
        safe = np.maximum(c, 2.0)
        mean = self.y_sum / np.maximum(c, 1.0)
        s2 = np.maximum(self.y_sq - c * mean * mean, 0.0) / (safe - 1.0)
        return np.where(c >= 2, s2 / safe, 0.0)

    def iz_variance_halves(self):
        """(n,) float64 estimate of the variance of each texel's mean I_z estimate from its
        two interleaved halves (even- and odd-numbered samples of every pass): with A, B the
        halves' means over a, b samples (a + b = count), ``(A - B)^2 a b / count^2``, unbiased
        for independent samples, and still an upper bound when the halves are anticorrelated,
        as two interleaved halves of one stratified R2 pattern are (each fills the other's
        gaps). It measures the error of the stratified estimate itself, where s^2 / count
        (``iz_variance``) measures that of independent samples: a texel across a sharp shadow
        edge has a large s^2 but a small stratified error. One degree of freedom per texel,
        so pool it over neighbours before use (``usdahd.bake.denoise``). 0 below 2 samples."""
        n = self.count.astype(np.float64)
        a = self.n_half.astype(np.float64)
        b = n - a
        ok = (a > 0) & (b > 0)
        mean_a = self.y_half / np.where(ok, a, 1.0)
        mean_b = (self.y_sum - self.y_half) / np.where(ok, b, 1.0)
        return np.where(ok, (mean_a - mean_b) ** 2 * a * b / np.where(ok, n * n, 1.0), 0.0)

    def result(self, estimator):
        c = np.maximum(self.count, 1).astype(np.float64)
        b = self.hemi / c[:, None, None]
        if estimator == "regression":
            g = self.gram / c[:, None, None]
            ok = self.count >= 16
            if np.any(ok):
                x = np.linalg.solve(g[ok] + 1e-9 * np.eye(9), b[ok].transpose(0, 2, 1))
                b[ok] = np.matmul(G_HEMI, x).transpose(0, 2, 1)
        res = b + self.nee / c[:, None, None] + self.delta
        return res.astype(np.float32), (self.back / c).astype(np.float32)


class ReferenceCtx:
    def __init__(self, scene, tracer, bounces, estimator, strategy="mis", mesh=None):
        self.strategy = strategy
        self.scene = scene
        self.tr = tracer
        self.bounces = bounces
        self.lights = LightGroups(scene.lights, tracer)
        # light linking (UsdLux collection:lightLink / shadowLink): per light, a bool mask over
        # scene meshes of the receivers it lights and of the meshes that cast its shadows
        # (None: every mesh); the texels' own mesh index receives as ``mesh``
        nm = len(scene.meshes)
        self.recv = {id(lt): _mesh_mask(getattr(lt, "lit_meshes", None), nm) for lt in scene.lights}
        self.cast = {
            id(lt): _mesh_mask(getattr(lt, "shadow_meshes", None), nm) for lt in scene.lights
        }
        self.texel_mesh = -1 if mesh is None else int(mesh)
        self.nee_bounds = [lt.bound() for lt in self.lights.nee]
        self.area_bounds = [lt.bound() for lt in self.lights.area]
        self.estimator = estimator
        # rays per hemisphere sample, for the rays_saved estimate
        self.rays_per_sample = 1 + (1 if self.lights.area else 0) + 3 * bounces

    # ------------------------------------------------------------------ texel level
    def direct_delta(self, P, NG, F, E, acc):
        """Exact contribution of delta lights: one shadow ray per texel and light."""
        for lt in self.lights.delta:
            ls = lt.sample(P, np.zeros((len(P), 2)))
            d, dist, val = ls.dirs, ls.dist, ls.value
            loc = to_local(d, F)
            ok = (loc[:, 2] > 0) & (np.einsum("ij,ij->i", d, NG) > 0)
            ok &= self._lit(lt, np.full(len(P), self.texel_mesh))
            if not np.any(ok):
                continue
            idx = np.nonzero(ok)[0]
            o = self.tr.offset(P[idx], NG[idx], d[idx], E[idx])
            tr = self._visibility(lt, o, *_shadow(o, P[idx], d[idx], dist[idx]))
            keep = tr > 0
            idx, tr = idx[keep], tr[keep]
            f = val[idx] * tr[:, None]
            acc.delta[idx] += np.einsum("nc,nk->nck", f, shmod.basis(loc[idx]))

    def hemisphere_pass(self, P, NG, F, E, s, offset, rng, acc, active):
        n = len(P)
        u = np.mod(r2_sequence(s, offset)[None] + rng.random((n, 1, 2)), 1.0)  # (n,s,2)
        loc, pdf_h = texel_hemisphere(u)  # (n,s,3), (n,s)
        d = to_world(loc, F[:, None]).reshape(-1, 3)
        loc = loc.reshape(-1, 3)
        Pf = np.repeat(P, s, axis=0)
        NGf = np.repeat(NG, s, axis=0)
        Ef = np.repeat(E, s, axis=0)
        above = np.einsum("ij,ij->i", d, NGf) > 0
        radiance = np.zeros((n * s, 3))
        back = np.zeros(n * s, bool)
        idx = np.nonzero(above)[0]
        texel_sel = self._texel_selection(P)
        if len(idx):
            o = self.tr.offset(Pf[idx], NGf[idx], d[idx], Ef[idx])
            hits = self.tr.intersect(o, d[idx], rng=rng)
            tri = hits["tri"]
            gn = self.tr.geom_normal[np.where(tri >= 0, tri, 0)]
            back[idx] = self.tr.back_face(tri, d[idx], gn)
            src = np.full(len(idx), self.texel_mesh)
            sel = texel_sel
            if np.ndim(texel_sel):  # (n, m) per texel -> the rays' rows
                sel = (np.repeat(texel_sel, s, axis=0)[idx], self.lights.area)
            radiance[idx] = self.incoming(o, d[idx], hits, pdf_h.reshape(-1)[idx], sel, 0, rng, src)
        Y = shmod.basis(loc).reshape(n, s, 9)
        R = radiance.reshape(n, s, 3)
        Ywt = (Y / pdf_h[..., None]).transpose(0, 2, 1)  # Y / p
        acc.hemi[active] += np.matmul(Ywt, R).transpose(0, 2, 1)
        if self.estimator == "regression":
            acc.gram[active] += np.matmul(Ywt, Y)
        acc.back[active] += back.reshape(n, s).sum(axis=1)
        acc.count[active] += s
        ylum = shmod.IZ_FROM_L10 * (R @ shmod.LUMINANCE) * Y[..., 2] / pdf_h
        if self.lights.area:
            nee_c, nee_y = self.texel_nee(P, NG, F, E, s, offset, rng, texel_sel)
            acc.nee[active] += nee_c
            ylum = ylum + nee_y
        acc.y_sum[active] += ylum.sum(axis=1)
        acc.y_sq[active] += (ylum * ylum).sum(axis=1)
        acc.y_half[active] += ylum[:, ::2].sum(axis=1)

    def _texel_selection(self, P):
        """Selection probability of each sampled light in the texels' light samples: 1 when
        there are at most ALL_LIGHTS_MAX (every light gets every sample), else (n, m) float64,
        ``selection_pmf`` of the area lights at the texels ``P`` (n, 3)."""
        if len(self.lights.area) <= ALL_LIGHTS_MAX:
            return 1.0
        return selection_pmf(self.area_bounds, P, LIGHT_SELECTION_FLOOR)

    def texel_nee(self, P, NG, F, E, s, offset, rng, texel_sel=None):
        """Light samples at the texel (MIS with the texel hemisphere); returns sums
        (c (n,3,9), per-sample luminance Iz (n,s)). With at most ALL_LIGHTS_MAX sampled lights
        every light gets every sample (no light-selection noise; ``texel_sel`` = 1), else each
        sample picks one light by ``texel_sel`` (n, m) (:meth:`_texel_selection`)."""
        n = len(P)
        m = len(self.lights.area)
        u = np.mod(r2_sequence(s, offset + 7919)[None] + rng.random((n, 1, 2)), 1.0)
        u = u.reshape(-1, 2)
        every = m <= ALL_LIGHTS_MAX
        if texel_sel is None:
            texel_sel = self._texel_selection(P)
        if not every:
            sel_rows = np.repeat(texel_sel, s, axis=0)  # (n s, m)
            cdf = np.cumsum(sel_rows, axis=1)
            pick = np.minimum((rng.random(n * s)[:, None] >= cdf).sum(axis=1), m - 1)
        Pf = np.repeat(P, s, axis=0)
        NGf = np.repeat(NG, s, axis=0)
        Ef = np.repeat(E, s, axis=0)
        Ff = np.repeat(F, s, axis=0)
        c = np.zeros((n, 3, 9))
        y = np.zeros(n * s)
        for j, lt in enumerate(self.lights.area):
            if every:
                idx = np.arange(n * s)
                uj = np.mod(u + j * LIGHT_SHIFT, 1.0)  # decorrelate the lights' points
            else:
                idx = np.nonzero(pick == j)[0]
                uj = u[idx]
            if len(idx) == 0:
                continue
            ls = lt.sample(Pf[idx], uj)
            d, dist, val, pdf = ls.dirs, ls.dist, ls.value, ls.pdf
            loc = to_local(d, Ff[idx])
            ok = (pdf > 0) & (loc[:, 2] > 0) & (np.einsum("ij,ij->i", d, NGf[idx]) > 0)
            ok &= np.any(val > 0, axis=1) & self._lit(lt, np.full(len(idx), self.texel_mesh))
            idx, d, dist, val, pdf, loc = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], loc[ok]
            if len(idx) == 0:
                continue
            o = self.tr.offset(Pf[idx], NGf[idx], d, Ef[idx])
            tr = self._visibility(lt, o, *_shadow(o, Pf[idx], d, dist), rng=rng)
            vis = tr > 0
            idx, val, pdf, loc = idx[vis], val[vis] * tr[vis, None], pdf[vis], loc[vis]
            pl = pdf * (1.0 if every else sel_rows[idx, j])
            w = _w_light(self.strategy, pl, texel_hemisphere_pdf(loc[:, 2]))
            f = val * (w / pl)[:, None]
            Yb = shmod.basis(loc)
            np.add.at(c, idx // s, np.einsum("mc,mk->mck", f, Yb))
            np.add.at(y, idx, shmod.IZ_FROM_L10 * (f @ shmod.LUMINANCE) * Yb[:, 2])
        return c, y.reshape(n, s)

    # ------------------------------------------------------------------ path level
    def incoming(self, o, d, hits, pdf_dir, sel_area, depth, rng, src):
        """Radiance arriving at ``o`` along ``d`` (m,3), MIS-weighted against light sampling.

        pdf_dir : (m,) solid-angle pdf the direction was sampled with; sel_area : selection
        probability of an area light in the NEE the direction is paired with (a scalar, the
        same for every light), or (matrix (m, k) float64 per ray and light, the k lights it
        chose among: ``lights.nee`` at a vertex (:meth:`reflect`), ``lights.area`` at a texel
        with many lights); depth :
        reflections already made along the path; src : (m,) int mesh index of the surface
        the rays leave (the receiver, for light linking; -1: unknown, lit by every light).
        """
        m = len(o)
        L = np.zeros((m, 3))
        t = hits["t"].astype(np.float64)
        tri = hits["tri"]
        miss = tri < 0
        for lt in self.lights.visible:
            lh = lt.intersect(o, d)
            hit, tl, rad = lh.hit, lh.t, lh.radiance
            if self.cast.get(id(lt)) is None:
                vis = hit & (miss if lt.infinite else (tl < t))
            else:  # shadow-linked: only casting meshes may stand between the ray and the light
                vis = hit.copy()
                idx = np.nonzero(hit)[0]
                if len(idx):
                    vis[idx] = ~self._occluded(lt, o[idx], d[idx], tl[idx])
            vis &= self._lit(lt, src)
            if not np.any(vis):
                continue
            w = np.ones(int(vis.sum()))
            if lt.sampled:
                pl = lt.pdf(o[vis], d[vis], tl[vis]) * self._sel(sel_area, lt, vis)
                w = _w_bsdf(self.strategy, pdf_dir[vis], pl)
            L[vis] += w[:, None] * rad[vis]
        surf = np.nonzero(~miss)[0]
        if len(surf) == 0:
            return L
        tri_s = tri[surf]
        u, v = hits["u"][surf], hits["v"][surf]
        gn = self.tr.geom_normal[tri_s].astype(np.float64)
        ds = d[surf]
        front = np.einsum("ij,ij->i", ds, gn) < 0
        if self.tr.has_emission:
            em = self.tr.emission_at(tri_s, u, v).astype(np.float64)
            if self.lights.emissive is not None:  # MIS against the emitter's light samples
                cos_abs = np.abs(np.einsum("ij,ij->i", ds, gn))
                pl = self.lights.emissive.pdf_hit(tri_s, t[surf], cos_abs)
                pl = pl * self._sel(sel_area, self.lights.emissive, surf)
                em = em * _w_bsdf(self.strategy, pdf_dir[surf], pl)[:, None]
            emits = front | ~self.tr.tri_one_sided[tri_s]  # doubleSided: both faces
            L[surf] += np.where(emits[:, None], em, 0.0)
        if depth + 1 > self.bounces:
            return L
        albedo = self.tr.albedo_at(tri_s, u, v).astype(np.float64)
        keep = np.any(albedo > 0, axis=1)
        if depth + 1 > RR_DEPTH:
            q = np.clip(albedo.max(axis=1), 0.05, 1.0)
            keep &= rng.random(len(q)) < q
            albedo = albedo / q[:, None]
        if not np.any(keep):
            return L
        surf, tri_s, u, v, gn, ds, albedo = (a[keep] for a in (surf, tri_s, u, v, gn, ds, albedo))
        p = self.tr.hit_points(tri_s, u, v)
        # the triangle's ray offset, and as many ulps of the hit distance (the native kernel's
        # hit points are o + t d, whose error grows with t; the same rule here)
        sc = np.maximum(self.tr.tri_offset[tri_s], OFFSET_ULPS * FLT_EPS * t[surf])
        ns = self.tr.shading_normals(tri_s, u, v)
        side = np.where(np.einsum("ij,ij->i", ds, gn) < 0, 1.0, -1.0)[:, None]
        gn = gn * side  # face the incoming ray (two-sided shading)
        ns = ns * side
        ns = np.where((np.einsum("ij,ij->i", ns, gn) > 0)[:, None], ns, gn)
        L[surf] += albedo * self.reflect(p, gn, ns, sc, depth + 1, rng, self.tr.tri_mesh[tri_s])
        return L

    def reflect(self, p, gn, ns, sc, depth, rng, mesh):
        """(1/pi) * integral of incoming radiance * cos at surface points: NEE + one BSDF ray.
        sc : (m,) ray-origin offset of each point (:meth:`Tracer.offset`); mesh : (m,) int
        scene mesh index of each point (light linking)."""
        m = len(p)
        out = np.zeros((m, 3))
        nee = self.lights.nee
        n_nee = len(nee)
        sel = None
        if n_nee:
            sel = selection_pmf(self.nee_bounds, p, LIGHT_SELECTION_FLOOR)  # (m, n_nee)
            cdf = np.cumsum(sel, axis=1)
            pick = np.minimum((rng.random(m)[:, None] >= cdf).sum(axis=1), n_nee - 1)
            uu = rng.random((m, 2))
            for j, lt in enumerate(nee):
                idx = np.nonzero(pick == j)[0]
                if len(idx) == 0:
                    continue
                ls = lt.sample(p[idx], uu[idx])
                d, dist, val, pdf = ls.dirs, ls.dist, ls.value, ls.pdf
                cos = np.einsum("ij,ij->i", d, ns[idx])
                ok = (cos > 0) & (np.einsum("ij,ij->i", d, gn[idx]) > 0) & (pdf > 0)
                ok &= np.any(val > 0, axis=1) & self._lit(lt, mesh[idx])
                idx, d, dist, val, pdf, cos = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], cos[ok]
                if len(idx) == 0:
                    continue
                o = self.tr.offset(p[idx], gn[idx], d, sc[idx])
                tr = self._visibility(lt, o, *_shadow(o, p[idx], d, dist), rng=rng)
                vis = tr > 0
                val = val * tr[:, None]
                ps = sel[idx, j]
                if lt.delta:
                    f = val * (cos / np.pi / ps)[:, None]
                else:
                    pl = pdf * ps
                    pb = cos / np.pi
                    f = val * (_w_light(self.strategy, pl, pb) * cos / np.pi / pl)[:, None]
                out[idx[vis]] += f[vis]
        # continuation / MIS partner: cosine sampling about the shading normal
        if self.lights.visible or self.tr.has_emission or depth < self.bounces:
            loc, pdf = cosine_hemisphere(rng.random((m, 2)))
            d = to_world(loc, orthonormal_basis(ns))
            ok = np.einsum("ij,ij->i", d, gn) > 0
            idx = np.nonzero(ok)[0]
            if len(idx):
                o = self.tr.offset(p[idx], gn[idx], d[idx], sc[idx])
                hits = self.tr.intersect(o, d[idx], rng=rng)
                s_idx = (sel[idx], nee) if n_nee else 1.0
                out[idx] += self.incoming(o, d[idx], hits, pdf[idx], s_idx, depth, rng, mesh[idx])
        return out

    @staticmethod
    def _sel(sel, lt, rows):
        """Selection probability of light ``lt`` for the rays ``rows`` (index or mask) of an
        :meth:`incoming` call: ``sel`` itself when scalar, else ``sel = (matrix (m, k),
        lights (k))`` and the column of ``lt``."""
        if np.isscalar(sel):
            return sel
        mat, lights = sel
        col = next(j for j, x in enumerate(lights) if x is lt)
        return mat[rows, col]

    # ------------------------------------------------------------------ light linking
    def _lit(self, lt, mesh):
        """(m,) bool: light ``lt`` lights receivers of scene mesh index ``mesh`` (m,) int."""
        mask = self.recv.get(id(lt))
        if mask is None:
            return np.ones(len(mesh), bool)
        return np.where(mesh >= 0, mask[np.maximum(mesh, 0)], True)

    def _visibility(self, lt, o, d, tfar, rng=None):
        """(m,) float64 fraction of a shadow ray's light that arrives: the tracer's
        transmittance (fractional opacity attenuates), or 0 / 1 for a shadow-linked light
        (:meth:`_occluded`, whose pass-through of non-casters stays stochastic)."""
        if self.cast.get(id(lt)) is None:
            return self.tr.transmittance(o, d, tfar)
        return np.where(self._occluded(lt, o, d, tfar, rng=rng), 0.0, 1.0)

    def _occluded(self, lt, o, d, tfar, rng=None):
        """Shadow rays of light ``lt``: only meshes its shadowLink collection includes cast
        shadows (others are passed through, up to LINK_MAX_CROSSINGS surfaces)."""
        casters = self.cast.get(id(lt))
        if casters is None:
            return self.tr.occluded(o, d, tfar, rng=rng)
        occ = np.zeros(len(o), bool)
        todo = np.arange(len(o))
        o, tfar = o.copy(), tfar.astype(np.float64).copy()
        for _ in range(LINK_MAX_CROSSINGS):
            if len(todo) == 0:
                break
            h = self.tr.intersect(o[todo], d[todo], tfar[todo], rng=rng)
            hit = h["tri"] >= 0
            mesh = self.tr.tri_mesh[np.where(hit, h["tri"], 0)]
            blocks = hit & casters[mesh]
            occ[todo[blocks]] = True
            go = hit & ~blocks  # a non-caster: continue past it
            nxt = todo[go]
            step = h["t"][go].astype(np.float64) + self.tr.tri_offset[h["tri"][go]]
            o[nxt] = o[nxt] + step[:, None] * d[nxt]
            tfar[nxt] = tfar[nxt] - step
            keep = tfar[nxt] > 0
            todo = nxt[keep]
        return occ


def _mesh_mask(indices, n):
    """(n,) bool mask of scene meshes from sorted indices, or None for "every mesh"."""
    if indices is None:
        return None
    mask = np.zeros(n, bool)
    mask[np.asarray(indices, np.int64)] = True
    return mask


def has_light_linking(lights) -> bool:
    """Whether any light restricts the meshes it lights or whose shadows it casts."""
    return any(
        getattr(lt, "lit_meshes", None) is not None
        or getattr(lt, "shadow_meshes", None) is not None
        for lt in lights
    )


def _power(pa, pb):
    """MIS power heuristic (beta 2) weight of strategy a."""
    a2 = pa * pa
    den = a2 + pb * pb
    return np.divide(a2, den, out=np.zeros_like(den), where=den > 0)


def _w_light(strategy, pl, pb):
    """Weight of a light (NEE) sample of a light the BSDF can also hit (see STRATEGIES)."""
    if strategy == "mis":
        return _power(pl, pb)
    return np.full(np.shape(pl), 1.0 if strategy == "nee" else 0.0)


def _w_bsdf(strategy, pb, pl):
    """Weight of a BSDF (hemisphere/cosine) sample that hit a light NEE also samples."""
    if strategy == "mis":
        return _power(pb, pl)
    return np.full(np.shape(pb), 1.0 if strategy == "bsdf" else 0.0)


def _shadow(o, p, d, dist):
    """Shadow ray from the offset origin ``o`` to the light point ``p + dist d`` (m,3 each):
    returns (direction (m,3), tfar (m,)) aimed at that point and stopping a relative
    SHADOW_SHORTEN before it, so an emitter in the BVH never shadows its own sample. Infinite
    ``dist`` (distant/dome lights) keeps ``d``."""
    fin = np.isfinite(dist)
    w = p + np.where(fin, dist, 0.0)[:, None] * d - o
    ln = np.sqrt(np.einsum("ij,ij->i", w, w))
    ok = fin & (ln > 0)
    dirs = np.where(ok[:, None], w / np.where(ok, ln, 1.0)[:, None], d)
    return dirs, np.where(fin, ln * (1.0 - SHADOW_SHORTEN), np.inf)
