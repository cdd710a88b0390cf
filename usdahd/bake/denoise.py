"""Intel Open Image Denoise (``pyoidn``) for baked radiance SH, chart by chart.

``denoise_sh(sh, texels, charts=...)`` returns a denoised copy of all 27 coefficients. Three
stages per chart:

1. **Context.** OIDN is a convolutional network: near an image border, or on a chart of a few
   texels, it has no context and distorts even a constant image (measured: a constant 16 x 16
   image comes back with up to 8.7 % error at its corners; 24 x 24 in directional mode 23 %;
   this, unpadded charts at the lightmap's edge and the ratio path for I_z below caused the
   old 2.4 % error floor). Each chart is put alone into its own canvas with at least ``PAD``
   texels on every side, its sides rounded up to a multiple of ``OIDN_BLOCK`` (OIDN's own
   padding) and at least ``MIN_CROP`` (also past the lightmap's edges): holes in the
   chart's bounding box are grown from the chart (:func:`usdahd.bake.post.dilate`) and the box
   is mirrored outward, so the network sees the chart's own signal *and noise* around it
   (constant 16 x 16 chart: < 0.1 %; smooth dilation instead of mirroring made OIDN leave
   small noisy charts almost untouched).
2. **Denoise.** ``filter="RTLightmap"`` (default; OIDN's lightmap network, no guides): the
   band-0 RGB coefficient ``c00`` and the l=1, m=0 coefficient ``c10`` (proportional to
   I_z, the quantity the IrradZ models store exactly: ``usdahd.sh.iz``) are each denoised as
   HDR lightmaps (OIDN's HDR mode is scale invariant, checked 0.01..1000). Every other
   coefficient ``c_lm`` is divided by ``sqrt(2l+1) * c00`` (in [-1, 1] for non-negative
   radiance), averaged over the chart's texels within ``DIRECTIONAL_RADIUS`` and multiplied
   back by the denoised ``c00`` (``DIRECTIONAL_OIDN``: OIDN's ``directional`` mode instead,
   as measured there: 7 of 9 OIDN runs for a few % of directional accuracy).
   ``filter="RT"`` runs OIDN's RT network with ``albedo``/``normal`` guides instead of
   RTLightmap (HDR for c00 and c10; with ``DIRECTIONAL_OIDN`` the ratios mapped to [0, 1]
   as LDR).
3. **Blend by the noise.** A network also changes signal (the directional one moved the
   l=1, 2 coefficients of pillar_room's light hotspot by 4-20 noise deviations), so its
   output is only trusted as far as the input is noisy: per texel and coefficient,
   ``out = x + w (d - x)``, ``w = min(1, g var / change)`` (:func:`blend_weights`), ``change``
   the mean of ``(d - x)^2`` over nearby chart texels. If the denoiser only removed noise,
   ``change ~ var`` and ``w = 1``; where it changed the signal by ``b >> noise``,
   ``w ~ g var / b^2`` keeps the input; a noise-free input (``var = 0``) comes back exactly.
   ``var`` is passed in (``variance``; a bake passes the integrator's own,
   :func:`integrator_iz_variance`, averaged over ``VARIANCE_POOL``) or estimated by
   :func:`noise_variance` from second differences of neighbouring texels. With the
   integrator's variance (``variance_bound``, a bake) each chart's summed c10 is put back to
   the input's (:func:`~usdahd.bake.blend.keep_chart_energy`), and so is each ring's from the
   chart border (:func:`~usdahd.bake.blend.border_depth`, up to ``ENERGY_DEPTH``) over all the
   record's denoised charts (:func:`~usdahd.bake.blend.keep_class_energy`): on charts a few
   texels wide the network smooths across the chart, moving energy between its border and
   its middle.

Charts are never mixed: each chart has its own canvas, only its texels are written back.
OIDN runs on the canvases of many charts at once (:func:`denoise_records`, every prim of a
bake): they are laid out side by side as tiles of one mosaic image per coefficient
(:mod:`usdahd.bake.mosaic`), each HDR tile scaled by its own exposure, so a
chart sees its own filled context on every side (``HDR_CROP``: 10 texels for c00 and c10,
``DIRECTIONAL_CROP``: 8 for the others when OIDN runs them; between tiles the HDR mosaics are
filled from the nearest tile, not 0) and the run count no longer grows with the charts (2 runs
per mosaic instead of 2 per chart; 9 with ``DIRECTIONAL_OIDN``). Results differ from chart by
chart only by the network's response to what lies beyond a canvas (another tile instead
of the image border): docs/time-to-quality.md states the bound measured on the samples.
"""

from __future__ import annotations

import threading

import numpy as np

from usdahd.bake.blend import (
    BAND_BOUND,
    BLEND_GAIN,
    RATIO_COEFFS,
    blend_chart,
    border_depth,
    class_scale,
    class_sums,
    keep_chart_energy,
)
from usdahd.bake.canvas import Canvas as _Canvas
from usdahd.bake.mosaic import HDR_CROP_PAD
from usdahd.bake.mosaic import plan as plan_mosaic
from usdahd.bake.mosaic import run as run_mosaic
from usdahd.bake.types import Texels
from usdahd.bake.variance import (
    canvas_noise,
    integrator_iz_variance,
    sh_variance,
)
from usdahd.errors import InputError, UsageError
from usdahd.numerics.noise import bends
from usdahd.numerics.windows import box_mean_texels

__all__ = ["VARIANCE_POOL", "denoise_records", "integrator_iz_variance", "sh_variance"]

