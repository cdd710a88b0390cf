"""Rule ``Retrace`` (opt-in): re-estimate I_z at random texels and compare it with the bake.

``usdahd validate --retrace N`` (and the UsdValidation validator ``usdahd.validate:Retrace``,
keyword ``UsdAhdRetrace``, not run by the ``UsdAhdValidators`` keyword because it costs time;
declared without ``schemaTypes``, since a context built with ``includeAllAncestors`` adds every
validator of the selected validators' schema types, and it checks for the API itself)
picks N random covered texel *centres* per baked prim, re-traces their incident radiance with
the baker's own integrator (:func:`usdahd.bake.integrate.bake_texels`) at a high sample count,
on its own random stream, with plain Monte Carlo (``estimator="mc"``, unbiased) and no
practical bounce cap (:data:`RETRACE_BOUNCES` with Russian roulette), and compares the I_z of
the retrace with the baked I_z. It catches what the other rules cannot see because they only
check the files against each other: a bake made with a bounce cap, textures *and* sidecar
rescaled together, the wrong light units, a stale bake whose hash was copied.

Texels: the prim's lightmap UVs (``baked:uvPrimvar`` on the validated stage) rasterised at
``baked:resolution`` by the baker's rasteriser (:func:`usdahd.bake.texels.rasterize`), so the
sample points and tangent frames are the ones the bake traced. Texels must match the bake's
coverage (the SH sidecar's ``A``); texels the retrace finds inside geometry (the baker's rule,
:func:`usdahd.bake.integrate.inside_geometry`: the baker filled those from neighbours) are
dropped.

Baked I_z: from the float32 SH sidecar when it exists (``usdahd.sh.iz``; the encoding's
quantization is IzCheck's job, not this rule's), else the decoded textures at n = z.

Statistics (per RGB channel c, over the n usable texels; docs/validate.md has the derivation,
the measured margin, the power curve and the cost):

- Replay (:mod:`usdahd.validate.replay`): the bake's own random stream re-run at a random
  subset of the prim's estimated texels gives the raw pre-denoise I_z bit for bit, so the
  bake's noise cancels; ``sum b / sum p`` is tested against the margin plus q standard errors
  of the texel choice (alpha / 4), with as many texels as a 1 % rescale needs for 99 % power (the
  stated 95 % with headroom).
  Skipped (with the reason in the finding) where the replay would not be exact.
- The retrace runs in K independent batches of s samples (``K * s`` = the retrace samples;
  s is at most the bake's sample count when possible), giving per texel a mean ``r_i`` and a
  sample variance ``v_i`` (K - 1 degrees of freedom). A prim with fewer candidate texels than
  N spends the same budget N x S on the texels it has (:func:`texel_samples`).
- Mean test: the ratio ``R = sum b_i / sum r_i`` with standard error
  ``SE = max(SE_emp, SE_model)``: ``SE_emp`` from the scatter of the linearised residuals
  ``b_i - R r_i``, ``SE_model`` from the variances (bake noise bounded by the retrace's
  per-batch variance scaled to the bake's sample count: a denoised bake's scatter hides its
  raw noise, but the prim's mean keeps it, since the denoiser restores each chart's sum). A
  finding when ``|R - 1| > margin + q SE``, margin the measured bound on the denoiser's
  residual bias (:data:`DENOISE_BIAS_BOUND`), q the Student-t quantile with n - 1 degrees of
  freedom at two-sided level ``alpha / 2`` (``alpha / 4`` when the replay ran; alpha 0.01)
  Bonferroni-split over channels.
- Per-texel test (texels whose 5 x 5 neighbourhood is covered by the same chart, so seam
  stitching and gutter dilation did not touch them): a *warning* when
  ``|b_i - r_i| > margin max(r_i, 0.1 mean r) + q_t sqrt(v_i / K + v_b,i)``, q_t the t
  quantile with K - 1 degrees of freedom at ``alpha / 2`` Bonferroni-split over texels and
  channels, v_i no lower than the prim's pooled relative variance, v_b scaled by
  :data:`DENOISE_TEXEL_FACTOR` for denoised bakes. A warning because bake noise is
  heavy-tailed (fireflies) where rare paths carry much light.
- False-alarm rate: at most ``alpha`` per prim for a bake whose mean is within ``margin`` of
  the truth and whose raw per-texel noise does not exceed plain Monte Carlo at its sample
  count (and, for the per-texel warning, is light-tailed).

The statistics (:func:`compare`, :func:`t_sf`, :func:`t_isf`) import only numpy; pxr and the
baker are imported when a prim is checked.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from usdahd.errors import UsageError
from usdahd.numerics.stats import betainc, t_isf, t_sf  # noqa: F401 (re-exported)

__all__ = ["DESCRIPTION", "KEYWORD", "MIN_TEXELS", "OPTIONS", "RULE", "RetraceOptions"]
__all__ += ["register", "validator_name", "DARK_CHANNEL", "DENOISE_BIAS_BOUND", "compare"]
__all__ += ["backface_threshold", "baked_iz", "pick_texels", "prim_candidates", "retrace_seed"]
__all__ += ["betainc", "t_isf", "t_sf"]

#: Rule name, UsdValidation keyword (opt-in) and the one-sentence doc (the plugInfo ``doc``).
RULE = "Retrace"
KEYWORD = "UsdAhdRetrace"
DESCRIPTION = (
    "Opt-in: I_z re-traced at random covered texel centres with the baker's integrator at a "
    "high sample count and no bounce cap agrees with the baked I_z within a statistical bound."
)
#: Bounce cap of the retrace: far above any path Russian roulette lets live (no practical cap).
RETRACE_BOUNCES = 256
#: Channel names of the per-channel statistics.
CHANNELS = ("R", "G", "B")
#: Channels whose retraced sum is below this fraction of the brightest channel's are not
#: ratio-tested (a black channel of a coloured light has no meaningful ratio).
DARK_CHANNEL = 1e-3
#: Per-texel margins are taken against max(r_i, TEXEL_FLOOR * mean r): texels far darker than
#: the prim's average are judged on the prim's scale (their relative noise is huge).
TEXEL_FLOOR = 0.1
#: Fewer usable texels than this: the mean test has too few degrees of freedom; skipped.
MIN_TEXELS = 4
#: A rasterised texel set that differs from the bake's coverage on more than this fraction
#: means the UVs or resolution changed since the bake (Staleness reports it); skipped.
COVERAGE_MISMATCH = 0.01
#: Bound on the default bake's residual bias of the retraced mean (the denoiser's, the
#: regression estimator's, the float32 sidecar's), relative: the margin of the mean test.
#: Measured by ``benchmarks/retrace_power.py --bias`` (docs/validate.md, "Margin").
DENOISE_BIAS_BOUND = 0.002
#: Prims with fewer candidate texels than N spend the same path budget (N x S) on the texels
#: they have, up to this many times S per texel.
BUDGET_FACTOR = 16
#: OIDN's blend weight ``g`` in usdahd.bake.denoise (docs/texels.md): a denoised texel moves
#: from its raw estimate by at most about sqrt(g) of its noise deviation, so its error is at
#: most (1 + sqrt(g)) raw deviations; the per-texel test scales the bake's variance by this
#: squared for denoised bakes.
DENOISE_TEXEL_FACTOR = (1.0 + math.sqrt(1.5)) ** 2


@dataclass
class RetraceOptions:
    """Settings of the Retrace rule (module-level :data:`OPTIONS`; the CLI sets them).

    texels : random covered texel centres per prim (N); samples : retrace samples per texel,
        split into batches; seed : the retrace's random stream (texel choice and tracing);
    margin : relative bias accepted before the statistics (:data:`DENOISE_BIAS_BOUND`, the
        measured bound on a default bake's residual bias: denoiser, regression estimator);
    alpha : false-alarm rate per prim (Bonferroni over channels and texels);
    budget_factor : a prim with fewer than N candidate texels retraces all of them with up to
        this many times S samples, spending at most N x S paths (:func:`texel_samples`);
    min_batches, max_batches : number of independent batches K (K - 1 degrees of freedom of
        the per-texel variance); bounces : the retrace's path cap; progress : callable(str) for
        progress lines (the CLI prints them on stderr) or None.
    """

    texels: int = 1024
    samples: int = 256
    seed: int = 0
    margin: float = DENOISE_BIAS_BOUND
    alpha: float = 0.01
    min_batches: int = 16
    max_batches: int = 256
    bounces: int = RETRACE_BOUNCES
    budget_factor: int = BUDGET_FACTOR
    progress: object = None


OPTIONS = RetraceOptions()


# ------------------------------------------------------------------------------- statistics


def batch_plan(samples: int, bake_samples: int, options: RetraceOptions) -> tuple[int, int]:
    """(K batches, s samples per batch) for ``samples`` retrace samples per texel.

    s is at most the bake's sample count when the batch count allows it, so the bake's noise
    bound (the batch variance scaled by s / S_bake) never extrapolates to fewer samples than
    measured.
    """
    k = max(options.min_batches, math.ceil(samples / max(int(bake_samples), 1)))
    k = max(2, min(k, options.max_batches, samples))
    return k, max(1, samples // k)


def bake_variance_factor(batch_samples: int, bake_samples: int) -> float:
    """Factor f with Var(bake texel) <= f * Var(batch) for a bake at ``bake_samples``.

    Monte Carlo variance falls as 1/S (randomized QMC at least as fast), so from s to
    S >= s the factor is s / S (an upper bound). Extrapolating to S < s, RQMC's faster decay
    makes s / S an underestimate; (s / S)^2 bounds decay rates up to S^-2.
    """
    ratio = batch_samples / max(int(bake_samples), 1)
    return ratio if ratio <= 1.0 else ratio * ratio


def compare(
    baked: np.ndarray,
    batches: np.ndarray,
    *,
    bake_factor: float,
    margin: float,
    alpha: float,
    texel_mask: np.ndarray | None = None,
    adaptive_tol: float | None = None,
    denoised: bool = False,
    mean_alpha: float | None = None,
) -> dict:
    """The Retrace statistics of one prim.

    baked : (n, 3) float64 baked I_z; batches : (K, n, 3) float64 independent retrace
        estimates (K >= 2); bake_factor : :func:`bake_variance_factor`; margin, alpha : see
        :class:`RetraceOptions`; texel_mask : (n,) bool texels eligible for the per-texel test
        (None: all; an all-False mask disables it); adaptive_tol : the bake's adaptive
        tolerance when it was adaptive (its texels may stop at that relative standard error);
        denoised : the bake was denoised (the per-texel bound scales the bake's variance by
        :data:`DENOISE_TEXEL_FACTOR`); mean_alpha : the mean test's share of alpha (None:
        alpha / 2; the per-texel test has alpha / 2).
    returns : dict with ``ratio``, ``se``, ``se_empirical``, ``se_model``, ``bound`` (3,) float
        (|R - 1| allowed), ``tested`` (3,) bool channels ratio-tested, ``mean_fail`` (3,) bool,
        ``q_mean``, ``q_texel`` floats, ``texel_fail`` (n, 3) bool, ``texel_excess`` (n, 3)
        float (|b - r| / bound, > 1 fails), ``retrace`` (n, 3), ``retrace_sd`` (n, 3) standard
        error of the retrace mean, ``n``, ``batches`` ints.
    """
    b = np.asarray(baked, np.float64)
    e = np.asarray(batches, np.float64)
    if e.ndim != 3 or e.shape[1:] != b.shape or b.ndim != 2 or e.shape[0] < 2:
        raise UsageError(
            f"compare needs baked (n, 3) and batches (K >= 2, n, 3), got {b.shape}, {e.shape}"
        )
    k, n, c = e.shape
    r = e.mean(axis=0)
    v = e.var(axis=0, ddof=1)  # per-batch variance
    v_r = v / k
    v_b = v * bake_factor
    if adaptive_tol is not None:
        level = np.maximum(np.abs(r), 1e-3 * np.abs(r).max(axis=0, keepdims=True))
        v_b = np.maximum(v_b, (adaptive_tol * level) ** 2)
    sum_r, sum_b = r.sum(axis=0), b.sum(axis=0)
    top = np.abs(sum_r).max() if n else 0.0
    tested = (sum_r > DARK_CHANNEL * top) & (top > 0)
    n_tested = max(int(tested.sum()), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(tested, sum_b / np.where(tested, sum_r, 1.0), np.nan)
        res = b - np.where(tested, ratio, 0.0) * r
        se_emp = np.sqrt(n / max(n - 1, 1) * (res * res).sum(axis=0)) / np.abs(sum_r)
        rr = np.where(tested, ratio, 1.0)
        se_mod = np.sqrt((v_b + rr * rr * v_r).sum(axis=0)) / np.abs(sum_r)
    # The residual scatter holds the bake's per-texel noise whatever it is (and the
    # retrace's), but not all of a denoised bake's: the denoiser lowers the scatter and keeps
    # each chart's sum (docs/texels.md), so the prim's mean carries the raw noise. The
    # variance model bounds that raw noise (plain Monte Carlo at the bake's sample count).
    se = np.maximum(se_emp, se_mod)
    share = 0.5 * alpha if mean_alpha is None else float(mean_alpha)
    q_mean = t_isf(0.5 * share / n_tested, max(n - 1, 1))
    bound = margin + q_mean * se
    mean_fail = tested & (np.abs(ratio - 1.0) > bound)
    # per texel
    mask = np.ones(n, bool) if texel_mask is None else np.asarray(texel_mask, bool)
    m_t = int(mask.sum())
    q_texel = t_isf(0.5 * alpha / (2.0 * max(m_t, 1) * n_tested), k - 1)
    mean_level = np.abs(r).mean(axis=0, keepdims=True)
    level = np.maximum(np.abs(r), TEXEL_FLOOR * mean_level)
    # Heavy tails: where rare paths carry much light (indirect light of a small lamp close to
    # a surface), K batches often miss the rare events that make a texel's variance, and the
    # bake shows them as isolated fireflies. The prim's pooled relative variance (all n x K
    # batches) sees them: no texel's noise is taken below it.
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(level > 0, v / (level * level), 0.0)
    pooled = rel.mean(axis=0, keepdims=True)
    v_t = np.maximum(v, pooled * level * level)
    v_bt = v_t * bake_factor * (DENOISE_TEXEL_FACTOR if denoised else 1.0)
    if adaptive_tol is not None:
        v_bt = np.maximum(v_bt, (adaptive_tol * level) ** 2)
    allowed = margin * level + q_texel * np.sqrt(v_t / k + v_bt)
    diff = np.abs(b - r)
    with np.errstate(divide="ignore", invalid="ignore"):
        excess = np.where(allowed > 0, diff / allowed, np.where(diff > 0, np.inf, 0.0))
    texel_fail = mask[:, None] & tested[None, :] & (excess > 1.0)
    return {
        "ratio": ratio,
        "se": se,
        "se_empirical": se_emp,
        "se_model": se_mod,
        "bound": bound,
        "tested": tested,
        "mean_fail": mean_fail,
        "q_mean": float(q_mean),
        "q_texel": float(q_texel),
        "texel_fail": texel_fail,
        "texel_excess": np.where(mask[:, None] & tested[None, :], excess, 0.0),
        "retrace": r,
        "retrace_sd": np.sqrt(v_r),
        "n": int(n),
        "batches": int(k),
        "texels_tested": m_t,
    }


# ------------------------------------------------------------------------------ texel choice


def retrace_seed(seed: int, prim_path: str) -> int:
    """The retrace's 32-bit seed for a prim (a stream of its own: the baker hashes
    ``f"{seed}:{path}"``, this ``f"retrace:{seed}:{path}"``)."""
    return int.from_bytes(
        hashlib.sha256(f"retrace:{seed}:{prim_path}".encode()).digest()[:4], "little"
    )


def interior_mask(xy: np.ndarray, chart: np.ndarray, resolution, radius: int = 2) -> np.ndarray:
    """(n,) bool: texels whose (2 radius + 1)^2 neighbourhood is covered by their own chart.

    xy : (n, 2) int texel column/row; chart : (n,) int chart id per texel. With radius 2 no
    bilinear tap of a seam sample (taps lie within one texel of the chart border) and no
    dilated gutter texel is among them, so stitching and dilation leave them unchanged.
    """
    w, h = resolution
    img = np.full((h + 2 * radius, w + 2 * radius), -1, np.int64)
    x = np.asarray(xy[:, 0], np.int64) + radius
    y = np.asarray(xy[:, 1], np.int64) + radius
    img[y, x] = np.asarray(chart, np.int64)
    ok = np.ones(len(xy), bool)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            ok &= img[y + dy, x + dx] == img[y, x]
    return ok


def texel_samples(picked: int, options: RetraceOptions) -> int:
    """Samples per texel for a prim with ``picked`` texels: S, or for a prim with fewer
    candidates than N the same budget N x S spread over them (at most budget_factor x S)."""
    s = int(options.samples)
    if picked <= 0 or picked >= int(options.texels):
        return s
    spread = (s * int(options.texels)) // picked
    return max(s, min(spread, s * int(options.budget_factor)))


def pick_texels(candidates: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``count`` distinct sorted entries of ``candidates`` (all if fewer), seeded."""
    candidates = np.asarray(candidates)
    if len(candidates) <= count:
        return np.sort(candidates)
    rng = np.random.default_rng([seed, 0])
    return np.sort(rng.choice(candidates, size=count, replace=False))


