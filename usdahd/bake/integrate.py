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
  MIS against cosine sampling) plus one cosine-sampled continuation ray; Russian roulette on the
  albedo from reflection ``RR_DEPTH`` on ends paths without bias, ``bounces`` (default
  ``DEFAULT_BOUNCES`` = 64) is only a safety cap.

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

Two implementations of the same estimator, chosen by the tracer's backend:

- ``native`` (default): :func:`_native_pass`, a numba kernel (``nogil``, no NRT) that, per
  texel, samples, traces through libembree4 directly (:mod:`usdahd.bake.embree_native`) in
  16-ray packets (a small wavefront over the texel's samples, :func:`_paths`), shades and
  accumulates the SH sums; texels are spread over the tracer's threads. Each texel has its
  own splitmix64 stream seeded from the chunk generator, so output is independent of the
  thread count. The SH regression solve also runs per texel on the threads
  (:func:`_native_result`).
- ``embreex``: the numpy wavefront reference (``_Ctx``), batched embreex queries.

They agree within Monte Carlo tolerance (tests/test_trace.py), not bit for bit (different
random streams; the native continuation rays draw cosine directions by disk rejection).
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from usdahd.bake import embree_native
from usdahd.bake.kernels.layout import (
    CFG_BOUNCES,
    CFG_EMISSION,
    CFG_EMISSIVE_LIGHT,
    CFG_EPS,
    CFG_LEN,
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
    TEX_ALBEDO,
    TEX_EMISSION,
    LightArrays,
    LightLists,
)
from usdahd.bake.kernels.lights import (
    light_intersect,
    light_pdf,
    light_sample,
    nb_basis_apply,
    pack_lights,
)
from usdahd.bake.trace import (
    nb_albedo,
    nb_emission,
    nb_hit_point,
    nb_occluded,
    nb_occluded_rays,
    nb_offset,
    nb_random,
    nb_shading_normal,
    nb_trace_rays,
)
from usdahd.numerics import sh as shmod
from usdahd.numerics.sampling import (
    cosine_hemisphere,
    orthonormal_basis,
    r2_sequence,
    texel_hemisphere,
    texel_hemisphere_pdf,
    to_local,
    to_world,
)
from usdahd.scene.lights import EmissiveTriangles

#: Rays per wavefront chunk (texels x samples): bounds memory (~100 B per ray per array).
CHUNK_RAYS = 1 << 16
#: Samples per chunk of the native kernel (memory is per texel there, ~1.4 kB).
NATIVE_CHUNK_RAYS = 1 << 18
#: Reflections before Russian roulette starts (bounces <= RR_DEPTH are never terminated).
RR_DEPTH = 3
#: Default cap on reflections along a path. Paths end by Russian roulette (unbiased), so this is
#: a safety cap, not a truncation: the energy it drops is at most albedo^64 of the first bounce's
#: (2e-3 % for a white furnace of albedo 0.8; a 3-bounce cap drops 41 % there).
DEFAULT_BOUNCES = 64
#: Adaptive: number of passes the sample budget is split into, relative tolerance, floor.
ADAPTIVE_PASSES = 4
ADAPTIVE_TOL = 0.02
ADAPTIVE_FLOOR = 1e-3
#: Shadow rays stop short of the light sample by this fraction (avoids hitting the emitter's
#: own supporting geometry, e.g. a RectLight on an emissive quad).
SHADOW_SHORTEN = 1e-4
INV_2PI = 1.0 / (2.0 * np.pi)
#: Surfaces a shadow ray of a shadow-linked light passes through (meshes its shadowLink
#: collection excludes) at most; a ray still going after that counts as unoccluded.
LINK_MAX_CROSSINGS = 32
#: Up to this many sampled lights, every light gets every texel light sample (selection noise
#: removed at m shadow rays per sample); beyond, each sample picks one light uniformly.
ALL_LIGHTS_MAX = 8
#: Offset of light j's copy of the texel's light-sample points (golden ratio conjugate, both
#: coordinates), so the lights do not share one point pattern.
LIGHT_SHIFT = 0.6180339887498949
#: How lights that both NEE and BSDF rays reach are estimated: "mis" (the power heuristic, the
#: default), "bsdf" (hemisphere/cosine rays only), "nee" (light samples only). The three are
#: unbiased estimators of the same integral; the consistency tests compare them.
STRATEGIES = ("mis", "bsdf", "nee")

_G_HEMI = shmod.hemispherical_gram()


class _Lights:
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


def bake_texels(
    scene,
    tracer,
    texels,
    *,
    samples: int = 256,
    bounces: int = DEFAULT_BOUNCES,
    seed: int = 0,
    adaptive: bool = False,
    progress=None,
    estimator: str = "regression",
    backface_threshold: float = 0.25,
    adaptive_tol: float = ADAPTIVE_TOL,
    stream: int = 0,
    strategy: str = "mis",
    mesh: int | None = None,
):
    """Bake incident radiance SH for ``texels`` of one mesh.

    scene : usdahd.scene.types.Scene (lights used); tracer : usdahd.bake.trace.Tracer over it;
    texels : usdahd.bake.types.Texels.
    samples : hemisphere samples per texel (and as many light samples when the scene has area
        lights); bounces : cap on surface reflections along a path (0 = direct light only;
        paths end earlier by Russian roulette, so the default is converged global illumination);
    strategy : one of STRATEGIES ("mis"; the others exist for the consistency tests);
    mesh : index of the texels' mesh in ``scene.meshes`` (the receiver for UsdLux light
        linking; None: lit by every light);
    stream : an integer identifying this task (e.g. the mesh index) for independent random
        streams; progress : optional callable(done_rays, total_estimate).
    returns : (sh (n, 3, 9) float32, stats dict with ``rays``, ``time``, ``invalid`` (n,) bool,
        ``backface_fraction`` (n,) float32, ``samples`` (n,) int32, ``rays_saved`` int).
    """
    if strategy not in STRATEGIES:
        from usdahd.errors import UsageError

        raise UsageError(f"unknown light strategy {strategy!r} (use one of {STRATEGIES})")
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
    ctx = _Ctx(scene, tracer, bounces, estimator, strategy, mesh)
    if n == 0:
        return out, _stats(tracer, rays0, t0, invalid, backfrac, used, 0)
    passes = ADAPTIVE_PASSES if adaptive and samples >= 4 * ADAPTIVE_PASSES else 1
    per_pass = int(np.ceil(samples / passes))
    # the native kernel has no light linking yet: linked stages take the numpy path (with the
    # same tracer's batch queries)
    native = getattr(tracer, "backend", "embreex") == "native" and not _linked(scene.lights)
    if native:
        ctx = _NativeCtx(scene, tracer, bounces, estimator, strategy)
        chunk = max(64, NATIVE_CHUNK_RAYS // max(per_pass, 1))
    else:
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
        if native:
            ctx.start_chunk(P, NG, F, rng)
        else:
            ctx.direct_delta(P, NG, F, acc)
        for k in range(passes):
            if len(active) == 0:
                break
            s_k = min(per_pass, samples - k * per_pass)
            if s_k <= 0:
                break
            if native:
                ctx.native_pass(s_k, k * per_pass, acc, active, k == 0)
            else:
                ctx.hemisphere_pass(
                    P[active], NG[active], F[active], s_k, k * per_pass, rng, acc, active
                )
            if passes > 1 and k < passes - 1:
                done = acc.converged(active, adaptive_tol)
                left = samples - (k + 1) * per_pass
                saved += int(done.sum()) * left * ctx.rays_per_sample
                active = active[~done]
        res, bf = ctx.result(acc) if native else acc.result(estimator)
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
                b[ok] = np.matmul(_G_HEMI, x).transpose(0, 2, 1)
        res = b + self.nee / c[:, None, None] + self.delta
        return res.astype(np.float32), (self.back / c).astype(np.float32)


class _Ctx:
    def __init__(self, scene, tracer, bounces, estimator, strategy="mis", mesh=None):
        self.strategy = strategy
        self.scene = scene
        self.tr = tracer
        self.bounces = bounces
        self.lights = _Lights(scene.lights, tracer)
        # light linking (UsdLux collection:lightLink / shadowLink): per light, a bool mask over
        # scene meshes of the receivers it lights and of the meshes that cast its shadows
        # (None: every mesh); the texels' own mesh index receives as ``mesh``
        nm = len(scene.meshes)
        self.recv = {id(lt): _mesh_mask(getattr(lt, "lit_meshes", None), nm) for lt in scene.lights}
        self.cast = {
            id(lt): _mesh_mask(getattr(lt, "shadow_meshes", None), nm) for lt in scene.lights
        }
        self.texel_mesh = -1 if mesh is None else int(mesh)
        self.texel_sel = _texel_selection(len(self.lights.area))
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
            ok &= self._lit(lt, np.full(len(P), self.texel_mesh))
            if not np.any(ok):
                continue
            idx = np.nonzero(ok)[0]
            o = self.tr.offset(P[idx], NG[idx], d[idx])
            occ = self._occluded(lt, o, *_shadow(o, P[idx], d[idx], dist[idx]))
            idx = idx[~occ]
            acc.delta[idx] += np.einsum("nc,nk->nck", val[idx], shmod.basis(loc[idx]))

    def hemisphere_pass(self, P, NG, F, s, offset, rng, acc, active):
        n = len(P)
        u = np.mod(r2_sequence(s, offset)[None] + rng.random((n, 1, 2)), 1.0)  # (n,s,2)
        loc, pdf_h = texel_hemisphere(u)  # (n,s,3), (n,s)
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
            src = np.full(len(idx), self.texel_mesh)
            radiance[idx] = self.incoming(
                o, d[idx], hits, pdf_h.reshape(-1)[idx], self.texel_sel, 0, rng, src
            )
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
            nee_c, nee_y = self.texel_nee(P, NG, F, s, offset, rng)
            acc.nee[active] += nee_c
            ylum = ylum + nee_y
        acc.y_sum[active] += ylum.sum(axis=1)
        acc.y_sq[active] += (ylum * ylum).sum(axis=1)

    def texel_nee(self, P, NG, F, s, offset, rng):
        """Light samples at the texel (MIS with the texel hemisphere); returns sums
        (c (n,3,9), per-sample luminance Iz (n,s)). With at most ALL_LIGHTS_MAX sampled lights
        every light gets every sample (no light-selection noise; ``texel_sel`` = 1), else each
        sample picks one light uniformly (``texel_sel`` = 1/m)."""
        n = len(P)
        m = len(self.lights.area)
        u = np.mod(r2_sequence(s, offset + 7919)[None] + rng.random((n, 1, 2)), 1.0)
        u = u.reshape(-1, 2)
        every = m <= ALL_LIGHTS_MAX
        if not every:
            pick = (rng.random(n * s) * m).astype(np.int64)
        Pf = np.repeat(P, s, axis=0)
        NGf = np.repeat(NG, s, axis=0)
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
            d, dist, val, pdf = lt.sample(Pf[idx], uj)
            loc = to_local(d, Ff[idx])
            ok = (pdf > 0) & (loc[:, 2] > 0) & (np.einsum("ij,ij->i", d, NGf[idx]) > 0)
            ok &= np.any(val > 0, axis=1) & self._lit(lt, np.full(len(idx), self.texel_mesh))
            idx, d, dist, val, pdf, loc = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], loc[ok]
            if len(idx) == 0:
                continue
            o = self.tr.offset(Pf[idx], NGf[idx], d)
            vis = ~self._occluded(lt, o, *_shadow(o, Pf[idx], d, dist), rng=rng)
            idx, val, pdf, loc = idx[vis], val[vis], pdf[vis], loc[vis]
            pl = pdf * self.texel_sel
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
        probability of an area light in the NEE the direction is paired with; depth :
        reflections already made along the path; src : (m,) int mesh index of the surface
        the rays leave (the receiver, for light linking; -1: unknown, lit by every light).
        """
        m = len(o)
        L = np.zeros((m, 3))
        t = hits["t"].astype(np.float64)
        tri = hits["tri"]
        miss = tri < 0
        for lt in self.lights.visible:
            hit, tl, rad = lt.intersect(o, d)
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
                pl = lt.pdf(o[vis], d[vis], tl[vis]) * sel_area
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
                pl = self.lights.emissive.pdf_hit(tri_s, t[surf], cos_abs) * sel_area
                em = em * _w_bsdf(self.strategy, pdf_dir[surf], pl)[:, None]
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
        L[surf] += albedo * self.reflect(p, gn, ns, depth + 1, rng, self.tr.tri_mesh[tri_s])
        return L

    def reflect(self, p, gn, ns, depth, rng, mesh):
        """(1/pi) * integral of incoming radiance * cos at surface points: NEE + one BSDF ray.
        mesh : (m,) int scene mesh index of each point (light linking)."""
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
                ok &= np.any(val > 0, axis=1) & self._lit(lt, mesh[idx])
                idx, d, dist, val, pdf, cos = idx[ok], d[ok], dist[ok], val[ok], pdf[ok], cos[ok]
                if len(idx) == 0:
                    continue
                o = self.tr.offset(p[idx], gn[idx], d)
                vis = ~self._occluded(lt, o, *_shadow(o, p[idx], d, dist), rng=rng)
                if lt.delta:
                    f = val * (cos / np.pi * n_nee)[:, None]
                else:
                    pl = pdf / n_nee
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
                o = self.tr.offset(p[idx], gn[idx], d[idx])
                hits = self.tr.intersect(o, d[idx], rng=rng)
                sel = 1.0 / max(1, n_nee)
                out[idx] += self.incoming(o, d[idx], hits, pdf[idx], sel, depth, rng, mesh[idx])
        return out

    # ------------------------------------------------------------------ light linking
    def _lit(self, lt, mesh):
        """(m,) bool: light ``lt`` lights receivers of scene mesh index ``mesh`` (m,) int."""
        mask = self.recv.get(id(lt))
        if mask is None:
            return np.ones(len(mesh), bool)
        return np.where(mesh >= 0, mask[np.maximum(mesh, 0)], True)

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
            step = h["t"][go].astype(np.float64) + self.tr.offset_eps
            o[nxt] = o[nxt] + step[:, None] * d[nxt]
            tfar[nxt] = tfar[nxt] - step
            keep = tfar[nxt] > 0
            todo = nxt[keep]
        return occ


@njit(cache=True, nogil=True, error_model="numpy")
def _native_result(ids, gram, hemi, nee, delta, count, back, regression, out, bf):
    """``_Accum.result`` for texels ``ids`` (into ``out`` (n,3,9) f32 and ``bf`` (n,) f32):
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
                    v += _G_HEMI[k, m] * a[m, 9 + ch]
                out[i, ch, k] = np.float32(v + nee[i, ch, k] * inv + delta[i, ch, k])


class _NativeCtx:
    """Drives :func:`_native_pass` over the tracer's threads (backend "native")."""

    def __init__(self, scene, tracer, bounces, estimator, strategy="mis"):
        self.tr = tracer
        lights = _Lights(scene.lights, tracer)
        order = {id(lt): i for i, lt in enumerate(lights.all)}
        tab = pack_lights(lights.all)
        self.lt = LightArrays(tab.kind, tab.par, tab.img, tab.pmf, tab.cdf, tab.delta,
                              tab.infinite, tab.sampled)  # fmt: skip

        def ids(group):
            return np.array([order[id(lt)] for lt in group], np.int64)

        self.lists = LightLists(
            ids(lights.nee), ids(lights.visible), ids(lights.delta), ids(lights.area)
        )
        em = order[id(lights.emissive)] if lights.emissive is not None else -1
        self.cfg = np.zeros(CFG_LEN, np.float64)
        self.cfg[CFG_BOUNCES] = bounces
        self.cfg[CFG_EPS] = tracer.offset_eps
        self.cfg[CFG_TRANSMISSION] = tracer.has_transmission
        self.cfg[CFG_EMISSION] = tracer.has_emission
        self.cfg[CFG_REGRESSION] = estimator == "regression"
        self.cfg[CFG_EMISSIVE_LIGHT] = em
        self.cfg[CFG_STRATEGY] = STRATEGIES.index(strategy)
        self.tb = tracer.native_tables()
        self.rays_per_sample = 1 + (1 if lights.area else 0) + 3 * bounces

    def start_chunk(self, P, NG, F, rng):
        self.P, self.NG, self.F = P, NG, np.ascontiguousarray(F)
        self.state = rng.integers(0, np.iinfo(np.uint64).max, len(P), dtype=np.uint64,
                                  endpoint=True)  # fmt: skip

    def native_pass(self, s, offset, acc, active, do_delta):
        r2h = r2_sequence(s, offset)
        r2h = np.c_[r2h, np.cos(_TWO_PI * r2h[:, 1]), np.sin(_TWO_PI * r2h[:, 1])]
        r2n = r2_sequence(s, offset + 7919)
        arrays = (acc.gram, acc.hemi, acc.nee, acc.delta, acc.count, acc.back, acc.y_sum,
                  acc.y_sq)  # fmt: skip
        handle = self.tr.native_handle

        def run(ids):
            work = _native_work(s)
            return _native_pass(
                handle, self.tb, self.lt, self.lists, self.cfg, ids, self.P, self.NG, self.F,
                s, r2h, r2n, self.state, do_delta, arrays, work,
            )  # fmt: skip

        rays = self.tr.run_parallel(run, np.asarray(active, np.int64))
        self.tr.rays_traced += int(sum(rays))

    def result(self, acc):
        n = len(acc.count)
        out = np.empty((n, 3, 9), np.float32)
        bf = np.empty(n, np.float32)
        reg = bool(self.cfg[CFG_REGRESSION])

        def run(ids):
            _native_result(ids, acc.gram, acc.hemi, acc.nee, acc.delta, acc.count, acc.back,
                           reg, out, bf)  # fmt: skip

        self.tr.run_parallel(run, np.arange(n, dtype=np.int64))
        return out, bf


def _mesh_mask(indices, n):
    """(n,) bool mask of scene meshes from sorted indices, or None for "every mesh"."""
    if indices is None:
        return None
    mask = np.zeros(n, bool)
    mask[np.asarray(indices, np.int64)] = True
    return mask


def _linked(lights) -> bool:
    """Whether any light restricts the meshes it lights or whose shadows it casts."""
    return any(
        getattr(lt, "lit_meshes", None) is not None
        or getattr(lt, "shadow_meshes", None) is not None
        for lt in lights
    )


def _texel_selection(m):
    """Selection probability of one sampled light in the texel's light samples."""
    return 1.0 if m <= ALL_LIGHTS_MAX else 1.0 / m


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


# ----------------------------------------------------------------------------- native kernel
# The same estimator as ``_Ctx`` above, in numba, tracing through libembree4 directly (backend
# "native"). Each call handles the texels ``ids`` of one chunk for one pass and adds into the
# ``_Accum`` arrays at those rows only, so threads given disjoint ``ids`` never touch the same
# memory. Per texel it is a small wavefront: the pass's hemisphere rays (all from one origin),
# the texel's light-sample shadow rays, and then each bounce's shadow and continuation rays are
# traced as 16-ray packets (:func:`usdahd.bake.embree_native.intersect_rays`). Random numbers:
# one splitmix64 stream per texel (state in ``rng_state``), so results do not depend on threads
# or on how texels are split among them. Helpers are plain ``@njit`` functions: LLVM inlines
# the small ones when the kernel is linked (numba-level ``inline="always"`` cost ~3x the
# compile time for no run-time gain).

_C0, _C1, _C2, _C20, _C22 = shmod.C0, shmod.C1, shmod.C2, shmod.C20, shmod.C22
_LUM = (float(shmod.LUMINANCE[0]), float(shmod.LUMINANCE[1]), float(shmod.LUMINANCE[2]))
_IZ = float(shmod.IZ_FROM_L10)
_TWO_PI = 2.0 * np.pi
_4PI = 4.0 * np.pi
_INV_4PI = 1.0 / (4.0 * np.pi)
#: Register-fed Gram sums of the native pass (see :func:`_gram_unpack`).
GRAM_SUMS = 45


@njit(cache=True, _nrt=False, error_model="numpy")
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


@njit(cache=True, _nrt=False, error_model="numpy")
def _nee_sample(kind, p, img, pmf, cdf, tb, x, y, z, u0, u1):
    """``light_sample`` for every kind, including the emissive triangles (``EmissiveTriangles``
    .sample: triangle by power, uniform point, emission looked up in the material tables).
    returns (dx, dy, dz, dist, r, g, b, pdf)."""
    if kind != KIND_EMISSIVE:
        return light_sample(kind, p, img, pmf, cdf, x, y, z, u0, u1)
    base, ne = int(p[PAR_EM_TABLE]), int(p[PAR_EM_COUNT])
    lo_i, hi_i = 0, ne
    while lo_i < hi_i:  # searchsorted(cdf, u0, side="right")
        mid = (lo_i + hi_i) // 2
        if cdf[base + mid] <= u0:
            lo_i = mid + 1
        else:
            hi_i = mid
    k = min(lo_i, ne - 1)
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


@njit(cache=True, _nrt=False, error_model="numpy")
def _wl(mode, pl, pb):
    """``_w_light`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return _pw(pl, pb)
    return 1.0 if mode == MODE_NEE else 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _wb(mode, pb, pl):
    """``_w_bsdf`` (mode: index in STRATEGIES)."""
    if mode == MODE_MIS:
        return _pw(pb, pl)
    return 1.0 if mode == MODE_BSDF else 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _pw(a, b):
    den = a * a + b * b
    return a * a / den if den > 0.0 else 0.0


@njit(cache=True, _nrt=False, error_model="numpy")
def _shadow1(ox, oy, oz, px, py, pz, dx, dy, dz, dist):
    """:func:`_shadow` for one ray: returns (dx, dy, dz, tfar)."""
    if not np.isfinite(dist):
        return dx, dy, dz, np.inf
    wx, wy, wz = px + dist * dx - ox, py + dist * dy - oy, pz + dist * dz - oz
    ln = np.sqrt(wx * wx + wy * wy + wz * wz)
    if not ln > 0.0:
        return dx, dy, dz, 0.0
    return wx / ln, wy / ln, wz / ln, ln * (1.0 - SHADOW_SHORTEN)


@njit(cache=True, _nrt=False, error_model="numpy")
def _set_row(a, j, x0, x1, x2, x3, x4, x5, x6):
    a[j, 0] = x0
    a[j, 1] = x1
    a[j, 2] = x2
    a[j, 3] = x3
    a[j, 4] = x4
    a[j, 5] = x5
    a[j, 6] = x6


@njit(cache=True, _nrt=False, error_model="numpy")
def _paths(scene, pk, rec, tb, lt, lists, cfg, st, n, ps, rays, hits, srays, sval, sidx, occ, R):
    """``_Ctx.incoming`` as a wavefront over the ``n`` paths in rows [0, n) of ``ps`` whose
    first hits are ``hits`` (the layout of ``embree_native.intersect_rays``): each path's
    radiance is added to ``R[k]`` (k its sample index). Per bounce, every live path makes one
    NEE shadow ray (``srays``, value ``sval``, sample ``sidx``) and one cosine continuation ray
    (``rays``; live rows are compacted to the front); both sets are traced as packets.
    Hit points are o + t d (no vertex fetch; error ~1e-7 t, far below the ray offset).
    returns : rays traced."""
    kind, par, img, pmf, cdf, ldelta, linf, lsampled = lt
    nee_idx, visible_idx = lists.nee, lists.visible
    tri_mat, mat_const, mat_tex = tb.tri_material, tb.mat_const, tb.mat_tex
    bounces, eps = int(cfg[CFG_BOUNCES]), cfg[CFG_EPS]
    transmission, has_em = cfg[CFG_TRANSMISSION] != 0.0, cfg[CFG_EMISSION] != 0.0
    em_q = int(cfg[CFG_EMISSIVE_LIGHT])  # the emissive-triangles light (-1: none)
    mode = int(cfg[CFG_STRATEGY])
    em_pdf = int(par[em_q, PAR_EM_PDF_AREA]) if em_q >= 0 else 0
    n_nee = nee_idx.shape[0]
    n_vis = visible_idx.shape[0]
    sel_next = 1.0 / max(1, n_nee)
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
                        pl = light_pdf(kind[q], par[q], pmf, ox, oy, oz, dx, dy, dz, tl) * sel
                        w = _wb(mode, pdf_dir, pl)
                    Lr += br * w * r
                    Lg += bg * w * g
                    Lb += bb * w * b
            for _once in range(1):  # a block to break out of
                if miss:
                    break
                cos_in = dx * gx + dy * gy + dz * gz
                mq = tri_mat[tri]  # constant materials inline, textured ones called
                if has_em and cos_in < 0.0:
                    if mat_tex[mq, TEX_EMISSION] < 0:
                        er = mat_const[mq, MAT_EMISSION]
                        eg = mat_const[mq, MAT_EMISSION + 1]
                        eb = mat_const[mq, MAT_EMISSION + 2]
                    else:
                        er, eg, eb = nb_emission(tb, tri, u, v)
                    w = 1.0
                    if em_q >= 0:  # MIS against the emitter's light samples
                        pe = sel * pmf[em_pdf + tri] * t * t / max(-cos_in, 1e-300)
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
                nx, ny, nz = nb_shading_normal(tb, tri, u, v)
                side = 1.0 if cos_in < 0.0 else -1.0
                gx, gy, gz = gx * side, gy * side, gz * side
                nx, ny, nz = nx * side, ny * side, nz * side
                if not (nx * gx + ny * gy + nz * gz > 0.0):
                    nx, ny, nz = gx, gy, gz
                br, bg, bb = br * ar, bg * ag, bb * ab
                depth += 1
                # next-event estimation: one light chosen uniformly, its shadow ray queued
                if n_nee:
                    q = nee_idx[min(int(nb_random(st) * n_nee), n_nee - 1)]
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
                            f = cos / np.pi * n_nee
                        else:
                            pl = pdf / n_nee
                            f = _wl(mode, pl, cos / np.pi) * cos / np.pi / pl
                        qx, qy, qz = nb_offset(eps, px, py, pz, gx, gy, gz, lx, ly, lz)
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
                ox, oy, oz = nb_offset(eps, px, py, pz, gx, gy, gz, dx, dy, dz)
                _set_row(rays, nn, ox, oy, oz, dx, dy, dz, np.inf)
                _set_row(ps, nn, ox, oy, oz, dx, dy, dz, br)
                ps[nn, PATH_BETA + 1] = bg
                ps[nn, PATH_BETA + 2] = bb
                ps[nn, PATH_PDF] = cz / np.pi
                ps[nn, PATH_SEL] = sel_next
                ps[nn, PATH_DEPTH] = depth
                ps[nn, PATH_SAMPLE] = k
                nn += 1
            R[k, 0] += Lr
            R[k, 1] += Lg
            R[k, 2] += Lb
        if ns:
            traced += nb_occluded_rays(scene, pk, rec, tb, eps, transmission, st, srays, ns, occ)
            for q in range(ns):
                if not occ[q]:
                    k = sidx[q]
                    R[k, 0] += sval[q, 0]
                    R[k, 1] += sval[q, 1]
                    R[k, 2] += sval[q, 2]
        if nn:
            traced += nb_trace_rays(scene, pk, rec, tb, eps, transmission, st, rays, nn, hits)
        n = nn
    return traced


@njit(cache=True, _nrt=False, error_model="numpy")
def _texel_delta(scene, rec, tb, lt, delta_idx, cfg, st, i, P, NG, F, Y, delta):
    """Exact delta-light terms of texel ``i`` (one shadow ray per light). returns rays."""
    kind, par, img, pmf, cdf = lt.kind, lt.par, lt.img, lt.pmf, lt.cdf
    eps, transmission = cfg[CFG_EPS], cfg[CFG_TRANSMISSION] != 0.0
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
        occ, k = nb_occluded(scene, rec, tb, eps, transmission, st, qx, qy, qz, sx, sy, sz, tf)
        rays += k
        if occ:
            continue
        lx = f[0, 0] * dx + f[0, 1] * dy + f[0, 2] * dz
        ly = f[1, 0] * dx + f[1, 1] * dy + f[1, 2] * dz
        _sh9(Y, lx, ly, lz)
        for c9 in range(9):
            delta[i, 0, c9] += r * Y[c9]
            delta[i, 1, c9] += g * Y[c9]
            delta[i, 2, c9] += b * Y[c9]
    return rays


@njit(cache=True, _nrt=False, error_model="numpy")
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
def _native_pass(
    scene, tb, lt, lists, cfg, ids, P, NG, F, s, r2h, r2n, rng_state, do_delta, acc, work
):
    """One pass of ``s`` hemisphere (+ light) samples for texels ``ids`` of a chunk.

    P, NG : (n,3) f64; F : (n,3,3) f64; r2h : (s,4) R2 points for the hemisphere with
    cos/sin of 2 pi times their second coordinate; r2n : (s,2) R2 points for the light
    samples; acc : (gram, hemi, nee, delta, count, back, y_sum, y_sq) of ``_Accum``;
    work : per-thread scratch from :func:`_native_work` (RTCRayHit record, packet, (1,) uint64
    random state, (9,) basis, (GRAM_SUMS,) zeroed Gram sums, (27,) zeroed hemisphere sums, the
    per-sample wavefront arrays). Compiled without the NRT (``_nrt=False``): no allocation
    and no reference counting in the hot loop.
    returns : rays traced.
    """
    kind, par, img, pmf, cdf, ldelta, linf, lsampled = lt
    delta_idx, area_idx = lists.delta, lists.area
    gram, hemi, nee, delta, count, back, y_sum, y_sq = acc
    eps, transmission = cfg[CFG_EPS], cfg[CFG_TRANSMISSION] != 0.0
    regression = cfg[CFG_REGRESSION] != 0.0
    mode = int(cfg[CFG_STRATEGY])
    n_area = area_idx.shape[0]
    every = n_area <= ALL_LIGHTS_MAX  # every light gets every texel light sample
    sel_area = 1.0 if every else 1.0 / n_area
    rec, pk, st, Y, G, H, ps, rays, hits, srays, sval, sidx, occ, R, loc, yl = work
    traced = 0
    for ii in range(ids.shape[0]):
        i = ids[ii]
        st[0] = rng_state[i]
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        ngx, ngy, ngz = NG[i, 0], NG[i, 1], NG[i, 2]
        f = F[i]
        if do_delta:
            traced += _texel_delta(scene, rec, tb, lt, delta_idx, cfg, st, i, P, NG, F, Y, delta)
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
                ps[m, PATH_DEPTH] = 0.0
                ps[m, PATH_SAMPLE] = k
                m += 1
        n_back = 0
        if m:
            traced += nb_trace_rays(scene, pk, rec, tb, eps, transmission, st, rays, m, hits)
            for j in range(m):
                if hits[j, HIT_TRI] >= 0.0:
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
                if every:
                    j = area_idx[rd]
                else:
                    j = area_idx[min(int(nb_random(st) * n_area), n_area - 1)]
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
                    pl = pdf * sel_area
                    wgt = _wl(mode, pl, (1.0 + 2.0 * lz) * _INV_4PI) / pl
                    sval[ns, 0], sval[ns, 1], sval[ns, 2] = r * wgt, g * wgt, b * wgt
                    sval[ns, 3] = f[0, 0] * dx + f[0, 1] * dy + f[0, 2] * dz
                    sval[ns, 4] = f[1, 0] * dx + f[1, 1] * dy + f[1, 2] * dz
                    sval[ns, 5] = lz
                    sidx[ns] = k
                    ns += 1
            if ns:
                traced += nb_occluded_rays(
                    scene, pk, rec, tb, eps, transmission, st, srays, ns, occ
                )
                for q in range(ns):
                    if occ[q]:
                        continue
                    _sh9(Y, sval[q, 3], sval[q, 4], sval[q, 5])
                    r, g, b = sval[q, 0], sval[q, 1], sval[q, 2]
                    for c9 in range(9):
                        nee[i, 0, c9] += r * Y[c9]
                        nee[i, 1, c9] += g * Y[c9]
                        nee[i, 2, c9] += b * Y[c9]
                    yl[sidx[q]] += _IZ * (_LUM[0] * r + _LUM[1] * g + _LUM[2] * b) * Y[2]
        # SH sums of the hemisphere samples (weights 1/p, p = sampling.texel_hemisphere_pdf)
        ys = 0.0
        ys2 = 0.0
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
        for c in range(3):
            for c9 in range(9):
                hemi[i, c, c9] += H[9 * c + c9]
                H[9 * c + c9] = 0.0
        y_sum[i] += ys
        y_sq[i] += ys2
        back[i] += n_back
        count[i] += s
        rng_state[i] = st[0]
        if regression:
            _gram_unpack(gram, i, G)
    return traced


def _native_work(s):
    """Per-thread scratch of :func:`_native_pass` for passes of ``s`` samples."""
    return (
        embree_native.new_scratch(),
        embree_native.new_packet(),
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
        np.zeros(s, np.bool_),
        np.zeros((s, 3)),
        np.zeros((s, 3)),
        np.zeros(s),
    )