FILTERS = ("RTLightmap", "RT")
#: Coefficients denoised as HDR lightmaps: c00 (mean radiance) and c10 (I_z, index 2).
_HDR_COEFFS = (0, 2)

# Tolerances and sizes (each with its reason)
#: The gain with the integrator's variance (``variance_bound``: the per-texel minimum of its
#: two upper bounds, s^2 / S and the two-halves estimate, pooled over ``VARIANCE_POOL``, and
#: of the second-difference estimate). The weight minimising the blend's expected squared
#: error is var / change (gain 1: ``change`` = b^2 + var for a denoiser that moved the signal
#: by b); the margin covers the scatter of a minimum of noisy estimates. Measured against
#: the 4096-spp point truth (10 stages x 16-1024 spp x 2 seeds, net relRMSE with --denoise /
#: without): gain 1 / 1.5 / 2 gave exterior_sun_sky's sun shadows 0.66-0.88 / 0.82-0.88 /
#: 0.92-0.97, the shared Cornell box at 16 spp 0.37 / 0.24 / 0.21 (docs/time-to-quality.md).
VARIANCE_BOUND_GAIN = 1.5
#: Chebyshev radius (texels) over which the integrator's variance is averaged within a chart
#: (``variance_pool``): the two-halves estimate has one degree of freedom per texel; 2 (a
#: 5 x 5 window, the window of ``change``, BIAS_RADIUS) measured as well as 1 or 3.
VARIANCE_POOL = 2
#: With the integrator's variance, the second-difference estimate is taken again after OIDN
#: without the texels where the *denoised* image curves (a squared second difference above
#: CURVATURE_CONTRAST x 6 var in some direction and channel, i.e. a signal curvature of more
#: than 2 noise deviations): there the curvature is signal, and counted as noise it let OIDN
#: move the flat texels beside a sun shadow by ~3 noise deviations (exterior_sun_sky's ground
#: at 256 spp: 1.07x the error without --denoise -> 0.95x). Measured (denoise_gain, 2 seeds,
#: 10 stages x 16-1024 spp): 1 left much noise (geometric-mean ratio 0.475 -> 0.518), 4 costs
#: 1 % (0.480) and no mesh's error rises; the gradient test of EDGE_CONTRAST instead also
#: dropped smooth gradients at high sample counts (stretched_boxes 1024 spp 0.81 -> 0.95).
CURVATURE_CONTRAST = 4.0
#: With the integrator's variance, summed I_z is also kept per ring of texels counted from
#: the chart's border (0: the border, 1: the ring inside it, ..., ENERGY_DEPTH: the rest),
#: pooled over every denoised chart of a record (:func:`usdahd.bake.blend.keep_class_energy`):
#: OIDN smooths across charts a few texels wide and moved energy from their middle to their
#: darker border (Sponza's window frames at 64^2: -1.65 % -> -2.97 % on the compared middle
#: texels). Measured on Sponza's 25 compared meshes (64^2, 256 spp, the bake's captured
#: denoise input against the 1024-spp Cycles truth): windows_lib_0 -2.97 % -> -1.86 %
#: (input -1.65 %), relRMSE 10.88 -> 10.65 %, no other mesh's relRMSE up by more than 0.05
#: points; depth 1 alike (-1.84 %); kept per chart instead of per record the rings re-inject
#: the input's noise of few texels (object21_lib_0, 48 texels, relRMSE 11.6 -> 12.4 %).
ENERGY_DEPTH = 2

#: Canvas pixels of the charts denoised together (one mosaic image per coefficient): enough
#: for OIDN's per-run cost to vanish, few enough to bound the memory of the charts held and
#: OIDN's scratch, which follows the image (RTLightmap, quality high, pyoidn 2.5.1: +600 MB at
#: 1024^2, +150 MB at 512^2, at the same CPU time per pixel, 2.3 us; 2026-12-06, session
#: script oidn_mem2.py). Was 1 << 20: the classroom's denoise peaked at +660 MB in OIDN.
MOSAIC_PIXELS = 1 << 18
#: OIDN's scratch cap (``maxMemoryMB``) for an image above ``MOSAIC_PIXELS`` (one large chart):
#: OIDN then denoises it in tiles, the same output (checked: equal sums at 1024^2). 512 costs
#: ~7 % more CPU at 1024^2 (+410 MB, 3.06 s vs +590 MB, 2.87 s); 256 would cost 2x.
OIDN_LARGE_MEMORY_MB = 512