# --------------------------------------------------------------------------- scene + tracer


class _TracerCache:
    """(scene, tracer) per stage (keyed by its layers' files, like Staleness) and UV name.

    The geometry is the same for every UV name, so one tracer serves them all; stages with
    unsaved or anonymous layers are not cached.
    """

    def __init__(self):
        self._data: OrderedDict = OrderedDict()

    @staticmethod
    def key(stage):
        import os

        parts = []
        for layer in stage.GetUsedLayers():
            if layer.anonymous:
                if layer == stage.GetSessionLayer() and layer.empty:
                    continue
                return None
            if layer.dirty:
                return None
            try:
                st = os.stat(layer.realPath)
            except OSError:
                return None
            parts.append((layer.identifier, st.st_size, st.st_mtime_ns))
        return tuple(sorted(parts))

    def get(self, stage, uv_name: str):
        from usdahd.bake.trace import Tracer
        from usdahd.scene.hashing import is_dark
        from usdahd.usd.reader import load_scene

        key = self.key(stage)
        entry = self._data.get(key) if key is not None else None
        if entry is None:
            entry = {"scenes": {}, "tracer": None}
        if uv_name not in entry["scenes"]:
            entry["scenes"][uv_name] = load_scene(stage, uv_name=uv_name)
        scene = entry["scenes"][uv_name]
        if entry["tracer"] is None and not is_dark(scene):
            entry["tracer"] = Tracer(scene)
        if key is not None:
            self._data[key] = entry
            self._data.move_to_end(key)
            while len(self._data) > 2:
                self._data.popitem(last=False)
        return scene, entry["tracer"]

    def clear(self):
        self._data.clear()


