"""Per-texel incident radiance SH by path tracing (NEE + MIS), in each texel's tangent frame.

Output: ``sh`` (n, 3, 9) float32 — the quadratic SH projection of the incident radiance over the
texel's upper hemisphere (zero below the horizon), in the frame ``texels.frame`` (rows tangent,
bitangent, normal; z = normal), with the basis/sign conventions of :mod:`usdahd.sh`.
``usdahd.sh.iz(sh)`` is the normalized irradiance (uniform sky of radiance 1 -> 1).

Light transport (Lambertian surfaces, material albedo, emission on front faces; both faces
on doubleSided meshes):

- Texel hemisphere: ``samples`` directions per texel from the R2 low-discrepancy set with a
  per-texel Cranley-Patterson rotation, warped to the uniform/cosine mixture of
  ``numerics.sampling.texel_hemisphere`` (pdf (1 + 2z)/4pi).
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
``backface_threshold`` and that is walled in along its surface, or whose point is covered by a
surface much closer than the texel is wide (:func:`inside_geometry`), is flagged in
``stats["invalid"]`` (its SH is still returned; post processing replaces it by its valid
neighbours).

Determinism: each chunk of texels draws from ``np.random.default_rng([seed, stream, first])``
so results depend on the seed and texel order only, not on threads or executors.

Two implementations of the same estimator, chosen by the tracer's backend:

- ``native`` (default): :func:`usdahd.bake.kernels.integrate.native_pass`, a numba kernel
  (``nogil``, no NRT) that, per texel, samples, traces through libembree4 directly
  (:mod:`usdahd.bake.kernels.embree`) in 16-ray packets (a small wavefront over the texel's
  samples, ``kernels.integrate._paths``), shades and accumulates the SH sums; texels are spread
  over the tracer's threads. Each texel has its own splitmix64 stream seeded from the chunk
  generator, so output is independent of the thread count. The SH regression solve also runs
  per texel on the threads (``kernels.integrate.native_result``).
- ``embreex``: the numpy wavefront reference (:class:`usdahd.bake.reference.ReferenceCtx`),
  batched embreex queries.

They agree within Monte Carlo tolerance (tests/bake/test_trace.py), not bit for bit (different
random streams; the native continuation rays draw cosine directions by disk rejection).
"""

from __future__ import annotations

import time

import numpy as np

from usdahd.bake.contacts import covered, inside_pilot, texel_sizes, walled_in
from usdahd.bake.kernels.integrate import native_pass, native_result, native_work
from usdahd.bake.kernels.layout import (
    CFG_LEN,
    CFG_REGRESSION,
    CONFIG,
    LightLists,
    PassPoints,
    TexelArrays,
)
from usdahd.bake.kernels.lights import pack_lights
from usdahd.bake.reference import Accum, LightGroups, ReferenceCtx, has_light_linking
from usdahd.numerics.sampling import r2_sequence

__all__ = [
    "ADAPTIVE_TOL",
    "DEFAULT_BOUNCES",
    "NativeCtx",
    "bake_texels",
    "chunk_texels",
    "inside_geometry",
    "iz_batches",
    "uses_native",
]