#: Threads for the charts' noise estimates and blends (numpy's array operations and the
#: noise kernel release the GIL): on 2 cores these ran on one while OIDN used both, and were
#: about a third of the denoiser's CPU time (docs/time-to-quality.md, issue 43). Each chart's
#: result does not depend on the threads (tests/bake/test_denoise.py).
CHART_THREADS = 2
#: Below this many texels in a denoise_records call the charts' work stays on the calling
#: thread: handing small charts to threads cost more than it saved (denoise_records of warm
#: 256-spp bakes, 2 threads vs 1: stretched_boxes 32² (2,199 texels) 58 vs 53 ms, pillar_room
#: 32² (2,599) 78 vs 68, exterior_sun_sky 32² (2,950) 80 vs 72; even at ~7,000
#: (stretched_boxes 64², cornell_box 32²); threads ahead from cornell_box 64² (23,320: 177
#: vs 193 ms) and stretched_boxes 128² (234 vs 264)).
CHART_THREADS_MIN_TEXELS = 4096
#: The 7 directional coefficients' ratios (c_lm / (sqrt(2l + 1) c00)) are denoised by their
#: mean over the chart's texels within DIRECTIONAL_RADIUS (Chebyshev; 1: 3 x 3), then blended
#: texel by texel like OIDN's output was; True runs them through OIDN's directional network
#: instead (7 of 9 runs per mosaic, ~70 % of OIDN's pixels; the reference the mean is
#: measured against). Measured (benchmarks/denoise_directional.py's method, 5 stages at 32^2,
#: 16-1024 spp, seeds 0 and 1, against usdahd's own two 4096-spp bakes): the l=1 and l=2
#: errors within -10..+9 % of OIDN's (the largest rise exterior_sun_sky at 16 spp, 1.65 ->
#: 1.79 %; lower than OIDN's at 1024 spp there; the undenoised input 2.50 %), c00 and I_z bit
#: for bit, the bake's CPU 0.51 -> 0.30 s (exterior_sun_sky 16 spp), 0.39 -> 0.24
#: (stretched_boxes), 0.77 -> 0.54 (cornell_box): most of a directional error after the
#: denoise is c00's (the ratio is multiplied by the denoised c00), so the network's better
#: ratios bought little. Radius 2 and 3 and a c00-weighted mean: up to 16 % and 25 % above
#: OIDN's (docs/time-to-quality.md). With DIRECTIONAL_NOISE_ESTIMATE off (below) the same
#: runs give 0.89-1.04x OIDN's errors (geometric mean 0.98).
DIRECTIONAL_OIDN = False
DIRECTIONAL_RADIUS = 1
#: With the integrator's variance (a bake, ``variance_bound``), the 7 directional coefficients'
#: blend takes that variance alone, without the per-coefficient second-difference estimate
#: (made for c00 and c10 only: before OIDN and again off the denoised image's curvature):
#: their mean is no network to be held back at a hotspot, and the estimate was ~3/4 of the
#: noise kernel's work. Measured (benchmarks/denoise_directional.py's method, 5 stages at 32^2,
#: 16-1024 spp, seeds 0 and 1): l=1 and l=2 errors 0.86-1.01x of those with the estimate
#: (exterior_sun_sky 16 spp l=1 1.79 -> 1.56 %, below OIDN's 1.65 %), I_z bit for bit, bake CPU
#: -0..-10 %. True estimates them too (the API's default without a variance always does).
DIRECTIONAL_NOISE_ESTIMATE = False
#: The directional coefficients' OIDN tiles (DIRECTIONAL_OIDN) are cropped to the
#: chart's box and mosaic.CROP_PAD texels of context (mosaic.MOSAIC_CROP for them alone), packed on
#: mosaic.MOSAIC_GRID columns: OIDN's run count is fixed, its time follows its pixels, and at
#: 32^2 the canvases' rounding to OIDN_BLOCK gives 4-9 OIDN pixels per texel. Their error
#: against a converged bake is in docs/time-to-quality.md.
DIRECTIONAL_CROP = True
#: c00's and c10's (I_z's) OIDN tiles cropped too, to the chart's box and mosaic.HDR_CROP_PAD
#: (10) texels, on a mosaic whose empty pixels are filled from the tiles (mosaic.fill_empty):
#: the other 2 of a mosaic's 9 runs, 16-40 % fewer pixels at 32^2 (the canvases' rounding to
#: OIDN_BLOCK and MIN_CROP is context OIDN needs only for a canvas run alone). Cropped on a
#: zero mosaic the noise-free gradient's I_z came back 0.53 % off (> 0.5 %,
#: tests/bake/test_denoise.py): the zeros a crop's width from the chart read as a dark border.
HDR_CROP = True
#: The directional runs' mosaic filled from the tiles as well (mosaic.fill_empty), else 0
#: between tiles (0 is a neutral ratio). Off: with it CROP_PAD 6 kept the stages' directional
#: error within +0.5 % of 8's, but the noisy fields of tests/bake/test_denoise.py came back
#: 4-7 % worse than with whole canvases at pads 6-8 (0 between tiles: 0-2 %).
DIRECTIONAL_FILL = False
#: Elements (float64) of the noise estimate's work arrays per pass (~32 MB each).
_WORK_ELEMENTS = 4_000_000
#: Texels scaled at once by the ring energy pass (_keep_ring_energy: bounded temporaries).
_BLEND_BLOCK = 65536


def _pyoidn():
    try:
        import pyoidn
    except ImportError:
        raise UsageError(
            "denoising needs Intel Open Image Denoise: pip install pyoidn, "
            "or bake with --no-denoise"
        ) from None
    return pyoidn


#: One OIDN device, with up to IDLE_FILTERS of its filters (images of at most
#: IDLE_FILTER_PIXELS pixels: OIDN's scratch follows the image, ~0.6 KB a pixel), kept between
#: denoise_records calls for a process that bakes stage after stage (a DCC plug-in, a farm
#: worker, the warm benchmarks): a new device's or filter's first run costs more than a later
#: one (a 144 x 112 mosaic: 18-25 ms on a new filter, 14 ms on a kept one; 2026-12-07). Taken
#: by one caller at a time (a second caller at once makes its own), so never shared between
#: threads; a later bake whose mosaics have other shapes gains only the device.
IDLE_FILTERS = 2
IDLE_FILTER_PIXELS = 1 << 16
_IDLE: list = []
_IDLE_LOCK = threading.Lock()


