"""The Retrace rule's replay test: the bake's own random stream re-run at a subset of texels.

The independent retrace (:mod:`usdahd.validate.retrace`) compares the bake with a fresh
estimate, so its mean test can never be sharper than the bake's own Monte Carlo noise in the
prim's mean (0.2-1 % at the default 256 samples): a 1 % rescale of textures and sidecar hides
in it on small or rarely lit prims. The baker is deterministic (``usdahd.bake.integrate``:
each chunk of texels draws from ``default_rng([seed, stream, first])`` and each texel of a
native chunk has its own splitmix64 state drawn from it), and the bake records its seed,
sample count and bounce cap in ``baked:settings``. So the validator can re-run the bake's
*own* estimate at any texel: the same random numbers, the same paths, the raw (pre-denoise)
SH bit for bit (common random numbers). The difference between the sidecar's I_z and this
replay is then what happened *after* the integrator: the denoiser (which keeps each chart's
sum, docs/texels.md), seam stitching, and any rescale or edit of the files. The bake's noise
cancels exactly.

Statistic (per RGB channel, over the n replayed texels, drawn without replacement from the N
texels the bake estimated): ``R = sum b_i / sum p_i`` (b the sidecar's I_z, p the replay's);
its standard error from the scatter of ``b_i - R p_i`` (the denoiser's per-texel changes)
with the finite-population factor ``1 - n / N`` (every texel replayed: no sampling error);
a finding when ``|R - 1| > margin + q SE``, margin the measured bound on the denoiser's
residual change of the prim's mean (:data:`usdahd.validate.retrace.DENOISE_BIAS_BOUND`), q the
Student-t quantile at ``alpha / 2`` split over channels.

Replayed only where the replay is exact: a bake of this usdahd version (``baked:generator``),
non-adaptive (adaptive passes stop texels on their chunk's brightest texel, not per texel),
on the native backend. Otherwise the rule says why and relies on the independent test.

numpy only at import; the baker is imported when a prim is replayed.
"""

from __future__ import annotations

import math

import numpy as np

#: The replay aims at catching a rescale of TARGET_SCALE with probability TARGET_POWER
#: (:func:`needed_texels`), replaying up to REPLAY_CAP times the first count of texels. 99 %:
#: headroom over the stated 95 %, since the scatter that sizes the sample is an estimate too
#: (at 95 % a 64 x 64 floor_lamp wall missed 0.99 on one of two seeds, docs/validate.md).
TARGET_SCALE = 0.01
TARGET_POWER = 0.99
REPLAY_CAP = 8
#: The replay test's share of the rule's false-alarm rate alpha (the independent mean test
#: has another quarter, the per-texel warning half).
REPLAY_ALPHA = 0.25

__all__ = ["REPLAY_ALPHA", "REPLAY_CAP", "TARGET_POWER", "TARGET_SCALE", "bake_seed"]
__all__ += ["compare_replay", "data", "message", "needed_texels", "replay_count", "replay_iz"]
__all__ += ["replay_problem", "run"]


def replay_problem(results, settings: dict, tracer) -> str | None:
    """Why the bake of ``results`` cannot be replayed exactly (None: it can)."""
    from usdahd.version import __version__

    gen = str(getattr(results, "generator", "") or "")
    if gen.split(";")[0].strip() != f"usdahd {__version__}":
        who = gen.split(";")[0].strip() or "an unknown generator"
        return f"baked by {who!r}, not usdahd {__version__}"
    if settings.get("adaptive"):
        return "an adaptive bake (texels stop on their chunk's brightest texel)"
    if settings.get("seed") is None or settings.get("samples") is None:
        return "baked:settings lacks the seed or sample count"
    if tracer is None or getattr(tracer, "backend", "") != "native":
        return "the native tracer backend is not available"
    return None


def bake_seed(seed: int, prim_path: str) -> int:
    """The bake's 32-bit seed of a prim (``usdahd.pipeline.stages._job_seed``)."""
    import hashlib

    return int.from_bytes(hashlib.sha256(f"{seed}:{prim_path}".encode()).digest()[:4], "little")


def replay_count(candidates: int, texels: int, samples: int, bake_samples: int) -> int:
    """Texels replayed: the budget ``texels x samples`` paths spent at the bake's sample count
    (all candidates when they fit)."""
    budget = (int(texels) * int(samples)) // max(int(bake_samples), 1)
    return max(1, min(int(candidates), budget))