#: Rays per wavefront chunk (texels x samples): bounds memory (~100 B per ray per array).
CHUNK_RAYS = 1 << 16
#: Samples per chunk of the native kernel (memory is per texel there, ~1.4 kB).
NATIVE_CHUNK_RAYS = 1 << 18
#: Default cap on reflections along a path. Paths end by Russian roulette (unbiased), so this is
#: a safety cap, not a truncation: the energy it drops is at most albedo^64 of the first bounce's
#: (2e-3 % for a white furnace of albedo 0.8; a 3-bounce cap drops 41 % there).
DEFAULT_BOUNCES = 64
#: Samples of a texel the inside pilot finds inside geometry (``contacts.inside_pilot``):
#: enough for an estimate where no neighbour can replace it (a chart wholly inside, warned
#: about); its back-face fraction is the pilot's, so it is judged inside as the pilot found.
INSIDE_SAMPLES = 16
#: Adaptive: number of passes the sample budget is split into, relative tolerance (the floor
#: is ``reference.ADAPTIVE_FLOOR``).
ADAPTIVE_PASSES = 4
ADAPTIVE_TOL = 0.02
#: How lights that both NEE and BSDF rays reach are estimated: "mis" (the power heuristic, the
#: default), "bsdf" (hemisphere/cosine rays only), "nee" (light samples only). The three are
#: unbiased estimators of the same integral; the consistency tests compare them.
STRATEGIES = ("mis", "bsdf", "nee")
_TWO_PI = 2.0 * np.pi


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
    first: int = 0,
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
    first : index of ``texels[0]`` among its mesh's texels when ``texels`` is a tile of them
        (:mod:`usdahd.bake.tiles`): chunk generators are keyed by the mesh-wide index, so
        tiles that start on a :func:`chunk_texels` boundary reproduce the whole-mesh bake
        bit for bit.
    returns : (sh (n, 3, 9) float32, stats dict with ``rays``, ``time``, ``invalid`` (n,) bool,
        ``backface_fraction`` (n,) float32, ``samples`` (n,) int32, ``rays_saved`` int,
        ``iz_variance`` (n,) float64: each texel's per-sample luminance I_z variance over
        its sample count, s^2 / S: an upper bound of the estimate's variance (the shifted R2
        points stratify the first two dimensions, measured 0.68x on a dome-lit ground; the
        regression estimator is lower still); ``iz_variance_halves`` (n,) float64: the
        two-halves estimate of the same variance (``Accum.iz_variance_halves``), another
        upper bound, far tighter where stratification pays most (a penumbra: 3.5x the real
        variance where s^2 / S is 8x); ``--denoise`` trusts the smaller of the two).
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
    iz_var = np.zeros(n)
    iz_halves = np.zeros(n)
    ctx = ReferenceCtx(scene, tracer, bounces, estimator, strategy, mesh)
    if n == 0:
        return out, _stats(tracer, rays0, t0, invalid, backfrac, used, 0, iz_var, iz_halves)
    passes, per_pass = _passes(samples, adaptive)
    native = uses_native(scene, getattr(tracer, "backend", "embreex"))
    if native:
        ctx = NativeCtx(scene, tracer, bounces, estimator, strategy, mesh)
    chunk = chunk_texels(samples, adaptive, native)
    offsets = tracer.texel_offsets(texels, mesh)  # ray-origin offset per texel
    # texels plainly inside geometry (under a box on a floor): INSIDE_SAMPLES samples, not
    # ``samples`` (each texel's samples are its own, so the others are traced as before)
    pilot = np.zeros(n)
    if samples > INSIDE_SAMPLES:
        pilot = inside_pilot(texels.position, texels.geom_normal, offsets, tracer)
    est_rays_per_sample = None
    saved = 0
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        rng = np.random.default_rng([seed, stream, first + start])
        acc = Accum(sl.stop - sl.start)
        stopped = np.nonzero(pilot[sl] > 0)[0]
        active = np.nonzero(pilot[sl] <= 0)[0]
        P = texels.position[sl].astype(np.float64)
        NG = texels.geom_normal[sl].astype(np.float64)
        F = texels.frame[sl].astype(np.float64)
        E = offsets[sl]
        if native:
            ctx.start_chunk(P, NG, F, E, rng)
        else:
            ctx.direct_delta(P, NG, F, E, acc)
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
                    P[active],
                    NG[active],
                    F[active],
                    E[active],
                    s_k,
                    k * per_pass,
                    rng,
                    acc,
                    active,
                )
            acc.n_half[active] += (s_k + 1) // 2
            if passes > 1 and k < passes - 1:
                done = acc.converged(active, adaptive_tol)
                left = samples - (k + 1) * per_pass
                saved += int(done.sum()) * left * ctx.rays_per_sample
                active = active[~done]
        if len(stopped):  # after the others: the numpy path's generator draws for them first
            if native:
                ctx.native_pass(INSIDE_SAMPLES, 0, acc, stopped, True)
            else:
                ctx.hemisphere_pass(P[stopped], NG[stopped], F[stopped], E[stopped],
                                    INSIDE_SAMPLES, 0, rng, acc, stopped)  # fmt: skip
            acc.n_half[stopped] += (INSIDE_SAMPLES + 1) // 2
        res, bf = ctx.result(acc) if native else acc.result(estimator)
        out[sl] = res
        bf[stopped] = np.maximum(bf[stopped], pilot[sl][stopped])
        backfrac[sl] = bf
        used[sl] = acc.count
        iz_var[sl] = acc.iz_variance()
        iz_halves[sl] = acc.iz_variance_halves()
        if progress is not None:
            done_rays = tracer.rays_traced - rays0
            if est_rays_per_sample is None:
                est_rays_per_sample = done_rays / max(1, int(acc.count.sum()))
            progress(done_rays, int(est_rays_per_sample * n * samples) or done_rays)
    invalid = inside_geometry(tracer, texels, offsets, backfrac, backface_threshold)
    cov = np.zeros(n, bool)
    if mesh is not None:  # the covered rule, apart: a chart wholly covered is not a warning
        cov = covered_texels(tracer, texels, offsets, mesh, ~invalid)
    stats = _stats(tracer, rays0, t0, invalid | cov, backfrac, used, saved, iz_var, iz_halves)
    stats["covered"] = cov
    return out, stats