class _Denoiser:
    """One OIDN device; one filter per kind of call (type, mode, image shape, guides), reused:
    a filter's first commit sets up its network (~0.5 ms per call on small charts), a later
    commit with new images of the same shape only swaps the buffers (same output, checked).
    At most ``MAX_FILTERS`` are kept (each holds ~0.05 MB: a stage of thousands of charts of
    different shapes would otherwise keep hundreds of MB); a chart's runs share two. Made by
    :meth:`take` (the one kept from an earlier call when there is one, ``_IDLE``)."""

    MAX_FILTERS = 8

    @classmethod
    def take(cls, quality: str) -> _Denoiser:
        """The denoiser kept idle by an earlier call (its quality set to ``quality``), or a
        new one."""
        with _IDLE_LOCK:
            den = _IDLE.pop() if _IDLE else None
        if den is not None and type(den) is not cls:  # kept by a subclass (a test's)
            den._release()
            den = None
        if den is None:
            return cls(quality)
        den.quality = den.qualities[quality]
        return den

    def __init__(self, quality: str):
        self.oidn = _pyoidn()
        self.device = self.oidn.Device()
        self.device.commit()
        self.qualities = {
            "high": self.oidn.OIDN_QUALITY_HIGH,
            "balanced": self.oidn.OIDN_QUALITY_BALANCED,
            "fast": self.oidn.OIDN_QUALITY_FAST,
        }
        self.quality = self.qualities[quality]
        self.filters = {}

    def _filter(self, key, filter_type, hdr, directional):
        flt = self.filters.pop(key, None)
        if flt is None:
            while len(self.filters) >= self.MAX_FILTERS:  # the least recently used goes
                self.filters.pop(next(iter(self.filters))).release()
            flt = self.oidn.Filter(self.device, filter_type)
            if filter_type == "RTLightmap":
                flt.set_bool("directional", bool(directional))
            else:
                flt.set_bool("hdr", bool(hdr))
            flt.set_int("quality", self.quality)
        self.filters[key] = flt  # (re)inserted last: dicts keep insertion order
        return flt

    def run(
        self, color, *, filter_type, hdr=False, directional=False, albedo=None, normal=None,
        input_scale=None,
    ):  # fmt: skip
        oidn = self.oidn
        color = np.ascontiguousarray(color, dtype=np.float32)
        out = np.zeros_like(color)
        key = (filter_type, bool(hdr), bool(directional), color.shape,
               albedo is not None, normal is not None, input_scale is not None,
               self.quality)  # fmt: skip
        flt = self._filter(key, filter_type, hdr, directional)
        large = color.shape[0] * color.shape[1] > MOSAIC_PIXELS
        if large:
            flt.set_int("maxMemoryMB", OIDN_LARGE_MEMORY_MB)
        if input_scale is not None:
            flt.set_float("inputScale", float(input_scale))
        flt.set_image(oidn.OIDN_IMAGE_COLOR, color, oidn.OIDN_FORMAT_FLOAT3)
        if albedo is not None:
            albedo = np.ascontiguousarray(albedo, dtype=np.float32)
            flt.set_image(oidn.OIDN_IMAGE_ALBEDO, albedo, oidn.OIDN_FORMAT_FLOAT3)
        if normal is not None:
            normal = np.ascontiguousarray(normal, dtype=np.float32)
            flt.set_image(oidn.OIDN_IMAGE_NORMAL, normal, oidn.OIDN_FORMAT_FLOAT3)
        flt.set_image(oidn.OIDN_IMAGE_OUTPUT, out, oidn.OIDN_FORMAT_FLOAT3)
        flt.commit()
        flt.execute()
        err = self.device.get_error()
        if err is not None:
            raise InputError(f"Open Image Denoise failed: {err}")
        if large:
            # a large image (one big chart): OIDN keeps its scratch (~600 MB at 1024^2) while
            # a filter that used it lives; release it now, not at the end of the denoise
            self.filters.pop(key).release()
        return out

    def close(self):
        """Done with for now: kept for the next call (``_IDLE``) with its IDLE_FILTERS most
        recently used filters of at most IDLE_FILTER_PIXELS pixels, the others released; or,
        when one is kept already, released with its device."""
        small = [k for k in self.filters if k[3][0] * k[3][1] <= IDLE_FILTER_PIXELS]
        kept = set(small[-IDLE_FILTERS:])  # the dict's order: least recently used first
        for key in [k for k in self.filters if k not in kept]:
            self.filters.pop(key).release()
        with _IDLE_LOCK:  # published only once pruned: the next taker has it alone
            if not _IDLE:
                _IDLE.append(self)
                return
        self._release()

    def _release(self):
        for flt in self.filters.values():
            flt.release()
        self.filters.clear()
        if hasattr(self.device, "release"):
            self.device.release()


# --------------------------------------------------------------------------------------------
# noise estimate and blending


def noise_variance(
    values: np.ndarray, texels: Texels, *, charts: np.ndarray | None = None
) -> np.ndarray:
    """Estimated noise variance of per-texel ``values (n, ...)`` (float64, same shape).

    For spatially independent noise of variance s^2 (Monte Carlo with per-texel random
    streams), a second difference ``x[p-d] - 2 x[p] + x[p+d]`` along a row, column or diagonal
    of one chart has mean square ``6 s^2`` and vanishes on any linear signal. The squared
    second differences are averaged per ``NOISE_TILE`` tile and its 3 x 3 neighbouring tiles
    (an 18 x 18 window) and assigned to the tile's texels; with fewer than
    ``MIN_NOISE_SAMPLES`` differences the chart's mean is used, and charts too thin for any
    (e.g. 2 x 2 texels) get 0. The mean counts heavy-tailed Monte Carlo outliers (fireflies)
    as noise, as it should, but also the curvature of the signal (shadow edges, hotspots), so
    it is capped at ``ROBUST_CAP`` times the same window's median-based estimate (tile medians
    divided by the chi-square(1) median, i.e. exact for Gaussian noise).
    """
    values = np.asarray(values)
    n = len(texels)
    if len(values) != n:
        raise InputError(f"{len(values)} values for {n} texels")
    charts = _check_charts(charts, n)
    flat = values.reshape(n, -1)
    out = np.zeros(flat.shape, np.float64)
    for c in np.unique(charts):
        sel = np.nonzero(charts == c)[0]
        cv = _Canvas(texels.xy[sel], pad=1, min_crop=1, block=1)
        out[sel] = cv.gather(canvas_noise(cv.image(flat[sel], fill=False), cv.mask))
    return out.reshape(values.shape)