def replay_iz(scene, tracer, texels, index, *, seed, samples, bounces, mesh) -> tuple:
    """The bake's raw I_z at ``texels[index]`` (texels in the bake's order, the whole prim).

    Re-runs :func:`usdahd.bake.integrate.bake_texels`' native path for the chosen texels with
    the per-texel states the bake drew for them (chunk generators keyed by the texel's chunk).
    Returns (iz (m, 3) float64, backface (m,) float32, rays int).
    """
    from usdahd.bake import integrate
    from usdahd.bake.kernels.layout import TexelArrays
    from usdahd.bake.reference import Accum
    from usdahd.numerics import sh as shm

    index = np.asarray(index, np.int64)
    n_all = len(texels)
    chunk = integrate.chunk_texels(int(samples), False, True)
    state = np.empty(len(index), np.uint64)
    for start in range(0, n_all, chunk):
        sel = (index >= start) & (index < start + chunk)
        if not sel.any():
            continue
        size = min(n_all, start + chunk) - start
        rng = np.random.default_rng([int(seed), 0, start])
        drawn = rng.integers(0, np.iinfo(np.uint64).max, size, dtype=np.uint64, endpoint=True)
        state[sel] = drawn[index[sel] - start]
    sub = texels.take(index)
    ctx = integrate.NativeCtx(scene, tracer, int(bounces), "regression", "mis", mesh)
    offsets = tracer.texel_offsets(sub, mesh)
    ctx.tex = TexelArrays(
        P=sub.position.astype(np.float64),
        NG=sub.geom_normal.astype(np.float64),
        F=np.ascontiguousarray(sub.frame.astype(np.float64)),
        E=offsets,
    )
    ctx.state = state
    ctx.n = len(index)
    rays0 = tracer.rays_traced
    acc = Accum(len(index))
    ctx.native_pass(int(samples), 0, acc, np.arange(len(index)), True)
    acc.n_half[:] += (int(samples) + 1) // 2
    sh, backface = ctx.result(acc)
    return shm.iz(sh.astype(np.float64)), backface, int(tracer.rays_traced - rays0)


def compare_replay(baked, replayed, population: int, *, margin: float, alpha: float) -> dict:
    """Mean test of the sidecar's I_z ``baked`` (n, 3) against the replay ``replayed`` (n, 3)
    at n texels drawn without replacement from ``population`` (see the module doc).

    returns dict: ``ratio``, ``se``, ``bound`` (3,) float, ``tested``, ``fail`` (3,) bool,
    ``q`` float, ``n`` int, ``fpc`` float (the finite-population factor of the variance).
    """
    from usdahd.numerics.stats import t_isf
    from usdahd.validate.retrace import DARK_CHANNEL

    b = np.asarray(baked, np.float64)
    p = np.asarray(replayed, np.float64)
    n = len(b)
    sum_b, sum_p = b.sum(axis=0), p.sum(axis=0)
    top = np.abs(sum_p).max() if n else 0.0
    tested = (sum_p > DARK_CHANNEL * top) & (top > 0)
    n_tested = max(int(tested.sum()), 1)
    fpc = max(0.0, 1.0 - n / max(int(population), n)) if n else 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(tested, sum_b / np.where(tested, sum_p, 1.0), np.nan)
        res = b - np.where(tested, ratio, 0.0) * p
        var = n / max(n - 1, 1) * (res * res).sum(axis=0) * fpc
        se = np.sqrt(var) / np.abs(sum_p)
    q = t_isf(0.5 * alpha / n_tested, max(n - 1, 1))
    bound = margin + q * se
    fail = tested & (np.abs(ratio - 1.0) > bound)
    return {
        "ratio": ratio,
        "se": se,
        "bound": bound,
        "tested": tested,
        "fail": fail,
        "q": float(q),
        "n": int(n),
        "fpc": float(fpc),
    }


def needed_texels(st: dict, population: int, margin: float) -> int:
    """Texels to replay so that a :data:`TARGET_SCALE` rescale is caught with probability
    :data:`TARGET_POWER`: the standard error must fall to (TARGET_SCALE - margin) / (q + z),
    z the normal quantile of the power; from the measured scatter of the n texels replayed,
    with the finite-population factor (Stein's two-stage rule: the count depends on the
    scatter, never on the ratio, so the test's level is kept)."""
    from statistics import NormalDist

    n = st["n"]
    if n >= population or not st["tested"].any():
        return n
    z = NormalDist().inv_cdf(TARGET_POWER)
    target = (TARGET_SCALE - margin) / (st["q"] + z)
    if target <= 0:
        return population
    se = float(np.max(np.where(st["tested"], st["se"], 0.0)))
    rel_var = se * se * n / max(st["fpc"], 1e-12)  # per-texel relative variance of b - R p
    if rel_var <= 0:
        return n
    return int(math.ceil(1.0 / (target * target / rel_var + 1.0 / population)))