_TRACERS = _TracerCache()
#: One retrace at a time: the tracer's first run is not thread-safe and it uses every core.
_RETRACE_LOCK = threading.Lock()


# ------------------------------------------------------------------------------------ rule


def _finding(prim, severity, code, message, fix="", **data):
    from usdahd.validate import Finding, jsonable

    text = message.rstrip(".") + "." + (f" Fix: {fix.rstrip('.')}." if fix else "")
    return Finding(RULE, severity, str(prim.GetPath()), code, text, jsonable(data))


def baked_iz(bake, rows: np.ndarray) -> np.ndarray:
    """(m, 3) float64 baked I_z of bake rows: sidecar SH when present, else decoded at z."""
    from usdahd.numerics import sh as shm

    if bake.sh is not None:
        return shm.iz(np.asarray(bake.sh[rows], np.float64))
    params = {k: np.asarray(v)[rows] for k, v in bake.params.items()}
    if "iz" in params:
        return params["iz"].astype(np.float64)
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(rows), 3))
    return np.asarray(bake.mod.evaluate(params, z), np.float64)


def check_retrace(prim, options: RetraceOptions | None = None) -> list:
    """Rule Retrace on one prim (see the module doc); returns usdahd.validate.Finding."""
    with _RETRACE_LOCK:
        return _check(prim, options or OPTIONS)