def _check_charts(charts, n: int) -> np.ndarray:
    charts = np.zeros(n, np.int64) if charts is None else np.asarray(charts)
    if charts.shape != (n,):
        raise InputError(f"charts must have shape ({n},), got {charts.shape}")
    return charts


# --------------------------------------------------------------------------------------------
# public


def denoise_sh(
    sh: np.ndarray,
    texels: Texels,
    *,
    charts: np.ndarray | None = None,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    filter: str = "RTLightmap",
    quality: str = "high",
    variance: np.ndarray | None = None,
    blend: bool = True,
    variance_bound: bool = False,
    variance_pool: int = 0,
    mosaic: bool = True,
) -> np.ndarray:
    """Denoised copy of radiance SH ``(n, 3, 9)`` (float32), chart by chart.

    charts : (n,) chart id per texel (``chart_ids(mesh)[texels.triangle]``); None = one chart.
    albedo, normal : (n, 3) guides for ``filter="RT"`` (ignored by RTLightmap, which takes
        none); normals in world space, e.g. ``texels.frame[:, 2]``.
    variance : noise variance of ``sh``, broadcastable to (n, 3, 9) (e.g. the integrator's
        per-texel sample variance divided by the sample count); None: :func:`noise_variance`.
    blend : False returns OIDN's output as it is (no noise-weighted blend; for comparisons).
    variance_pool : average ``variance`` over the chart's texels within this Chebyshev radius
        first (1: 3 x 3), for per-texel estimates with few degrees of freedom (the
        integrator's two-halves estimate has one).
    variance_bound : ``variance`` is an upper bound of the noise (the integrator's, from
        :func:`integrator_iz_variance`): each texel uses the smaller of it and the
        second-difference estimate (taken again after OIDN without the texels where the
        denoised image curves: :func:`_noise_off_curvature`), so neither an edge (which
        inflates the estimate) nor the bound's slack lets the denoiser change signal, the
        blend's gain is
        ``VARIANCE_BOUND_GAIN`` and edges are judged texel by texel; each chart's summed c10
        per channel is then kept equal to the input's (:func:`keep_chart_energy`), and so is
        each ring's from the chart border over all denoised charts (``ENERGY_DEPTH``).
    mosaic : the charts' canvases are denoised as tiles of a few mosaic images, one OIDN run
        per image and coefficient (:func:`usdahd.bake.mosaic.run`); False runs OIDN on each chart's
        canvas alone (the reference the mosaic is measured against).
    Charts whose variance is 0 everywhere (noise free, or too small to estimate) are
    returned unchanged without running OIDN.
    Raises UsageError if pyoidn is not installed or an option is unknown, InputError on
    arrays of the wrong shape or non-finite SH.
    """
    (out,) = denoise_records(
        [dict(sh=sh, texels=texels, charts=charts, albedo=albedo, normal=normal,
              variance=variance)],
        filter=filter, quality=quality, blend=blend, variance_bound=variance_bound,
        variance_pool=variance_pool, mosaic=mosaic,
    )  # fmt: skip
    return out


class _Chart:
    """One chart's state between its noise estimate, OIDN and its blend."""

    def __init__(self, record, sel, cv, x, var, groups, images, guides, depth=None,
                 ratios=None, wv=None):  # fmt: skip
        self.record, self.sel, self.cv, self.x, self.var = record, sel, cv, x, var
        #: the chart's box alone (_Canvas.work): the noise estimate's and the blend's canvas
        self.wv = cv.work() if wv is None else wv
        self.groups, self.images, self.guides = groups, images, guides
        #: (m,) ring of each texel from the chart's border (border_depth), for keep_class_energy
        self.depth = depth
        #: (m, 3, 7) denoised directional ratios (DIRECTIONAL_OIDN False), else None
        self.ratios = ratios