def inside_geometry(
    tracer, texels, offsets, backfrac, threshold: float = 0.25, mesh=None
) -> np.ndarray:
    """(n,) bool: texels inside geometry, whose estimate the pipeline replaces by its neighbours'.

    texels : usdahd.bake.types.Texels; offsets : (n,) float64 ray-origin offsets; backfrac :
    (n,) the fraction of each texel's hemisphere rays that hit a back face of a one-sided mesh;
    mesh : the scene mesh the texels belong to (its index in ``tracer.scene.meshes`` or its
    MeshData), for the texels' world size; None skips the covered test below.
    A texel is inside geometry when ``backfrac > threshold`` (the texel's view is mostly the
    back of something) and :func:`usdahd.bake.contacts.walled_in` (rays along its surface meet
    back faces on all sides), so a thin gap behind a one-sided card is estimated, not filled
    (docs/integrator.md); or when it is :func:`usdahd.bake.contacts.covered`: its point lies under
    a surface (front or back face) much closer than the texel is wide, e.g. the board under a
    chess piece's closed base, which front faces hide (docs/texels.md, "Covered texels").
    """
    inside = np.asarray(backfrac) > threshold
    if inside.any():
        idx = np.nonzero(inside)[0]
        inside[idx] = walled_in(texels.position[idx], texels.geom_normal[idx], offsets[idx], tracer)
    if mesh is not None:
        inside |= covered_texels(tracer, texels, offsets, mesh, ~inside)
    return inside


def covered_texels(tracer, texels, offsets, mesh, among=None) -> np.ndarray:
    """(n,) bool: :func:`usdahd.bake.contacts.covered` over ``texels`` of the scene mesh ``mesh``
    (index or MeshData), tested only where ``among`` ((n,) bool, default all) is set; none
    when the mesh has no lightmap UVs (texels given by their points, e.g. in tests)."""
    out = np.zeros(len(texels), bool)
    if len(texels) == 0:
        return out
    if isinstance(mesh, (int, np.integer)):
        mesh = tracer.scene.meshes[int(mesh)]
    if mesh.uv is None:  # texels not laid out on this mesh's lightmap UVs: no texel size
        return out
    rest = np.arange(len(texels)) if among is None else np.nonzero(among)[0]
    size = texel_sizes(texels, mesh)[rest]
    pos, ng = texels.position[rest], texels.geom_normal[rest]
    out[rest] = covered(pos, ng, np.asarray(offsets)[rest], size, tracer)
    return out


def iz_batches(
    scene,
    tracer,
    texels,
    *,
    batches: int,
    samples: int,
    bounces: int,
    seed: int,
    stream: int,
    mesh: int | None = None,
):
    """Independent plain Monte Carlo estimates of Iz at ``texels`` (the re-estimates of
    ``validate --retrace`` and ``preview --compare``): ``batches`` runs of :func:`bake_texels`
    with ``samples`` each, ``estimator="mc"``, random streams ``stream .. stream + batches - 1``.

    Returns (iz, backface, rays): iz (batches, n, 3) float64, one estimate per batch (the mean
    over axis 0 is the estimate, its variance / batches the variance of that mean);
    backface (n,) float64, the mean back-face fraction of the batches; rays (int) traced.
    """
    from usdahd.numerics import sh as shm

    iz = np.empty((batches, len(texels), 3))
    backface = np.zeros(len(texels))
    rays = 0
    for j in range(batches):
        sh, st = bake_texels(
            scene,
            tracer,
            texels,
            samples=samples,
            bounces=bounces,
            seed=seed,
            stream=stream + j,
            estimator="mc",
            mesh=mesh,
        )
        iz[j] = shm.iz(sh.astype(np.float64))
        backface += np.asarray(st["backface_fraction"], np.float64) / batches
        rays += int(st["rays"])
    return iz, backface, rays