def prim_candidates(prim):
    """The prim's retrace candidates: (bake, scene, tracer, mesh, texels, rows, candidates,
    estimated), texels the bake's rasterised texels (in the bake's order), rows their bake
    rows (-1 uncovered), candidates the indices of covered, validly decoded texel centres the
    bake estimated, estimated all such texels (centres or not: the replay's population); or a
    str saying why the rule cannot run."""
    from usdahd import validate as V
    from usdahd.bake.contacts import push_off_contacts
    from usdahd.bake.texels import rasterize
    from usdahd.errors import UsdAhdError

    path = str(prim.GetPath())
    try:
        bake = V.load_bake(prim)
    except V.SkipRule as why:
        return str(why)
    res = bake.results
    uv_name = str(res.uv_primvar or res.settings.get("uv") or "st")
    try:
        scene, tracer = _TRACERS.get(prim.GetStage(), uv_name)
    except UsdAhdError as exc:
        return f"the stage cannot be read as a scene ({exc}); see Staleness"
    mesh = next((m for m in scene.meshes if m.path == path), None)
    if mesh is None:
        return "the prim is not a visible mesh the baker would bake; see Staleness"
    if mesh.uv is None:
        return f"primvars:{uv_name} cannot be read as lightmap UVs; see UVSet"
    try:
        texels = rasterize(mesh, res.resolution)
    except UsdAhdError as exc:
        return f"the lightmap UVs do not rasterise ({exc}); see UVSet"
    contact_invalid = np.zeros(len(texels), bool)
    if tracer is not None:  # the bake's sample points (moved off contacts, docs/texels.md)
        texels, contact_invalid = push_off_contacts(texels, mesh, tracer)
    w, h = res.resolution
    rows_img = np.full((h, w), -1, np.int64)
    rows_img[bake.xy[:, 1], bake.xy[:, 0]] = np.arange(len(bake.xy))
    rows = rows_img[texels.xy[:, 1], texels.xy[:, 0]]
    if bake.sh is not None:
        mism = int((rows < 0).sum()) + (len(bake.xy) - int((rows >= 0).sum()))
        if mism > COVERAGE_MISMATCH * max(len(bake.xy), 1):
            return (
                f"primvars:{uv_name} rasterised at {w}x{h} covers {len(texels)} texels but the "
                f"bake covered {len(bake.xy)} ({mism} differ): the UVs changed since the bake; "
                "see Staleness"
            )
    ok = rows >= 0
    ok[ok] = bake.valid[rows[ok]]
    ok &= ~contact_invalid  # filled from neighbours in the bake, not estimated there
    candidates = np.nonzero(ok & texels.center_inside)[0]
    if len(candidates) < MIN_TEXELS:
        return f"only {len(candidates)} covered texel centre(s) decode validly"
    return bake, scene, tracer, mesh, texels, rows, candidates, np.nonzero(ok)[0]