def denoise_records(
    records: list[dict],
    *,
    filter: str = "RTLightmap",
    quality: str = "high",
    blend: bool = True,
    variance_bound: bool = False,
    variance_pool: int = 0,
    mosaic: bool = True,
    inplace: bool = False,
) -> list[np.ndarray]:
    """:func:`denoise_sh` of several records at once (e.g. every prim of a bake), their charts
    sharing OIDN runs: each record a dict with ``sh`` and ``texels`` and optionally
    ``charts``, ``albedo``, ``normal``, ``variance`` (as :func:`denoise_sh`'s arguments).
    Returns the denoised SH (float32) of each record, in order. Charts are gathered until
    their canvases hold ``MOSAIC_PIXELS`` pixels, then denoised together (bounded memory).
    ``inplace``: a record's ``sh`` that is a writable float32 array receives its result (and is
    returned) instead of a copy; safe because each texel's input is read (its chart prepared)
    before its chart's output is written, and charts are disjoint (a bake: no second copy of
    every SH, 108 bytes per texel)."""
    if filter not in FILTERS:
        raise UsageError(f"unknown denoise filter {filter!r}; use one of {FILTERS}")
    if quality not in ("high", "balanced", "fast"):
        raise UsageError(f"unknown denoise quality {quality!r}")
    checked = [_check_record(r) for r in records]  # every record before any work
    outs = [
        sh if inplace and sh.dtype == np.float32 and sh.flags.writeable
        else sh.astype(np.float32, copy=True)
        for sh, *_ in checked
    ]  # fmt: skip
    den = None
    batch: list[_Chart] = []
    pixels = 0
    pool = _chart_pool(sum(len(c[0]) for c in checked))
    rings = blend and variance_bound  # I_z kept per ring class of each record (ENERGY_DEPTH)
    # per record: (n,) ring of each denoised texel (-1: chart not denoised), the input's sums
    depths = [np.full(len(c[1]), -1, np.int8) if rings else None for c in checked]
    sums_in = [np.zeros((ENERGY_DEPTH + 1, 3)) for _ in checked]
    try:

        def tasks():
            for i, (_, _, charts, *_) in enumerate(checked):
                for c in np.unique(charts):
                    yield i, np.nonzero(charts == c)[0]

        def prepare(task):
            i, sel = task
            sh, texels, _, albedo, normal, variance = checked[i]
            return _prepare_chart(
                i, sel, sh, texels, albedo, normal, variance, filter, blend, variance_bound,
                variance_pool,
            )  # fmt: skip

        # on CHART_THREADS threads (the kernels and numpy release the GIL), taken in order
        # across records (a record's one big chart beside the next record's small ones); at
        # most CHART_THREADS charts prepared ahead of the batch, so memory stays one batch's
        for chart in _in_order(pool, prepare, tasks(), CHART_THREADS):
            if chart is None:
                continue  # noise free (or too small to tell): nothing to remove
            i = chart.record
            if rings:
                depths[i][chart.sel] = chart.depth
                sums_in[i] += class_sums(chart.x, chart.depth, ENERGY_DEPTH + 1)
            batch.append(chart)
            pixels += chart.cv.shape[0] * chart.cv.shape[1]
            if pixels >= MOSAIC_PIXELS:
                den = den or _Denoiser.take(quality)
                _finish(den, batch, outs, filter, blend, variance_bound, mosaic, pool)
                batch, pixels = [], 0
        if batch:
            den = den or _Denoiser.take(quality)
            _finish(den, batch, outs, filter, blend, variance_bound, mosaic, pool)
        if rings:
            for out, depth, s_in in zip(outs, depths, sums_in, strict=True):
                _keep_ring_energy(out, depth, s_in)
    finally:
        if den is not None:
            den.close()
        if pool is not None:
            pool.shutdown()
    return outs


def _keep_ring_energy(out: np.ndarray, depth: np.ndarray, s_in: np.ndarray) -> None:
    """:func:`~usdahd.bake.blend.keep_class_energy` of a record's denoised texels (``depth``
    >= 0, their ring) in place, in blocks of texels (no copy of a large record's SH)."""
    done = np.nonzero(depth >= 0)[0]
    if not len(done):
        return
    blocks = [done[a : a + _BLEND_BLOCK] for a in range(0, len(done), _BLEND_BLOCK)]
    s_out = sum(class_sums(out[b], depth[b], len(s_in)) for b in blocks)
    scale = class_scale(s_in, s_out)
    for b in blocks:
        out[b] *= scale[depth[b].astype(np.intp)][:, :, None].astype(out.dtype)


def _chart_pool(texels: int):
    """Threads for the charts' noise estimates and blends of ``texels`` texels in all (None:
    the calling thread, for one thread or fewer than CHART_THREADS_MIN_TEXELS texels): each
    chart's work is its own (disjoint texels, deterministic), so the results are the same in
    any order; OIDN's runs stay on the calling thread (OIDN uses every core itself)."""
    if CHART_THREADS <= 1 or texels < CHART_THREADS_MIN_TEXELS:
        return None
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(CHART_THREADS, thread_name_prefix="usdahd-denoise")


def _check_record(r: dict):
    texels = r["texels"]
    sh = np.asarray(r["sh"])
    n = len(texels)
    if sh.shape != (n, 3, 9):
        raise InputError(f"denoise_sh needs SH of shape ({n}, 3, 9), got {sh.shape}")
    if not np.isfinite(sh).all():
        raise InputError("denoise_sh got non-finite SH coefficients")
    charts = _check_charts(r.get("charts"), n)
    variance = r.get("variance")
    if variance is not None:
        try:
            # kept in its own float type (a bake passes float32: half the memory of every
            # record's variance held through the denoise); charts convert their own share
            variance = np.asarray(variance)
            if not np.issubdtype(variance.dtype, np.floating):
                variance = variance.astype(np.float64)
            variance = np.broadcast_to(variance, sh.shape)
        except ValueError:
            raise InputError(f"variance of shape {np.shape(variance)} does not fit SH "
                             f"{sh.shape}") from None  # fmt: skip
    return sh, texels, charts, r.get("albedo"), r.get("normal"), variance