def run(path: str, got: tuple, opt) -> dict | str:
    """The replay test of one prim: ``got`` is ``retrace.prim_candidates``' tuple, ``opt`` the
    :class:`usdahd.validate.retrace.RetraceOptions`. Replays :func:`replay_count` texels,
    then more (in a seeded random order, up to :data:`REPLAY_CAP` times as many) while
    :func:`needed_texels` asks for them. Returns the :func:`compare_replay` dict with
    ``texels``, ``population``, ``inside``, ``rays``, ``seconds``, ``needed``, or a str: why
    the bake was not replayed."""
    import time

    from usdahd.bake import integrate
    from usdahd.validate.retrace import backface_threshold, baked_iz, retrace_seed

    bake, scene, tracer, mesh, texels, rows, _, estimated = got
    settings = bake.results.settings or {}
    why = replay_problem(bake.results, settings, tracer)
    if why is not None:
        return why
    samples = int(settings["samples"])
    first = replay_count(len(estimated), opt.texels, opt.samples, samples)
    cap = min(len(estimated), REPLAY_CAP * first)
    # its own texel order (not the independent test's texels), extended while needed
    rng = np.random.default_rng([retrace_seed(opt.seed, path), 2])
    order = rng.permutation(np.asarray(estimated))
    mi = next((i for i, m in enumerate(scene.meshes) if m is mesh), None)
    bounces = int(settings.get("bounces") or integrate.DEFAULT_BOUNCES)
    seed = bake_seed(int(settings["seed"]), path)
    t0 = time.perf_counter()
    parts, rays, done, target = [], 0, 0, first
    while True:
        pick = order[done:target]
        if opt.progress:
            opt.progress(f"replay {path}: {len(pick)} texels x {samples} samples")
        iz, backface, r = replay_iz(
            scene, tracer, texels, pick, seed=seed, samples=samples, bounces=bounces, mesh=mi
        )
        sub = texels.take(pick)
        inside = integrate.inside_geometry(
            tracer, sub, tracer.texel_offsets(sub, mi), backface, backface_threshold(), mi
        )
        parts.append((baked_iz(bake, rows[pick]), iz, inside))
        rays, done = rays + r, target
        baked = np.concatenate([x[0] for x in parts])
        iz = np.concatenate([x[1] for x in parts])
        inside = np.concatenate([x[2] for x in parts])
        use = ~inside & np.isfinite(baked).all(axis=1) & np.isfinite(iz).all(axis=1)
        if int(use.sum()) < 4:
            return f"only {int(use.sum())} replayed texels lie outside geometry"
        # the population: estimated texels outside geometry (scaled by the replayed share)
        population = int(round(len(estimated) * use.sum() / done))
        st = compare_replay(
            baked[use],
            iz[use],
            population,
            margin=float(opt.margin),
            alpha=REPLAY_ALPHA * opt.alpha,
        )
        need = needed_texels(st, population, float(opt.margin))
        want = int(math.ceil(need * done / max(int(use.sum()), 1)))  # in replayed texels
        if want <= done or done >= cap:
            break
        target = min(cap, max(want, done + 64))
    st.update(
        texels=int(use.sum()),
        population=population,
        inside=int(inside.sum()),
        rays=int(rays),
        seconds=time.perf_counter() - t0,
        samples=samples,
        needed=int(need),
        first=int(first),
    )
    return st


def data(st: dict | str) -> dict:
    """The replay's fields of the Retrace findings' ``--json`` data."""
    if isinstance(st, str):
        return {"replayed": False, "replay_skipped": st}
    t = st["tested"]
    return {
        "replayed": True,
        "replay_ratio": [float(x) if ok else None for x, ok in zip(st["ratio"], t)],
        "replay_standard_error": [float(x) if ok else None for x, ok in zip(st["se"], t)],
        "replay_bound": [float(x) if ok else None for x, ok in zip(st["bound"], t)],
        "replay_texels": st["texels"],
        "replay_population": st["population"],
        "replay_rays": st["rays"],
        "replay_seconds": st["seconds"],
        "replay_texels_needed": st["needed"],
    }


def message(st: dict, channels, margin: float, alpha: float) -> str:
    """The finding text of a failed replay test."""
    i = int(np.argmax(np.where(st["fail"], np.abs(st["ratio"] - 1.0) - st["bound"], -np.inf)))
    r = st["ratio"]
    ratios = ", ".join(
        f"{c} {r[j]:.4f} +- {st['se'][j]:.2g}" for j, c in enumerate(channels) if st["tested"][j]
    )
    way = "brighter" if r[i] > 1.0 else "darker"
    return (
        f"the bake's own random stream replayed at {st['texels']} of {st['population']} texels "
        f"({st['samples']} samples each, its seed and bounces: the raw estimate bit for bit) "
        f"gives baked/replayed {ratios}; channel {channels[i]} is {abs(r[i] - 1.0):.3g} from 1, "
        f"beyond the bound {st['bound'][i]:.3g} (margin {margin:g} for the denoiser + "
        f"{st['q']:.2f} standard errors of the texel choice; false-alarm rate <= {alpha:g}): the "
        f"sidecar and textures are {way} than what the integrator computed, so they were "
        "scaled or edited after the bake, or the lights, materials or geometry changed since"
    )