def candidate_rows(prim) -> np.ndarray | None:
    """Bake rows of the prim's retrace candidates (None when the rule would skip it)."""
    got = prim_candidates(prim)
    return None if isinstance(got, str) else got[5][got[6]]


def _check(prim, opt: RetraceOptions) -> list:
    from usdahd.bake import integrate
    from usdahd.bake.texels import chart_ids
    from usdahd.validate import replay

    def skipped(why):
        return [_finding(prim, "info", "Skipped", f"Retrace did not run: {why}")]

    path = str(prim.GetPath())
    got = prim_candidates(prim)
    if isinstance(got, str):
        return skipped(got)
    bake, scene, tracer, mesh, texels, rows, candidates, _ = got
    res = bake.results
    w, h = res.resolution
    seed = retrace_seed(opt.seed, path)
    pick = pick_texels(candidates, int(opt.texels), seed)
    charts = chart_ids(mesh)[texels.triangle]
    interior = interior_mask(texels.xy, charts, (w, h))[pick]
    sub = texels.take(pick)
    baked = baked_iz(bake, rows[pick])
    settings = res.settings or {}
    bake_samples = int(settings.get("samples") or 256)
    k, s = batch_plan(texel_samples(len(pick), opt), bake_samples, opt)
    t0 = time.perf_counter()
    if opt.progress:
        opt.progress(f"retrace {path}: {len(pick)} texels x {k * s} samples ({k} batches)")
    dark = tracer is None
    # the bake's own random stream replayed (exact: the bake's noise cancels; usdahd.validate.
    # replay), then the independent retrace (the physics, whatever the bake's settings were)
    rp = "nothing emits light" if dark else replay.run(path, got, opt)
    if dark:  # nothing emits: the exact answer is 0
        batches = np.zeros((k, len(pick), 3))
        backface = np.zeros(len(pick))
        rays = 0
    else:
        batches, backface, rays = integrate.iz_batches(
            scene,
            tracer,
            sub,
            batches=k,
            samples=s,
            bounces=int(opt.bounces),
            seed=seed,
            stream=1,
            mesh=next((i for i, m in enumerate(scene.meshes) if m is mesh), None),
        )
    seconds = time.perf_counter() - t0
    if dark:
        inside = np.zeros(len(pick), bool)
    else:  # the baker's rule (it filled these from neighbours)
        offsets = tracer.texel_offsets(sub, mesh)
        inside = integrate.inside_geometry(
            tracer, sub, offsets, backface, backface_threshold(), mesh
        )
    finite = np.isfinite(baked).all(axis=1) & np.isfinite(batches).all(axis=(0, 2))
    use = ~inside & finite
    n = int(use.sum())
    base = dict(
        texels=n,
        texels_inside_geometry=int(inside.sum()),
        samples=k * s,
        batches=k,
        bounces=int(opt.bounces),
        seconds=seconds,
        rays=rays,
        seed=int(opt.seed),
        bake_samples=bake_samples,
        bake_bounces=settings.get("bounces"),
    )
    if n < MIN_TEXELS:
        return skipped(f"only {n} of the sampled texels lie outside geometry")
    denoised = bool(settings.get("denoise"))
    adaptive = integrate.ADAPTIVE_TOL if settings.get("adaptive") else None
    st = compare(
        baked[use],
        batches[:, use],
        bake_factor=bake_variance_factor(s, bake_samples),
        margin=float(opt.margin),
        alpha=float(opt.alpha),
        texel_mask=interior[use],
        adaptive_tol=adaptive,
        denoised=denoised,
        mean_alpha=None if isinstance(rp, str) else replay.REPLAY_ALPHA * float(opt.alpha),
    )
    xy = sub.xy[use]
    base.update(replay.data(rp))
    st["replay"] = rp
    return _report(prim, st, xy, baked[use], base, settings, opt, denoised, dark)