def _prepare_chart(
    i, sel, sh, texels, albedo, normal, variance, filter, blend, variance_bound, variance_pool
) -> _Chart | None:
    """A chart's canvas, noise variance and OIDN input images; None when it has no noise."""
    x = sh[sel].astype(np.float64)  # (m, 3, 9)
    cv = _Canvas(texels.xy[sel])
    wv = cv.work()  # the box alone: noise, pooling and blend need no OIDN context
    groups = _coefficient_groups(cv.shape)  # canvases of bounded size
    vsel = None
    if variance is not None:
        # a variance shared by the 9 coefficients (sh_variance's, broadcast: stride 0) is
        # pooled once, not 9 times
        v = variance[sel, :, :1] if variance.strides[-1] == 0 else variance[sel]
        vsel = np.broadcast_to(_pooled(wv, v, variance_pool), x.shape)
    if variance is None or variance_bound:
        hdr_only = variance is not None and not DIRECTIONAL_NOISE_ESTIMATE
        var = vsel.copy() if hdr_only else np.empty_like(x)
        for g in _estimated_groups(groups, hdr_only):
            noise = canvas_noise(wv.image(_channels(x, g), fill=False), wv.mask)
            var[:, :, g] = wv.gather(noise).reshape(len(sel), 3, len(g))
        if variance is not None:
            var = np.minimum(var, vsel)
    else:
        var = vsel
    if blend and not (var > 0).any():
        return None
    guides = {}
    if filter == "RT":
        if albedo is not None:
            guides["albedo"] = np.clip(cv.image(np.asarray(albedo)[sel]), 0.0, 1.0)
        if normal is not None:
            guides["normal"] = np.clip(cv.image(np.asarray(normal)[sel]), -1.0, 1.0)
    # every OIDN input canvas from one fill per group (dilation and mirroring act on each
    # channel alone: the same values as one canvas per coefficient, a ninth of the calls)
    filled = {}
    for g in groups if DIRECTIONAL_OIDN else [np.array(_HDR_COEFFS)]:
        img = cv.image(_channels(x, g))
        for j, k in enumerate(g):
            filled[int(k)] = img[:, :, j :: len(g)]
    images = {}
    c00 = None
    for k in _HDR_COEFFS:
        band = np.maximum(filled.pop(k), 0.0)
        c00 = band if k == 0 else c00
        images[k] = band
    ratios = None
    if DIRECTIONAL_OIDN:
        safe = np.where(c00 > 0, c00, 1.0)
        for k in RATIO_COEFFS:
            ratio = np.where(c00 > 0, filled.pop(k) / (BAND_BOUND[k] * safe), 0.0)
            ratio = np.clip(ratio, -1.0, 1.0)
            images[k] = ratio if filter == "RTLightmap" else 0.5 * (ratio + 1.0)
    else:
        ratios = _pooled(wv, directional_ratios(x), DIRECTIONAL_RADIUS)
    depth = None
    if blend and variance_bound:
        depth = wv.gather(border_depth(wv.mask, ENERGY_DEPTH))
    return _Chart(i, sel, cv, x, var, groups, images, guides, depth, ratios, wv)


def directional_ratios(x: np.ndarray) -> np.ndarray:
    """(m, 3, 7) float64 ratios c_lm / (sqrt(2l + 1) c00) of the directional coefficients
    (``RATIO_COEFFS``) of SH ``x (m, 3, 9)``, clipped to [-1, 1] (the bound of a non-negative
    radiance); 0 where c00 <= 0."""
    x = np.asarray(x, np.float64)
    c00 = np.maximum(x[:, :, :1], 0.0)
    safe = np.where(c00 > 0, c00, 1.0)
    r = x[:, :, list(RATIO_COEFFS)] / (BAND_BOUND[list(RATIO_COEFFS)] * safe)
    return np.clip(np.where(c00 > 0, r, 0.0), -1.0, 1.0)


def _pass_kind(k: int, filter: str) -> dict:
    """OIDN settings of coefficient k's run."""
    if k in _HDR_COEFFS:
        return dict(filter_type=filter, hdr=True)
    if filter == "RTLightmap":
        return dict(filter_type=filter, directional=True)
    return dict(filter_type=filter, hdr=False)


def _finish(
    den, batch: list[_Chart], outs, filter, blend, variance_bound, mosaic, pool=None
) -> None:
    """OIDN on every chart of ``batch`` (one mosaic per coefficient, or chart by chart), then
    each chart's blend, written into ``outs`` (on ``pool``'s threads when given)."""
    den_out: list[dict] = [{} for _ in batch]
    # one layout for the HDR runs, one for the directional ones (computed once, not per run)
    fills = {"hdr": HDR_CROP, "dir": DIRECTIONAL_FILL}
    layouts = {"hdr": plan_mosaic(batch, cropped=HDR_CROP, pad=HDR_CROP_PAD)} if mosaic else {}
    if mosaic and DIRECTIONAL_OIDN:
        layouts["dir"] = plan_mosaic(batch, cropped=DIRECTIONAL_CROP)
    for k in (*_HDR_COEFFS, *(RATIO_COEFFS if DIRECTIONAL_OIDN else ())):
        kind = _pass_kind(k, filter)
        use_guides = k in _HDR_COEFFS or filter == "RT"
        if mosaic:
            runs = "hdr" if k in _HDR_COEFFS else "dir"
            res = run_mosaic(den, batch, k, kind, use_guides, layouts[runs], fill=fills[runs])
        else:
            res = [
                den.run(ch.images[k], **kind, **(ch.guides if use_guides else {})) for ch in batch
            ]
        for store, r, ch in zip(den_out, res, batch, strict=True):
            store[k] = r
            ch.images[k] = None  # its input canvas is done with (holds the peak at ~1 copy)

    def finish_chart(ch, store):
        d = _chart_output(ch, store, filter)
        store.clear()  # the canvases are done with: free them chart by chart (peak memory)
        ch.images = ch.guides = ch.ratios = None
        x, var, cv, groups = ch.x, ch.var, ch.wv, ch.groups  # the box: no OIDN context
        ch.x = ch.var = None  # held by the locals only from here: freed with them
        if blend and variance_bound:
            est = _estimated_groups(groups, not DIRECTIONAL_NOISE_ESTIMATE)
            var = np.minimum(var, _noise_off_curvature(cv, x, d, var, groups, est))
        if blend:
            gain = VARIANCE_BOUND_GAIN if variance_bound else BLEND_GAIN
            d = blend_chart(x, d, var, cv.ly, cv.lx, cv.mask, gain=gain, edges=variance_bound,
                            out=d)  # fmt: skip
            if variance_bound:
                d = keep_chart_energy(x, d)
        outs[ch.record][ch.sel] = d.astype(np.float32)  # charts are disjoint: no race

    if pool is None or len(batch) < 2:
        for ch, store in zip(batch, den_out, strict=True):
            finish_chart(ch, store)
        return
    # every chart to the pool at once: a thread that finishes a small chart takes the next
    # (no barrier per window), and the pool's CHART_THREADS threads bound the blend
    # temporaries held at once
    list(pool.map(finish_chart, batch, den_out))


