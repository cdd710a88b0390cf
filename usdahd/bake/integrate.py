"""Per-texel incident radiance SH by path tracing (NEE + MIS), in each texel's tangent frame.

Output: ``sh`` (n, 3, 9) float32 — the quadratic SH projection of the incident radiance over the
texel's upper hemisphere (zero below the horizon), in the frame ``texels.frame`` (rows tangent,
bitangent, normal; z = normal), with the basis/sign conventions of :mod:`usdahd.sh`.
``usdahd.sh.iz(sh)`` is the normalized irradiance (uniform sky of radiance 1 -> 1).

Light transport (Lambertian surfaces, material albedo, emission on front faces):

- Texel hemisphere: ``samples`` directions per texel from the R2 low-discrepancy set with a
  per-texel Cranley-Patterson rotation, mapped uniformly onto the hemisphere (pdf 1/2pi).
- Direct light: delta lights (treatAsPoint spheres, zero-angle distant lights) get one exact
  shadow ray per texel; area/cone/textured-dome lights get ``samples`` light samples per texel
  (light chosen uniformly), combined with the hemisphere rays that hit them by the power
  heuristic (beta = 2: for small, bright lights the hemisphere strategy's share, which it
  samples only rarely, vanishes quadratically instead of linearly). Uniform domes and
  emissive meshes are reached by hemisphere rays only (no light sampling for them yet).
- Indirect: at each surface hit, one NEE sample (light chosen uniformly among sampleable lights,
  MIS against cosine sampling) plus one cosine-sampled continuation ray, for up to ``bounces``
  reflections; Russian roulette on the albedo from reflection ``RR_DEPTH`` on.

SH projection estimator (``estimator="regression"``, the default): the hemisphere-sampled part
is a least-squares fit of the 9 basis functions to the samples, ``c = G_H Ghat^-1 b`` with
``b = 1/S sum L_i Y(w_i) / p`` and ``Ghat = 1/S sum Y(w_i) Y(w_i)^T / p``, where ``G_H`` is the
exact hemispherical Gram matrix (``sh.hemispherical_gram``). This is the SH basis used as its
own control variate (the integrals of Y_k Y_l over the hemisphere are known): it is exact for
any radiance that lies in the span of the 9 functions on the hemisphere (a uniform or linearly
varying sky, a furnace) and removes the error component correlated with the sample layout,
at an O(1/S) bias for other signals. Light-sampled (NEE) contributions are importance sampled
already and are added as plain Monte Carlo sums. ``estimator="mc"`` uses plain Monte Carlo for
everything (unbiased; used by the tests that derive tolerances from the sample variance).

Adaptive sampling (``adaptive=True``): samples are taken in ``ADAPTIVE_PASSES`` passes; after each
pass a texel stops when the standard error of its luminance Iz estimate (from the per-sample
variance) is below ``adaptive_tol`` times max(its Iz, ``ADAPTIVE_FLOOR`` times the chunk's
largest Iz). ``stats["rays_saved"]`` counts the rays not traced.

Texels inside geometry: a texel whose hemisphere rays hit back faces more often than
``backface_threshold`` is flagged in ``stats["invalid"]`` (its SH is still returned; post
processing should replace it by dilation).

Determinism: each chunk of texels draws from ``np.random.default_rng([seed, stream, first])``
so results depend on the seed and texel order only, not on threads or executors.
"""

from __future__ import annotations

import time

import numpy as np

from usdahd import sh as shmod
from usdahd.sampling import (
    cosine_hemisphere,
    orthonormal_basis,
    r2_sequence,
    to_local,
    to_world,
    uniform_hemisphere,
)

#: Rays per wavefront chunk (texels x samples): bounds memory (~100 B per ray per array).
CHUNK_RAYS = 1 << 16
#: Reflections before Russian roulette starts (bounces <= RR_DEPTH are never terminated).
RR_DEPTH = 3
#: Adaptive: number of passes the sample budget is split into, relative tolerance, floor.
ADAPTIVE_PASSES = 4
ADAPTIVE_TOL = 0.02
ADAPTIVE_FLOOR = 1e-3
#: Shadow rays stop short of the light sample by this fraction (avoids hitting the emitter's
#: own supporting geometry, e.g. a RectLight on an emissive quad).
SHADOW_SHORTEN = 1e-4
INV_2PI = 1.0 / (2.0 * np.pi)