def _passes(samples: int, adaptive: bool) -> tuple[int, int]:
    """(passes, samples per pass) of the sample budget."""
    passes = ADAPTIVE_PASSES if adaptive and samples >= 4 * ADAPTIVE_PASSES else 1
    return passes, int(np.ceil(samples / passes))


def uses_native(scene, backend: str) -> bool:
    """Whether :func:`bake_texels` runs the native kernel for ``scene`` on a tracer of
    ``backend`` (every stage on the "native" backend, light-linked ones included)."""
    return backend == "native"


def chunk_texels(samples: int, adaptive: bool, native: bool) -> int:
    """Texels per chunk (one random generator each) of :func:`bake_texels`; a tile of texels
    starting on a multiple of it draws exactly the numbers the whole-mesh bake draws there."""
    per_pass = _passes(samples, adaptive)[1]
    if native:
        return max(64, NATIVE_CHUNK_RAYS // max(per_pass, 1))
    return max(1, CHUNK_RAYS // max(per_pass, 1))


def _stats(tracer, rays0, t0, invalid, backfrac, used, saved, iz_var, iz_halves):
    return {
        "iz_variance": iz_var,
        "iz_variance_halves": iz_halves,
        "rays": int(tracer.rays_traced - rays0),
        "time": time.perf_counter() - t0,
        "invalid": invalid,
        "backface_fraction": backfrac,
        "samples": used,
        "rays_saved": int(saved),
    }


class NativeCtx:
    """Drives :func:`native_pass` over the tracer's threads (backend "native")."""

    def __init__(self, scene, tracer, bounces, estimator, strategy="mis", mesh=None):
        self.tr = tracer
        lights = LightGroups(scene.lights, tracer)
        order = {id(lt): i for i, lt in enumerate(lights.all)}
        self.lt = pack_lights(lights.all, len(scene.meshes))

        def ids(group):
            return np.array([order[id(lt)] for lt in group], np.int64)

        self.lists = LightLists(
            ids(lights.nee), ids(lights.visible), ids(lights.delta), ids(lights.area)
        )
        em = order[id(lights.emissive)] if lights.emissive is not None else -1
        self.cfg = np.zeros(CFG_LEN, np.float64)
        cfg = CONFIG.view(self.cfg)
        cfg.bounces = bounces
        cfg.eps = tracer.offset_eps
        cfg.transmission = tracer.has_transmission
        cfg.emission = tracer.has_emission
        cfg.regression = estimator == "regression"
        cfg.emissive_light = em
        cfg.strategy = STRATEGIES.index(strategy)
        cfg.linked = has_light_linking(scene.lights)
        cfg.shadow_linked = any(lt.shadow_meshes is not None for lt in scene.lights)
        cfg.texel_mesh = -1 if mesh is None else int(mesh)
        self.tb = tracer.native_tables()
        self.rays_per_sample = 1 + (1 if lights.area else 0) + 3 * bounces

    def start_chunk(self, P, NG, F, E, rng):
        self.tex = TexelArrays(P=P, NG=NG, F=np.ascontiguousarray(F), E=E)
        self.state = rng.integers(0, np.iinfo(np.uint64).max, len(P), dtype=np.uint64,
                                  endpoint=True)  # fmt: skip
        self.n = len(P)

    def native_pass(self, s, offset, acc, active, do_delta):
        r2h = r2_sequence(s, offset)
        r2h = np.c_[r2h, np.cos(_TWO_PI * r2h[:, 1]), np.sin(_TWO_PI * r2h[:, 1])]
        pts = PassPoints(r2h=r2h, r2n=r2_sequence(s, offset + 7919))
        handle = self.tr.native_handle

        def run(ids):
            work = native_work(s)
            return native_pass(handle, self.tb, self.lt, self.lists, self.cfg, self.tex, ids,
                               pts, self.state, do_delta, acc.arrays, work)  # fmt: skip

        rays = self.tr.run_parallel(run, np.asarray(active, np.int64))
        self.tr.rays_traced += int(sum(rays))

    def result(self, acc):
        n = len(acc.count)
        out = np.empty((n, 3, 9), np.float32)
        bf = np.empty(n, np.float32)
        reg = bool(self.cfg[CFG_REGRESSION])

        def run(ids):
            native_result(ids, acc.arrays, reg, out, bf)

        self.tr.run_parallel(run, np.arange(n, dtype=np.int64))
        return out, bf