def _in_order(pool, fn, items, ahead: int):
    """``fn(item)`` of each of ``items`` on ``pool``'s threads (in the calling thread when
    None), yielded in order, with at most ``ahead`` items submitted beyond the one awaited."""
    if pool is None:
        yield from map(fn, items)
        return
    from collections import deque

    queued = deque()
    for item in items:
        queued.append(pool.submit(fn, item))
        if len(queued) > ahead:
            yield queued.popleft().result()
    while queued:
        yield queued.popleft().result()


def _chart_output(ch: _Chart, res: dict, filter: str) -> np.ndarray:
    """OIDN output (m, 3, 9) of one chart from its denoised canvases ``res`` (k -> image)."""
    cv = ch.cv
    out = np.zeros((len(ch.sel), 3, 9))
    for k in _HDR_COEFFS:
        out[:, :, k] = np.maximum(cv.gather(res[k]), 0.0)
    for j, k in enumerate(RATIO_COEFFS):
        if ch.ratios is not None:
            r = ch.ratios[:, :, j]
        else:
            r = cv.gather(res[k] if filter == "RTLightmap" else res[k] * 2.0 - 1.0)
        out[:, :, k] = np.clip(r, -1.0, 1.0) * BAND_BOUND[k] * out[:, :, 0]
    return out


def _curved_texels(cv: _Canvas, d: np.ndarray, var: np.ndarray) -> np.ndarray:
    """(h, w) bool: chart texels where the denoised SH ``d (m, 3, 9)`` has a squared second
    difference (any direction and channel of c00 or c10) above CURVATURE_CONTRAST x 6 ``var``
    (m, 3, 9), the squared second difference of pure noise of that variance. The directional
    coefficients are not asked (their blend is judged texel by texel anyway): asked, their
    curvature took texels out of the noise estimate of c00 and c10 too, and I_z was
    denoised less (floor_lamp 32^2, 16 spp: I_z error vs a 4096-spp bake 2.41 % ->
    2.14 %, 64 spp 1.01 -> 0.94 %; docs/time-to-quality.md)."""
    g = np.array(_HDR_COEFFS)
    factor = CURVATURE_CONTRAST * 6.0
    return bends(_channels(d, g), _channels(var, g), cv.ly, cv.lx, cv.shape, factor)


def _estimated_groups(groups: list[np.ndarray], hdr_only: bool) -> list[np.ndarray]:
    """The coefficient groups whose second-difference noise is estimated: all, or with
    ``hdr_only`` c00 and c10 alone (DIRECTIONAL_NOISE_ESTIMATE False)."""
    return [np.array(_HDR_COEFFS)] if hdr_only else groups


def _noise_off_curvature(
    cv: _Canvas, x: np.ndarray, d: np.ndarray, var: np.ndarray, groups, estimated=None
) -> np.ndarray:
    """(m, 3, 9) second-difference noise variance of the chart's input ``x (m, 3, 9)`` from
    the texels where the denoised ``d`` does not curve (:func:`_curved_texels` with ``var``),
    for the coefficients of ``estimated`` (default ``groups``); +inf for the others."""
    support = cv.mask & ~_curved_texels(cv, d, var)
    out = np.full_like(x, np.inf)
    for g in groups if estimated is None else estimated:
        noise = canvas_noise(cv.image(_channels(x, g), fill=False), cv.mask, support=support)
        out[:, :, g] = cv.gather(noise).reshape(len(x), 3, len(g))
    return out


def _coefficient_groups(shape: tuple[int, int]) -> list[np.ndarray]:
    """The 9 SH coefficient indices in groups whose (h, w, 3 x group) canvases stay within
    ``_WORK_ELEMENTS`` (all 9 at once for charts up to ~385 x 385 texels)."""
    per = int(np.clip(_WORK_ELEMENTS // (shape[0] * shape[1] * 3), 1, 9))
    return [np.arange(k, min(9, k + per)) for k in range(0, 9, per)]


def _channels(v: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(m, 3 x len(g)) channel-major columns of coefficients ``g`` of ``v (m, 3, 9)``."""
    return v[:, :, g].reshape(len(v), -1)


def _pooled(cv: _Canvas, v: np.ndarray, radius: int) -> np.ndarray:
    """Per-texel ``v (m, 3, 9)`` averaged over the chart texels within ``radius`` (Chebyshev)
    of each texel (:func:`usdahd.numerics.windows.box_mean_texels`: the chart's canvas,
    float32 as its images); ``v`` itself for radius 0."""
    if radius <= 0:
        return np.asarray(v, np.float64)
    flat = v.reshape(len(v), -1)
    return box_mean_texels(flat, cv.ly, cv.lx, cv.shape, radius).reshape(v.shape)