def backface_threshold() -> float:
    """The baker's inside-geometry threshold (bake_texels' default, which the pipeline uses)."""
    from usdahd.bake import integrate

    return float((integrate.bake_texels.__kwdefaults__ or {}).get("backface_threshold", 0.25))


def _report(prim, st, xy, baked, base, settings, opt, denoised, dark) -> list:
    from usdahd.validate import replay

    if dark:  # nothing emits light: the exact answer is 0 (the baker traces nothing either)
        top = float(np.abs(baked).max())
        if top > 0:
            return [
                _finding(
                    prim,
                    "error",
                    "RetraceMismatch",
                    f"the stage has no light source, yet the baked I_z reaches {top:.4g} at "
                    f"{base['texels']} sampled texels: the lighting changed since the bake or "
                    "the textures were edited",
                    "check Staleness, re-bake the prim",
                    **base,
                )
            ]
        return [_finding(prim, "info", "RetraceOk", "no light source: baked I_z is 0", **base)]
    ratio, se, bound, tested = st["ratio"], st["se"], st["bound"], st["tested"]
    chans = [c for c, t in zip(CHANNELS, tested) if t]
    data = dict(
        base,
        ratio=[float(x) if t else None for x, t in zip(ratio, tested)],
        standard_error=[float(x) if t else None for x, t in zip(se, tested)],
        standard_error_empirical=[
            float(x) if t else None for x, t in zip(st["se_empirical"], tested)
        ],
        standard_error_model=[float(x) if t else None for x, t in zip(st["se_model"], tested)],
        bound=[float(x) if t else None for x, t in zip(bound, tested)],
        margin=float(opt.margin),
        alpha=float(opt.alpha),
        texels_per_texel_test=st["texels_tested"],
        denoised=denoised,
    )
    ratio_txt = ", ".join(
        f"{c} {ratio[i]:.4f} +- {se[i]:.2g}" for i, c in enumerate(CHANNELS) if tested[i]
    )
    head = (
        f"baked/retraced I_z over {base['texels']} random texel centres ({base['samples']} "
        f"samples each, plain Monte Carlo, up to {base['bounces']} bounces with Russian "
        f"roulette): {ratio_txt}"
    )
    out = []
    if st["mean_fail"].any():
        i = int(np.argmax(np.where(st["mean_fail"], np.abs(ratio - 1.0) - bound, -np.inf)))
        darker = ratio[i] < 1.0
        bounces = settings.get("bounces")
        if darker and bounces is not None and int(bounces) <= 8:
            why = (
                f"the bake is darker than its own integrator with unbounded paths and was "
                f"made with bounces={int(bounces)}: light of longer paths (indirect bounces) "
                "is missing"
            )
            fix = "re-bake without a bounce cap (the default --bounces)"
        elif darker:
            why = (
                "the bake is darker than the retrace: light is missing (lights or materials "
                "changed since the bake, or the textures and sidecar were scaled down)"
            )
            fix = "check Staleness, re-bake the prim"
        else:
            why = (
                "the bake is brighter than the retrace: the textures (and the SH sidecar) "
                "were scaled after the bake, or the lights changed since"
            )
            fix = "check Staleness, re-bake the prim"
        out.append(
            _finding(
                prim,
                "error",
                "RetraceMismatch",
                f"{head}; channel {CHANNELS[i]} is {abs(ratio[i] - 1.0):.3g} from 1, beyond "
                f"the bound {bound[i]:.3g} (margin {opt.margin:g} + {st['q_mean']:.2f} "
                f"standard errors; false-alarm rate <= {opt.alpha:g} per prim): {why}",
                fix,
                **data,
            )
        )
    rp = st.get("replay")
    if isinstance(rp, dict) and rp["fail"].any():
        out.append(
            _finding(
                prim,
                "error",
                "RetraceMismatch",
                replay.message(rp, CHANNELS, opt.margin, replay.REPLAY_ALPHA * opt.alpha),
                "check Staleness, re-bake the prim",
                **data,
            )
        )
    fail = st["texel_fail"]
    if fail.any():
        exc = st["texel_excess"]
        worst = int(np.argmax(exc.max(axis=1)))
        c = int(np.argmax(exc[worst]))
        x, y = (int(v) for v in xy[worst])
        r = st["retrace"][worst, c]
        sd = st["retrace_sd"][worst, c]
        nfail = int(fail.any(axis=1).sum())
        out.append(
            _finding(
                prim,
                "warning",
                "RetraceOutlier",
                f"{nfail} of {st['texels_tested']} interior texel(s) differ from the retrace "
                f"beyond the per-texel bound (margin {opt.margin:g} of the texel's level + "
                f"{st['q_texel']:.2f} standard deviations of bake and retrace noise, "
                f"Bonferroni over texels: <= {opt.alpha:g} per prim for light-tailed noise); "
                f"worst at texel ({x}, {y}) channel {CHANNELS[c]}: baked "
                f"{baked[worst, c]:.4g}, retraced {r:.4g} +- {sd:.2g}. A warning, not an "
                "error: bake noise is heavy-tailed where rare paths carry much light, so one "
                "texel can be a firefly of the bake; several texels point at a local defect "
                "(a light leak, an edited texel, a moved occluder)",
                "look at the lightmap around the texel; re-bake with more --samples if it is "
                "an isolated firefly, else check Staleness and re-bake the prim",
                **dict(data, failing_texels=nfail, worst_texel=(x, y)),
            )
        )
    if not out:
        note = "" if not denoised else "; denoised bake (per-texel bound widened)"
        if len(chans) < 3:
            note += f"; channels tested: {', '.join(chans) or 'none'}"
        if isinstance(rp, dict):
            note += "; its own random stream replayed at {} of {} texels: {}".format(
                rp["texels"],
                rp["population"],
                ", ".join(
                    f"{c} {rp['ratio'][j]:.4f}" for j, c in enumerate(CHANNELS) if rp["tested"][j]
                ),
            )
        elif rp:
            note += f"; not replayed: {rp}"
        out.append(_finding(prim, "info", "RetraceOk", head + note, **data))
    return out