_G_HEMI = shmod.hemispherical_gram()


class _Lights:
    """Light lists split by how the integrator uses them."""

    def __init__(self, lights):
        self.all = list(lights)
        self.delta = [lt for lt in self.all if lt.delta]
        self.area = [lt for lt in self.all if not lt.delta and lt.sampled]  # MIS partners
        self.hit_only = [lt for lt in self.all if not lt.delta and not lt.sampled]
        self.nee = self.delta + self.area  # sampled at secondary vertices
        self.visible = self.area + self.hit_only  # can be hit by BSDF rays


def bake_texels(
    scene,
    tracer,
    texels,
    *,
    samples: int = 256,
    bounces: int = 2,
    seed: int = 0,
    adaptive: bool = False,
    progress=None,
    estimator: str = "regression",
    backface_threshold: float = 0.25,
    adaptive_tol: float = ADAPTIVE_TOL,
    stream: int = 0,
):
    """Bake incident radiance SH for ``texels`` of one mesh.

    scene : usdahd.usd.scene.Scene (lights used); tracer : usdahd.bake.trace.Tracer over it;
    texels : usdahd.bake.types.Texels.
    samples : hemisphere samples per texel (and as many light samples when the scene has area
        lights); bounces : surface reflections along a path (0 = direct light only);
    stream : an integer identifying this task (e.g. the mesh index) for independent random
        streams; progress : optional callable(done_rays, total_estimate).
    returns : (sh (n, 3, 9) float32, stats dict with ``rays``, ``time``, ``invalid`` (n,) bool,
        ``backface_fraction`` (n,) float32, ``samples`` (n,) int32, ``rays_saved`` int).
    """
    if estimator not in ("regression", "mc"):
        from usdahd.errors import UsageError

        raise UsageError(f"unknown SH estimator {estimator!r} (use 'regression' or 'mc')")
    if samples < 1 or bounces < 0:
        from usdahd.errors import UsageError

        raise UsageError(f"samples must be >= 1 and bounces >= 0 (got {samples}, {bounces})")
    t0 = time.perf_counter()
    rays0 = tracer.rays_traced
    n = len(texels)
    out = np.zeros((n, 3, 9), np.float32)
    invalid = np.zeros(n, bool)
    backfrac = np.zeros(n, np.float32)
    used = np.zeros(n, np.int32)
    ctx = _Ctx(scene, tracer, bounces, estimator)
    if n == 0:
        return out, _stats(tracer, rays0, t0, invalid, backfrac, used, 0)
    passes = ADAPTIVE_PASSES if adaptive and samples >= 4 * ADAPTIVE_PASSES else 1
    per_pass = int(np.ceil(samples / passes))
    chunk = max(1, CHUNK_RAYS // max(per_pass, 1))
    est_rays_per_sample = None
    saved = 0
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        rng = np.random.default_rng([seed, stream, start])
        acc = _Accum(sl.stop - sl.start)
        active = np.arange(sl.stop - sl.start)
        P = texels.position[sl].astype(np.float64)
        NG = texels.geom_normal[sl].astype(np.float64)
        F = texels.frame[sl].astype(np.float64)
        ctx.direct_delta(P, NG, F, acc)
        for k in range(passes):
            if len(active) == 0:
                break
            s_k = min(per_pass, samples - k * per_pass)
            if s_k <= 0:
                break
            ctx.hemisphere_pass(
                P[active], NG[active], F[active], s_k, k * per_pass, rng, acc, active
            )
            if passes > 1 and k < passes - 1:
                done = acc.converged(active, adaptive_tol)
                left = samples - (k + 1) * per_pass
                saved += int(done.sum()) * left * ctx.rays_per_sample
                active = active[~done]
        res, bf = acc.result(estimator)
        out[sl] = res
        backfrac[sl] = bf
        invalid[sl] = bf > backface_threshold
        used[sl] = acc.count
        if progress is not None:
            done_rays = tracer.rays_traced - rays0
            if est_rays_per_sample is None:
                est_rays_per_sample = done_rays / max(1, int(acc.count.sum()))
            progress(done_rays, int(est_rays_per_sample * n * samples) or done_rays)
    return out, _stats(tracer, rays0, t0, invalid, backfrac, used, saved)


def _stats(tracer, rays0, t0, invalid, backfrac, used, saved):
    return {
        "rays": int(tracer.rays_traced - rays0),
        "time": time.perf_counter() - t0,
        "invalid": invalid,
        "backface_fraction": backfrac,
        "samples": used,
        "rays_saved": int(saved),
    }


class _Accum:
    """Per-texel running sums (so passes and estimators combine)."""

    def __init__(self, n):
        self.gram = np.zeros((n, 9, 9))  # sum Y Y^T / p over hemisphere samples
        self.hemi = np.zeros((n, 3, 9))  # sum L Y / p over hemisphere samples
        self.nee = np.zeros((n, 3, 9))  # sum of light-sample contributions
        self.delta = np.zeros((n, 3, 9))  # exact delta-light terms (not divided by S)
        self.count = np.zeros(n, np.int32)
        self.back = np.zeros(n, np.int64)
        self.y_sum = np.zeros(n)  # per-sample luminance Iz estimates (for adaptivity)
        self.y_sq = np.zeros(n)

    def converged(self, active, tol):
        c = self.count[active].astype(np.float64)
        mean = self.y_sum[active] / c
        var = np.maximum(self.y_sq[active] / c - mean * mean, 0.0)
        se = np.sqrt(var / c)
        base = self.delta[active][:, :, 2] @ shmod.LUMINANCE * shmod.IZ_FROM_L10
        level = np.abs(mean + base)
        floor = ADAPTIVE_FLOOR * (level.max() if len(level) else 0.0)
        return se <= tol * np.maximum(level, floor)

    def result(self, estimator):
        c = np.maximum(self.count, 1).astype(np.float64)
        b = self.hemi / c[:, None, None]
        if estimator == "regression":
            g = self.gram / c[:, None, None]
            ok = self.count >= 16
            if np.any(ok):
                x = np.linalg.solve(g[ok] + 1e-9 * np.eye(9), b[ok].transpose(0, 2, 1))
                b[ok] = np.einsum("kl,nlc->nck", _G_HEMI, x)
        res = b + self.nee / c[:, None, None] + self.delta
        return res.astype(np.float32), (self.back / c).astype(np.float32)


class _Ctx:
    def __init__(self, scene, tracer, bounces, estimator):
        self.scene = scene
        self.tr = tracer
        self.bounces = bounces
        self.lights = _Lights(scene.lights)
        self.estimator = estimator
        # rays per hemisphere sample, for the rays_saved estimate
        self.rays_per_sample = 1 + (1 if self.lights.area else 0) + 3 * bounces

    # ------------------------------------------------------------------ texel level
    def direct_delta(self, P, NG, F, acc):
        """Exact contribution of delta lights: one shadow ray per texel and light."""
        for lt in self.lights.delta:
            d, dist, val, _ = lt.sample(P, np.zeros((len(P), 2)))
            loc = to_local(d, F)
            ok = (loc[:, 2] > 0) & (np.einsum("ij,ij->i", d, NG) > 0)
            if not np.any(ok):
                continue
            idx = np.nonzero(ok)[0]
            o = self.tr.offset(P[idx], NG[idx], d[idx])
            occ = self.tr.occluded(o, d[idx], _shorten(dist[idx]))
            idx = idx[~occ]
            acc.delta[idx] += np.einsum("nc,nk->nck", val[idx], shmod.basis(loc[idx]))

    def hemisphere_pass(self, P, NG, F, s, offset, rng, acc, active):
        n = len(P)
        u = np.mod(r2_sequence(s, offset)[None] + rng.random((n, 1, 2)), 1.0)  # (n,s,2)
        loc, _ = uniform_hemisphere(u)
        d = to_world(loc, F[:, None]).reshape(-1, 3)
        loc = loc.reshape(-1, 3)
        Pf = np.repeat(P, s, axis=0)
        NGf = np.repeat(NG, s, axis=0)
        above = np.einsum("ij,ij->i", d, NGf) > 0
        radiance = np.zeros((n * s, 3))
        back = np.zeros(n * s, bool)
        idx = np.nonzero(above)[0]
        if len(idx):
            o = self.tr.offset(Pf[idx], NGf[idx], d[idx])
            hits = self.tr.intersect(o, d[idx], rng=rng)
            tri = hits["tri"]
            hit = tri >= 0
            gn = self.tr.geom_normal[np.where(hit, tri, 0)]
            back[idx] = hit & (np.einsum("ij,ij->i", d[idx], gn) > 0)
            sel_area = 1.0 / max(1, len(self.lights.area))
            radiance[idx] = self.incoming(
                o, d[idx], hits, np.full(len(idx), INV_2PI), sel_area, 0, rng
            )
        Y = shmod.basis(loc).reshape(n, s, 9)
        R = radiance.reshape(n, s, 3)
        Yt = Y.transpose(0, 2, 1)
        acc.hemi[active] += (2.0 * np.pi) * np.matmul(Yt, R).transpose(0, 2, 1)
        if self.estimator == "regression":
            acc.gram[active] += (2.0 * np.pi) * np.matmul(Yt, Y)
        acc.back[active] += back.reshape(n, s).sum(axis=1)
        acc.count[active] += s
        ylum = (2.0 * np.pi * shmod.IZ_FROM_L10) * (R @ shmod.LUMINANCE) * Y[..., 2]
        if self.lights.area:
            nee_c, nee_y = self.texel_nee(P, NG, F, s, offset, rng)
            acc.nee[active] += nee_c
            ylum = ylum + nee_y
        acc.y_sum[active] += ylum.sum(axis=1)
        acc.y_sq[active] += (ylum * ylum).sum(axis=1)

    def texel_nee(self, P, NG, F, s, offset, rng):
        """Light samples at the texel (MIS with the uniform hemisphere); returns sums."""
        n = len(P)
        m = len(self.lights.area)
        u = np.mod(r2_sequence(s, offset + 7919)[None] + rng.random((n, 1, 2)), 1.0)
        u = u.reshape(-1, 2)
        pick = (rng.random(n * s) * m).astype(np.int64) if m > 1 else np.zeros(n * s, np.int64)
        Pf = np.repeat(P, s, axis=0)
        NGf = np.repeat(NG, s, axis=0)
        Ff = np.repeat(F, s, axis=0)
        contrib = np.zeros((n * s, 3))
        Y = np.zeros((n * s, 9))
        for j, lt in enumerate(self.lights.area):
            idx = np.nonzero(pick == j)[0]
            if len(idx) == 0:
                continue
            d, dist, val, pdf = lt.sample(Pf[idx], u[idx])
            loc = to_local(d, Ff[idx])
            ok = (pdf > 0) & (loc[:, 2] > 0) & (np.einsum("ij,ij->i", d, NGf[idx]) > 0)
            ok &= np.any(val > 0, axis=1)
            idx, d, dist, val, pdf, loc = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], loc[ok]
            if len(idx) == 0:
                continue
            o = self.tr.offset(Pf[idx], NGf[idx], d)
            vis = ~self.tr.occluded(o, d, _shorten(dist), rng=rng)
            pl = pdf / m
            w = _power(pl, INV_2PI)
            contrib[idx[vis]] = (val * (w / pl)[:, None])[vis]
            Y[idx] = shmod.basis(loc)
        C = contrib.reshape(n, s, 3)
        Yr = Y.reshape(n, s, 9)
        c = np.matmul(Yr.transpose(0, 2, 1), C).transpose(0, 2, 1)
        y = shmod.IZ_FROM_L10 * (C @ shmod.LUMINANCE) * Yr[..., 2]
        return c, y

    # ------------------------------------------------------------------ path level
    def incoming(self, o, d, hits, pdf_dir, sel_area, depth, rng):
        """Radiance arriving at ``o`` along ``d`` (m,3), MIS-weighted against light sampling.

        pdf_dir : (m,) solid-angle pdf the direction was sampled with; sel_area : selection
        probability of an area light in the NEE the direction is paired with; depth :
        reflections already made along the path.
        """
        m = len(o)
        L = np.zeros((m, 3))
        t = hits["t"].astype(np.float64)
        tri = hits["tri"]
        miss = tri < 0
        for lt in self.lights.visible:
            hit, tl, rad = lt.intersect(o, d)
            vis = hit & (miss if lt.infinite else (tl < t))
            if not np.any(vis):
                continue
            w = np.ones(int(vis.sum()))
            if lt.sampled:
                pl = lt.pdf(o[vis], d[vis], tl[vis]) * sel_area
                w = _power(pdf_dir[vis], pl)
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
            em = self.tr.emission_at(tri_s, u, v)
            L[surf] += np.where(front[:, None], em, 0.0)
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
        ns = self.tr.shading_normals(tri_s, u, v)
        side = np.where(np.einsum("ij,ij->i", ds, gn) < 0, 1.0, -1.0)[:, None]
        gn = gn * side  # face the incoming ray (two-sided shading)
        ns = ns * side
        ns = np.where((np.einsum("ij,ij->i", ns, gn) > 0)[:, None], ns, gn)
        L[surf] += albedo * self.reflect(p, gn, ns, depth + 1, rng)
        return L

    def reflect(self, p, gn, ns, depth, rng):
        """(1/pi) * integral of incoming radiance * cos at surface points: NEE + one BSDF ray."""
        m = len(p)
        out = np.zeros((m, 3))
        nee = self.lights.nee
        n_nee = len(nee)
        if n_nee:
            pick = (rng.random(m) * n_nee).astype(np.int64)
            uu = rng.random((m, 2))
            for j, lt in enumerate(nee):
                idx = np.nonzero(pick == j)[0]
                if len(idx) == 0:
                    continue
                d, dist, val, pdf = lt.sample(p[idx], uu[idx])
                cos = np.einsum("ij,ij->i", d, ns[idx])
                ok = (cos > 0) & (np.einsum("ij,ij->i", d, gn[idx]) > 0) & (pdf > 0)
                ok &= np.any(val > 0, axis=1)
                idx, d, dist, val, pdf, cos = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], cos[ok]
                if len(idx) == 0:
                    continue
                o = self.tr.offset(p[idx], gn[idx], d)
                vis = ~self.tr.occluded(o, d, _shorten(dist), rng=rng)
                if lt.delta:
                    f = val * (cos / np.pi * n_nee)[:, None]
                else:
                    pl = pdf / n_nee
                    pb = cos / np.pi
                    f = val * (_power(pl, pb) * cos / np.pi / pl)[:, None]
                out[idx[vis]] += f[vis]
        # continuation / MIS partner: cosine sampling about the shading normal
        if self.lights.visible or self.tr.has_emission or depth < self.bounces:
            loc, pdf = cosine_hemisphere(rng.random((m, 2)))
            d = to_world(loc, orthonormal_basis(ns))
            ok = np.einsum("ij,ij->i", d, gn) > 0
            idx = np.nonzero(ok)[0]
            if len(idx):
                o = self.tr.offset(p[idx], gn[idx], d[idx])
                hits = self.tr.intersect(o, d[idx], rng=rng)
                sel = 1.0 / max(1, n_nee)
                out[idx] += self.incoming(o, d[idx], hits, pdf[idx], sel, depth, rng)
        return out


def _power(pa, pb):
    """MIS power heuristic (beta 2) weight of strategy a."""
    a2 = pa * pa
    den = a2 + pb * pb
    return np.divide(a2, den, out=np.zeros_like(den), where=den > 0)


def _shorten(dist):
    return np.where(np.isfinite(dist), dist * (1.0 - SHADOW_SHORTEN), np.inf)