# ------------------------------------------------------------------------------ registration


def validator_name() -> str:
    from usdahd.validate import PLUGIN_NAME

    return f"{PLUGIN_NAME}:{RULE}"


def _recorded(prim) -> list:
    """check_retrace on a prim with AhdLightmapAPI, an exception becoming an InternalError
    finding, keeping each finding's data in FINDING_DATA (see usdahd.validate.plugin)."""
    from usdahd import validate as V
    from usdahd.usd import schema

    if not schema.has_api(prim):
        return []
    try:
        found = check_retrace(prim)
    except Exception as exc:  # noqa: BLE001 - reported, never raised (see validate.run_rule)
        first = str(exc).strip().splitlines()[0][:300] if str(exc).strip() else ""
        found = [
            _finding(
                prim,
                "error",
                "InternalError",
                f"rule {RULE} could not run: {type(exc).__name__}: {first}",
                "report this as a usdahd bug (with the stage) and check the prim by hand",
            )
        ]
    with V.LOCK:
        for f in found:
            V.FINDING_DATA[(f.rule, f.prim, f.code, f.message)] = f.data
    return found


def _task(prim, time_range=None):
    """The UsdValidation prim task of Retrace (usdahd.usd.validation.prim_task)."""
    from usdahd.usd import validation as usd_validation

    return usd_validation.prim_task(RULE, _recorded)(prim, time_range)


_task.__name__ = f"usdahd_{RULE}"


def register() -> list[str]:
    """Register the Retrace validator with UsdValidation (idempotent; only when the plugInfo
    declares it). Returns the names registered by this call."""
    from usdahd.usd import validation as usd_validation

    name = validator_name()
    return [name] if usd_validation.register_validator(name, _task) else []
