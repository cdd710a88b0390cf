"""OIDN denoising of baked SH (usdahd.bake.denoise): exactness on noise-free fields (chart
borders and corners included), error reduction on noisy fields, chart isolation, noise
estimate, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd.bake import blend, canvas, denoise, mosaic
from usdahd.bake import texels as tx
from usdahd.errors import InputError, UsageError
from usdahd.numerics import sh

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
RGB = np.array([1.0, 0.6, 0.3])

# Tolerances (reasons)
#: Noise-free input must come back within this relative I_z error, at every texel.
EXACT_IZ = 5e-3
#: "Does not grow" at low noise: the error may rise by at most this factor (the noise
#: estimate and the blend weights are themselves random).
LOW_NOISE_GROWTH = 1.02


def full_quad(res=32):
    """One chart filling the whole image: its borders and corners are the image's."""
    mesh = tx.mesh_from_arrays(QUAD, [[0, 1, 2], [0, 2, 3]], uv=QUAD[:, :2])
    return mesh, tx.rasterize(mesh, (res, res))


def two_chart_plane(res=32):
    """A flat 2 x 1 plane cut into two UV charts along x = 1 (right one rotated in UV)."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    tri = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    p = pts[tri]
    uv = np.zeros((4, 3, 2))
    uv[:2] = np.stack([0.05 + 0.4 * p[:2, ..., 0], 0.1 + 0.4 * p[:2, ..., 1]], -1)
    uv[2:] = np.stack([0.55 + 0.4 * p[2:, ..., 1], 0.1 + 0.4 * (2 - p[2:, ..., 0])], -1)
    mesh = tx.mesh_from_arrays(pts, tri, uv=uv)
    return mesh, tx.rasterize(mesh, (res, res))


def quad_and_sliver(res=32):
    """A big chart and a tiny one (2 x 2 texels) in the same image."""
    pts = np.concatenate([QUAD, QUAD + [2, 0, 0]])
    tri = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    uv = np.concatenate([QUAD[:, :2] * 0.6, 0.8 + QUAD[:, :2] * 0.04])
    mesh = tx.mesh_from_arrays(pts, tri, uv=uv)
    return mesh, tx.rasterize(mesh, (res, res))


MESHES = {"full_quad": full_quad, "two_charts": two_chart_plane, "tiny_chart": quad_and_sliver}


def _hemi_basis():
    """SH (3, 9) of the radiance functions 1, w_x, w_z over the upper hemisphere (exact
    Gauss-Legendre projection; zero below the horizon, as the baker's SH)."""
    dirs, w = sh.hemisphere_quadrature(16)
    f = np.stack([np.ones(len(dirs)), dirs[:, 0], dirs[:, 2]], axis=1)
    return sh.project(f, dirs, w)


def field(t, kind):
    """Clean radiance SH (n, 3, 9) float32 on texels t: 'dome' (uniform sky, I_z = 1 per
    channel times RGB) or 'gradient' (a smooth non-negative radiance a + b w_x + c w_z whose
    a, b, c vary smoothly with position)."""
    basis = _hemi_basis()
    x, y = t.position[:, 0], t.position[:, 1]
    if kind == "dome":
        coef = np.stack([np.ones_like(x), 0 * x, 0 * x], axis=1)
    else:
        a = 1.0 + 0.8 * x + 0.5 * y**2
        coef = np.stack([a, 0.3 * a * np.sin(2 * y), 0.4 * a * x], axis=1)
    return (coef @ basis)[:, None, :] * RGB[None, :, None]


def rel_iz_error(out, ref):
    """Per texel and channel |I_z(out) - I_z(ref)| / I_z(ref)."""
    return np.abs(sh.iz(out) - sh.iz(ref)) / sh.iz(ref)


def rms_iz(out, ref):
    return np.sqrt(np.mean((sh.luminance(sh.iz(out)) - sh.luminance(sh.iz(ref))) ** 2))


def charts_of(mesh, t):
    return tx.chart_ids(mesh)[t.triangle]


@pytest.fixture(autouse=True)
def _need_oidn():
    pytest.importorskip("pyoidn")


# ------------------------------------------------------------------------------ noise free


@pytest.mark.parametrize("mesh_name", list(MESHES))
@pytest.mark.parametrize("kind", ["dome", "gradient"])
def test_noise_free_field_comes_back_unchanged(mesh_name, kind):
    mesh, t = MESHES[mesh_name]()
    clean = field(t, kind).astype(np.float32)
    out = denoise.denoise_sh(clean, t, charts=charts_of(mesh, t))
    assert out.shape == clean.shape and out.dtype == np.float32
    assert rel_iz_error(out, clean).max() < EXACT_IZ  # every texel, corners included


def test_oidn_alone_keeps_uniform_dome_at_image_corners():
    """The cause of the old 2.4 % error: OIDN without context at the chart's (and image's)
    borders. With mirrored padding even the raw network output keeps a constant field."""
    mesh, t = full_quad()
    clean = field(t, "dome").astype(np.float32)
    raw = denoise.denoise_sh(clean, t, charts=charts_of(mesh, t), blend=False)
    err = rel_iz_error(raw, clean)
    assert err.max() < EXACT_IZ
    corners = np.isin(t.xy[:, 0], [0, 31]) & np.isin(t.xy[:, 1], [0, 31])
    assert corners.sum() == 4 and err[corners].max() < EXACT_IZ


# ------------------------------------------------------------------------------ noisy


def noisy_field(t, sigma, seed):
    """Gradient field plus Gaussian noise of relative std ``sigma`` on every coefficient
    (scaled by the texel's own level: Monte Carlo noise grows with radiance)."""
    clean = field(t, "gradient")
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(clean.shape) * sigma * clean[:, :, :1]
    return clean, (clean + noise).astype(np.float32)


@pytest.mark.parametrize("mesh_name", ["full_quad", "two_charts"])
def test_high_noise_error_drops_at_least_2x(mesh_name):
    mesh, t = MESHES[mesh_name]()
    clean, noisy = noisy_field(t, 0.3, seed=1)
    out = denoise.denoise_sh(noisy, t, charts=charts_of(mesh, t))
    before, after = rms_iz(noisy, clean), rms_iz(out, clean)
    assert after < 0.5 * before, (before, after)


@pytest.mark.parametrize("mesh_name", ["full_quad", "two_charts"])
def test_low_noise_error_does_not_grow(mesh_name):
    mesh, t = MESHES[mesh_name]()
    clean, noisy = noisy_field(t, 0.002, seed=2)
    out = denoise.denoise_sh(noisy, t, charts=charts_of(mesh, t))
    before, after = rms_iz(noisy, clean), rms_iz(out, clean)
    assert after <= LOW_NOISE_GROWTH * before, (before, after)


@pytest.mark.parametrize("filter_type", ["RTLightmap", "RT"])
def test_denoise_reduces_noise_per_chart(filter_type):
    mesh, t = two_chart_plane()
    charts = charts_of(mesh, t)
    rng = np.random.default_rng(5)
    clean = np.zeros((len(t), 3, 9), np.float32)
    clean[:, :, 0] = np.where(charts == 0, 1.0, 4.0)[:, None]  # different light per chart
    clean[:, :, 2] = 0.5 * clean[:, :, 0]
    noisy = clean + 0.05 * rng.standard_normal(clean.shape).astype(np.float32) * clean[:, :, :1]
    out = denoise.denoise_sh(
        noisy, t, charts=charts, albedo=np.full((len(t), 3), 0.5), normal=t.frame[:, 2],
        filter=filter_type,
    )  # fmt: skip
    assert out.shape == noisy.shape and np.isfinite(out).all()
    err_before = np.sqrt(((noisy - clean) ** 2).mean())
    err_after = np.sqrt(((out - clean) ** 2).mean())
    assert err_after < 0.7 * err_before
    # no bleeding across the chart border: each chart keeps its own level
    for c, level in ((0, 1.0), (1, 4.0)):
        np.testing.assert_allclose(out[charts == c, :, 0].mean(), level, rtol=0.05)


def test_given_variance_is_used():
    mesh, t = full_quad()
    clean, noisy = noisy_field(t, 0.3, seed=3)
    charts = charts_of(mesh, t)
    # variance 0: nothing is noise, the input comes back as it is (OIDN not even run)
    same = denoise.denoise_sh(noisy, t, charts=charts, variance=0.0)
    np.testing.assert_array_equal(same, noisy)
    # the true variance: as good as the estimate
    var = (0.3 * clean[:, :, :1]) ** 2
    out = denoise.denoise_sh(noisy, t, charts=charts, variance=var)
    assert rms_iz(out, clean) < 0.5 * rms_iz(noisy, clean)


def test_sh_variance_from_the_integrators_iz_variance():
    """var(c10) = var(I_z) / IZ_FROM_L10^2 in luminance, each channel scaled by its share of
    the luminance (c00 of the channel / c00 luminance), the same for every coefficient."""
    x = np.zeros((2, 3, 9))
    x[0, :, 0] = [1.0, 1.0, 1.0]  # grey: every channel's share is 1
    x[1, :, 0] = [2.0, 0.0, 0.0]  # red only: luminance 0.2126 * 2
    var = denoise.sh_variance(x, np.array([0.5, 0.1]))
    assert var.shape == (2, 3, 9)
    np.testing.assert_allclose(var[0], 0.5 / sh.IZ_FROM_L10**2)
    np.testing.assert_allclose(var[1, 0], 0.1 / sh.IZ_FROM_L10**2 / 0.2126**2)
    np.testing.assert_allclose(var[1, 1:], 0.0)


def test_a_variance_bound_takes_the_smaller_of_it_and_the_estimate(monkeypatch):
    """variance_bound=True: an unbounded figure gives the second-difference estimate's result
    (blended with VARIANCE_BOUND_GAIN), then each chart's summed c10 per channel is put back
    to the input's, and so is each ring's from the chart border (border_depth up to
    ENERGY_DEPTH); a zero bound keeps the input (nothing is trusted as noise). With
    DIRECTIONAL_NOISE_ESTIMATE (the directional coefficients estimated too); by default they
    take the bound alone: :func:`test_directional_coefficients_take_the_bound_alone`."""
    mesh, t = full_quad()
    _clean, noisy = noisy_field(t, 0.3, seed=5)
    charts = charts_of(mesh, t)
    monkeypatch.setattr(denoise, "DIRECTIONAL_NOISE_ESTIMATE", True)
    with monkeypatch.context() as m:
        m.setattr(denoise, "BLEND_GAIN", denoise.VARIANCE_BOUND_GAIN)
        est = denoise.denoise_sh(noisy, t, charts=charts)
    loose = denoise.denoise_sh(noisy, t, charts=charts, variance=1e30, variance_bound=True)
    x = noisy.astype(np.float64)
    kept = blend.keep_chart_energy(x, est.astype(np.float64))
    mask = np.zeros((32, 32), bool)
    mask[t.xy[:, 1], t.xy[:, 0]] = True
    rings = blend.border_depth(mask, denoise.ENERGY_DEPTH)[t.xy[:, 1], t.xy[:, 0]]
    assert set(np.unique(rings)) == set(range(denoise.ENERGY_DEPTH + 1))
    kept = blend.keep_class_energy(kept, rings, blend.class_sums(x, rings, len(np.unique(rings))))
    np.testing.assert_allclose(loose, kept, rtol=1e-5, atol=1e-7)
    for ring in np.unique(rings):
        sel = rings == ring
        np.testing.assert_allclose(
            loose[sel, :, 2].sum(axis=0), noisy[sel, :, 2].sum(axis=0), rtol=1e-5
        )
    none = denoise.denoise_sh(noisy, t, charts=charts, variance=0.0, variance_bound=True)
    np.testing.assert_array_equal(none, noisy)


def test_directional_coefficients_take_the_bound_alone(monkeypatch):
    """By default (not DIRECTIONAL_NOISE_ESTIMATE) a bake's directional coefficients are
    blended with the integrator's bound alone: an unbounded one lets their in-chart mean
    through whole (each ratio to the output's c00 is the 3 x 3 chart mean of the input's
    ratios), while c00 and c10 come back as with the estimate, which only they still get."""
    assert not denoise.DIRECTIONAL_NOISE_ESTIMATE
    mesh, t = full_quad()
    _clean, noisy = noisy_field(t, 0.3, seed=5)
    charts = charts_of(mesh, t)
    loose = denoise.denoise_sh(noisy, t, charts=charts, variance=1e30, variance_bound=True)
    monkeypatch.setattr(denoise, "DIRECTIONAL_NOISE_ESTIMATE", True)
    both = denoise.denoise_sh(noisy, t, charts=charts, variance=1e30, variance_bound=True)
    np.testing.assert_array_equal(loose[:, :, [0, 2]], both[:, :, [0, 2]])
    cv = canvas.Canvas(t.xy)
    mean = denoise._pooled(cv, denoise.directional_ratios(noisy), denoise.DIRECTIONAL_RADIUS)
    ratio = list(blend.RATIO_COEFFS)
    got = loose[:, :, ratio] / (blend.BAND_BOUND[ratio] * loose[:, :, :1])
    ok = (noisy[:, :, 0] > 0).all(axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(got[ok], np.clip(mean[ok], -1, 1), rtol=1e-4, atol=1e-5)
    assert not np.allclose(loose[:, :, ratio], both[:, :, ratio])  # the estimate held some back


def test_integrator_variance_is_the_smaller_of_its_two_bounds():
    stats = {"iz_variance": np.array([1.0, 2.0, 0.5]),
             "iz_variance_halves": np.array([3.0, 0.25, 0.5])}  # fmt: skip
    np.testing.assert_array_equal(denoise.integrator_iz_variance(stats), [1.0, 0.25, 0.5])
    only = denoise.integrator_iz_variance({"iz_variance": np.array([2.0])})
    np.testing.assert_array_equal(only, [2.0])
    assert denoise.integrator_iz_variance({"rays": 0}) is None  # a refit: no variance


def test_variance_pool_averages_within_the_chart_only():
    """variance_pool=r: each texel gets the mean over the chart texels within Chebyshev radius
    r (the two-halves estimate has one degree of freedom per texel): texels outside the
    chart do not count (a spike on the chart's border), and radius 0 is the identity."""
    mesh, t = two_chart_plane()
    charts = charts_of(mesh, t)
    v = np.zeros((len(t), 3, 9))
    first = np.nonzero(charts == 0)[0]
    spike = first[np.argmax(t.xy[first, 0])]  # on chart 0's right border
    v[spike] = 9.0
    cv = canvas.Canvas(t.xy[first])
    np.testing.assert_array_equal(denoise._pooled(cv, v[first], 0), v[first])
    pooled = denoise._pooled(cv, v[first], 1)
    near = np.max(np.abs(t.xy[first] - t.xy[spike]), axis=1) <= 1
    assert (pooled[~near] == 0).all() and (pooled[near] > 0).all()
    # an interior neighbour of the spike averages 9 texels of which one is the spike
    x, y = t.xy[spike]
    inner = np.nonzero((t.xy[first, 0] == x - 1) & (t.xy[first, 1] == y))[0]
    for i in inner:
        window = np.max(np.abs(t.xy[first] - t.xy[first][i]), axis=1) <= 1
        np.testing.assert_allclose(pooled[i], 9.0 / window.sum(), rtol=1e-6)


def test_coefficient_groups_and_reused_filters_change_nothing(monkeypatch):
    """Speed-ups that must not change a bit: the noise estimate and the blend of all 9
    coefficients in one canvas (vs one coefficient at a time: groups of 1 when the work
    budget is tiny), and an OIDN filter reused for images of one shape (vs a new filter)."""
    mesh, t = two_chart_plane()
    charts = charts_of(mesh, t)
    _, noisy = noisy_field(t, 0.2, seed=3)
    var = np.full(noisy.shape, 1e-3)
    kw = dict(charts=charts, variance=var, variance_bound=True, variance_pool=2)
    batched = denoise.denoise_sh(noisy, t, **kw)
    assert len(denoise._coefficient_groups((64, 64))) == 1
    monkeypatch.setattr(denoise, "_WORK_ELEMENTS", 1)
    assert [len(g) for g in denoise._coefficient_groups((64, 64))] == [1] * 9
    np.testing.assert_array_equal(denoise.denoise_sh(noisy, t, **kw), batched)
    rng = np.random.default_rng(0)
    a, b = (rng.random((40, 40, 3), dtype=np.float32) for _ in range(2))
    reused = denoise._Denoiser("high")
    reused.run(a, filter_type="RTLightmap", directional=True)
    again = reused.run(b, filter_type="RTLightmap", directional=True)
    assert len(reused.filters) == 1
    fresh = denoise._Denoiser("high")
    np.testing.assert_array_equal(again, fresh.run(b, filter_type="RTLightmap", directional=True))
    for side in range(20, 20 + 2 * reused.MAX_FILTERS):  # many shapes: only the last few kept
        reused.run(rng.random((side, 24, 3), dtype=np.float32), filter_type="RTLightmap")
    assert len(reused.filters) == reused.MAX_FILTERS
    np.testing.assert_array_equal(
        reused.run(b, filter_type="RTLightmap", directional=True), again
    )  # an evicted kind is set up anew, with the same output
    reused.close(), fresh.close()


# ------------------------------------------------------------------------------ noise estimate


def test_noise_variance_estimate():
    mesh, t = full_quad(48)
    x, y = t.position[:, 0], t.position[:, 1]
    linear = np.stack([1 + 2 * x - y, 3 * y], axis=1)
    # a linear signal has no second differences: zero noise, up to the float32 rounding of
    # the positions (eps 6e-8 x values <= 3: differences ~1e-7, squares ~1e-14)
    assert denoise.noise_variance(linear, t).max() < 1e-12
    # iid Gaussian noise: the estimate of a tile averages ~400-1300 squared differences with
    # mean 6 s^2, strongly correlated (each noise value enters up to 12 of them): the median
    # over tiles is within 5 %, every tile (64 here, corner ones on the fewest) within 50 %
    s = 0.1
    rng = np.random.default_rng(7)
    est = denoise.noise_variance(linear + s * rng.standard_normal(linear.shape), t)
    assert est.shape == linear.shape
    np.testing.assert_allclose(np.median(est), s * s, rtol=0.05)
    assert np.all(np.abs(est / (s * s) - 1) < 0.5)
    # a chart too small for any second difference: no estimate (0), so it is left alone
    mesh, t = quad_and_sliver()
    charts = charts_of(mesh, t)
    est = denoise.noise_variance(rng.standard_normal((len(t), 2)), t, charts=charts)
    small = np.bincount(charts).argmin()
    assert np.bincount(charts)[small] <= 4 and (est[charts == small] == 0).all()
    assert (est[charts != small] > 0).all()


def test_noise_estimate_leaves_out_where_the_denoised_image_curves():
    """Beside a sharp shadow the second-difference estimate counts the edge's curvature as
    noise (capped at ROBUST_CAP x the robust one); without the texels where the denoised
    image curves it measures the input's real noise there, and a firefly OIDN removed still
    counts as noise. A 32 x 32 chart, a staircase shadow edge (1 -> 0.35), iid noise of 1 %;
    the noise-free image stands in for OIDN's output, the given bound is 16x too high."""
    n, s = 32, 0.01
    yy, xx = np.mgrid[0:n, 0:n]
    cv = canvas.Canvas(np.stack([xx.ravel(), yy.ravel()], axis=1))
    dist = (20 - (xx + yy // 2)).ravel()  # texels from the edge, > 0 on the lit side
    clean = np.where(dist > 0, 1.0, 0.35)[:, None, None] * np.ones((1, 3, 9))
    x = clean + s * np.random.default_rng(5).standard_normal(clean.shape)
    groups = denoise._coefficient_groups(cv.shape)
    bound = np.full(x.shape, 16 * s * s)
    img = cv.image(x.reshape(len(x), -1), fill=False)
    plain = cv.gather(denoise.canvas_noise(img, cv.mask)).reshape(x.shape)
    off = denoise._noise_off_curvature(cv, x, clean, bound, groups)
    near = (dist >= 2) & (dist <= 5)
    assert np.median(plain[near]) > 3 * s * s  # the edge inflates it
    # ~300 squared differences per window, correlated: within 30 % (measured 0.95-1.05)
    np.testing.assert_allclose(np.median(off[near]), s * s, rtol=0.3)
    assert off[near].max() < 2 * s * s
    firefly = np.nonzero((dist == 10) & (yy.ravel() == 16))[0][0]
    x[firefly] += 0.2
    hot = denoise._noise_off_curvature(cv, x, clean, bound, groups)
    assert hot[firefly].min() > 2 * off[firefly].max()


def test_denoised_sh_stays_a_non_negative_radiance():
    """|c_lm| <= sqrt(2l+1) c00 holds for every non-negative radiance, and for a Monte Carlo
    estimate of one (each sample's basis values obey it). The blend keeps it: a directional
    coefficient is blended as its ratio to c00, whose weight may differ from its own.
    Input: per texel 4 random directions of the upper hemisphere with random weights."""
    mesh, t = full_quad()
    rng = np.random.default_rng(11)
    n, k = len(t), 4
    z = rng.random((n, k))
    phi = 2 * np.pi * rng.random((n, k))
    r = np.sqrt(1 - z * z)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    wts = rng.exponential(size=(n, k, 3)) * (1 + t.position[:, :1, None])
    x = np.einsum("nkc,nki->nci", wts, sh.basis(dirs)) / k
    bound = np.sqrt(2.0 * np.array([0, 1, 1, 1, 2, 2, 2, 2, 2]) + 1.0)
    assert (np.abs(x) <= bound * x[:, :, :1] * (1 + 1e-9)).all()
    iz_var = np.full(n, np.var(sh.luminance(sh.iz(x))))  # a loose bound, as the integrator's
    out = denoise.denoise_sh(
        x.astype(np.float32), t, charts=charts_of(mesh, t),
        variance=denoise.sh_variance(x, iz_var), variance_bound=True, variance_pool=2,
    )  # fmt: skip
    assert np.abs(out - x).max() > 0.1 * np.abs(x).max()  # it did denoise
    assert (np.abs(out) <= bound * out[:, :, :1] * (1 + 1e-5) + 1e-7).all()


def test_directional_coefficients_of_a_regression_like_input_are_not_made_worse():
    """The integrator's regression estimator adds zero-mean noise to every coefficient, so
    where c00 is small by chance a ratio c_lm / c00 is beyond sqrt(2l+1) (floor_lamp 32^2,
    16 spp: 54 of 5,184 texel channels). Such a ratio times a denoised c00 was a spike: the
    blended L2 coefficients came out with 2-4x the input's error. Input: one valid radiance
    (a sky-like lobe) on the whole chart, Gaussian noise of 40 % of c00 on every coefficient.
    The output keeps the bound (the unclipped blend broke it here) and each directional
    coefficient's error is at most the input's."""
    mesh, t = full_quad()
    rng = np.random.default_rng(5)
    n = len(t)
    dirs = sh.fibonacci_sphere(64, hemisphere=True)
    lobe = (0.2 + dirs[:, 2:3] ** 4) * np.array([1.0, 0.9, 0.7])  # (64, 3) radiance
    truth = sh.project(lobe, dirs, np.full(64, 2 * np.pi / 64))  # (3, 9)
    x = truth + 0.4 * truth[:, :1] * rng.standard_normal((n, 3, 9))
    bound = np.sqrt(2.0 * np.array([0, 1, 1, 1, 2, 2, 2, 2, 2]) + 1.0)
    beyond = np.abs(x) > bound * np.maximum(x[:, :, :1], 0)
    assert beyond[:, :, 1:].any(axis=(1, 2)).mean() > 0.01  # as a small-c00 texel has
    var = np.broadcast_to((0.4 * truth[:, :1]) ** 2, x.shape)
    out = denoise.denoise_sh(x.astype(np.float32), t, charts=charts_of(mesh, t), variance=var)
    ok = x[:, 0, 0] > 0.3 * truth[0, 0]  # texels whose c00 stayed positive, for the bound
    lim = bound * out[:, :, :1] * (1 + 1e-5) + 1e-7
    assert (np.abs(out[ok]) <= lim[ok]).all()
    for k in (1, 3, 4, 5, 6, 7, 8):
        err_in = np.sqrt(np.mean((x[:, :, k] - truth[:, k]) ** 2))
        err_out = np.sqrt(np.mean((out[:, :, k] - truth[:, k]) ** 2))
        assert err_out <= err_in, (k, err_out, err_in)


def test_border_depth_and_class_energy():
    """border_depth: each texel's ring from the mask's border (8-neighbourhood), capped;
    keep_class_energy: each class's summed c10 per channel put back to the given sums."""
    mask = np.zeros((7, 9), bool)
    mask[1:6, 1:8] = True  # a 5 x 7 chart
    mask[3, 8] = True  # a one-texel bump on its right side
    depth = blend.border_depth(mask, 5)
    expected = np.full((7, 9), -1)
    expected[1:6, 1:8] = 0
    expected[2:5, 2:7] = 1
    expected[3, 3:6] = 2
    expected[3, 8] = 0
    expected[3, 7] = 0  # its right neighbour is in the mask, its diagonal ones are not
    np.testing.assert_array_equal(depth, expected)
    np.testing.assert_array_equal(blend.border_depth(mask, 1), np.minimum(expected, 1))
    rng = np.random.default_rng(3)
    x = rng.uniform(0.5, 1.5, (mask.sum(), 3, 9))
    d = x * rng.uniform(0.8, 1.2, (mask.sum(), 3, 1))
    classes = depth[mask]
    sums = blend.class_sums(x, classes, 3)
    np.testing.assert_allclose(sums[2], x[classes == 2, :, 2].sum(axis=0))
    out = blend.keep_class_energy(d.copy(), classes, sums)
    np.testing.assert_allclose(blend.class_sums(out, classes, 3), sums)
    for c in range(3):  # one factor per class and channel, on every coefficient
        ratio = out[classes == c] / d[classes == c]
        np.testing.assert_allclose(ratio, np.broadcast_to(ratio[:1, :, :1], ratio.shape))


def test_blend_keeps_an_unlit_texel_free_of_direction():
    """blend_sh: where the input's c00 is 0 (an unlit, noise-free texel) and the denoised one
    is not, the texel keeps c00 = 0 (weight 0) and so gets no directional coefficient either,
    whatever the directional weights; a lit texel's directional coefficients stay within the
    band bound of its blended c00."""
    x = np.zeros((2, 3, 9))
    d = np.zeros((2, 3, 9))
    d[:, :, 0], d[:, :, 1], d[:, :, 4] = 1.0, 0.5, -0.8  # the neighbours' light, denoised
    x[1, :, 0], x[1, :, 1] = 2.0, 0.1  # texel 1 lit
    w = np.ones((2, 3, 9))
    w[:, :, 0] = w[:, :, 2] = 0.0  # c00 and c10 kept (var 0 for the unlit texel)
    out = blend.blend_sh(x, d, w)
    np.testing.assert_array_equal(out[0], 0.0)
    lim = blend.BAND_BOUND[list(blend.RATIO_COEFFS)] * out[1, :, :1]
    assert (np.abs(out[1][:, list(blend.RATIO_COEFFS)]) <= lim + 1e-12).all()
    np.testing.assert_allclose(out[1, :, 1], 0.5 * 2.0)  # the denoised ratio, times c00


def test_blend_weights():
    mask = np.ones((8, 8), bool)
    x = np.zeros((8, 8, 1))
    var = np.full((8, 8, 1), 0.01)
    # the denoiser changed texels by about the noise: fully trusted
    assert np.allclose(blend.blend_weights(x, x + 0.1, var, mask), 1.0)
    # by much more than the noise: weight var * gain / change^2
    w = blend.blend_weights(x, x + 1.0, var, mask)
    np.testing.assert_allclose(w, blend.BLEND_GAIN * 0.01, rtol=1e-12)
    # pointwise channels: one texel moved by far more than the noise is held back even when
    # its neighbourhood's mean change is small
    spike = x.repeat(2, axis=2)
    spike[4, 4] = 1.0
    w = blend.blend_weights(x.repeat(2, axis=2), spike, var.repeat(2, axis=2), mask,
                              pointwise=[False, True])  # fmt: skip
    assert w[4, 4, 0] == 1.0  # 1 / 25 mean change < 4 var: trusted
    np.testing.assert_allclose(w[4, 4, 1], blend.BLEND_GAIN * 0.01, rtol=1e-12)
    # no noise: never trusted
    assert (blend.blend_weights(x, x + 1.0, 0 * var, mask) == 0).all()


def test_blend_judges_edges_texel_by_texel():
    """edges=True (the integrator's variance): where the denoised image has an edge (squared
    gradient > EDGE_CONTRAST x var), a texel's weight is at most var / (d - x)^2, so a blurred
    one-texel-wide step is held back although its 5 x 5 window's mean change is small;
    flat texels and the plain rule are unchanged."""
    n = 16
    mask = np.ones((n, n), bool)
    var = np.full((n, n, 1), 1e-4)
    x = np.zeros((n, n, 1))
    x[:, n // 2 :] = 1.0  # a sharp step (a sun-shadow edge), noise-free for clarity
    d = x.copy()
    d[:, n // 2 - 1] += 0.05  # the denoiser blurred it by 0.05 on both sides (5 sigma)
    d[:, n // 2] -= 0.05
    d[2:-2, 3] += 0.005  # and moved a flat column by half a sigma
    plain = blend.blend_weights(x, d, var, mask, gain=1.5)
    edge = blend.blend_weights(x, d, var, mask, gain=1.5, edges=True)
    # plain rule: the 5 x 5 mean of (d - x)^2 is 2/5 x 0.05^2 = 1e-3 > 1.5 var: partly trusted
    np.testing.assert_allclose(plain[8, n // 2], 1.5e-4 / 1e-3, rtol=1e-9)
    np.testing.assert_allclose(edge[8, n // 2 - 1 : n // 2 + 1], 1e-4 / 0.05**2, rtol=1e-9)
    np.testing.assert_array_equal(edge[:, :5], plain[:, :5])  # flat: no edge, same weights
    assert (edge[:, :5] == 1.0).all()
    edges = blend.edge_texels(d, mask, var)[..., 0]
    assert edges[1:-1, n // 2 - 1 : n // 2 + 1].all()  # the two texels either side of the step
    # (and the blur's own bend one texel further out, which the denoiser did not move)
    assert not edges[:, : n // 2 - 2].any() and not edges[:, n // 2 + 2 :].any()


def test_blend_edge_rule_leaves_a_soft_penumbra_to_the_window_rule():
    """A soft penumbra is a ramp across many texels: its gradient is many noise deviations per
    texel but it does not bend, so edge_texels (a squared second difference above
    EDGE_CONTRAST x var) leaves it to the window rule, and where the denoiser took 1.5 noise
    deviations of noise out of each texel the denoised value is kept; only the ramp's two
    ends, where it bends by 8 deviations, are edges. (The earlier test, the squared
    gradient, flagged the whole ramp and held each texel back to var / (d - x)^2 = 0.44:
    stretched_boxes' penumbrae, docs/time-to-quality.md.)"""
    n = 24
    mask = np.ones((n, n), bool)
    var = np.full((n, n, 1), 1e-4)  # sigma 0.01
    ramp = np.clip((np.arange(n) - 4) * 0.08, 0.0, 0.96)[None, :, None].repeat(
        n, 0
    )  # 8 sigma a texel
    rng = np.random.default_rng(3)
    x = ramp + 0.015 * rng.choice([-1.0, 1.0], size=ramp.shape)  # the noisy input
    d = ramp  # what a good denoiser returns
    edges = blend.edge_texels(d, mask, var)[..., 0]
    assert edges[:, 4].all() and edges[:, 16].all()  # the ramp's bends
    assert edges.sum() == 2 * n
    grad2 = 0.25 * (d[:, 2:, 0] - d[:, :-2, 0]) ** 2  # what the gradient test measured
    assert (grad2[:, 4:15] > blend.EDGE_CONTRAST * 1e-4).all()  # it flagged the whole ramp
    w_edge = blend.blend_weights(x, d, var, mask, gain=4.0, edges=True)
    w_plain = blend.blend_weights(x, d, var, mask, gain=4.0)
    mid = (slice(None), slice(7, 14))
    np.testing.assert_array_equal(w_edge[mid], w_plain[mid])
    assert (w_edge[mid] == 1.0).all()  # 1.5 sigma moves: trusted (the gradient test: 0.44)


# ------------------------------------------------------------------------------ errors


def test_denoise_errors():
    mesh, t = two_chart_plane(8)
    zeros = np.zeros((len(t), 3, 9))
    with pytest.raises(UsageError, match="unknown denoise filter"):
        denoise.denoise_sh(zeros, t, filter="NLM")
    with pytest.raises(UsageError, match="quality"):
        denoise.denoise_sh(zeros, t, quality="best")
    with pytest.raises(InputError, match="shape"):
        denoise.denoise_sh(np.zeros((len(t), 9)), t)
    with pytest.raises(InputError, match="charts"):
        denoise.denoise_sh(zeros, t, charts=np.zeros(3))
    with pytest.raises(InputError, match="variance"):
        denoise.denoise_sh(zeros, t, variance=np.zeros((2, 5)))
    bad = zeros.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        denoise.denoise_sh(bad, t)
    with pytest.raises(InputError, match="values"):
        denoise.noise_variance(np.zeros(3), t)


@pytest.mark.parametrize(
    "shape,tile", [((23, 31, 5), 8), ((8, 8, 2), 8), ((1, 9, 1), 4), ((40, 17, 27), 6)]
)
def test_tile_stats_kernel_matches_the_numpy_reference(shape, tile):
    """The numba tile statistics of the noise estimate (usdahd/numerics/noise.py) equal the
    numpy reference on a random chart shape (holes, borders, a canvas smaller than a tile):
    counts exactly, means and medians to summation-order rounding (1e-12 relative)."""
    from usdahd.numerics.noise import tile_stats

    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    img = rng.standard_normal(shape) * rng.exponential(size=shape)
    support = rng.random(shape[:2]) < 0.8
    img[~support] = np.nan  # outside the chart: never read
    fast = tile_stats(img, support, tile)
    ref = tile_stats(img, support, tile, backend="numpy")
    for name, a, b in zip(("mean", "median", "count", "chart mean", "chart median", "chart count"),
                          fast, ref):  # fmt: skip
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0, equal_nan=True, err_msg=name)
    # every difference is in exactly one tile
    np.testing.assert_array_equal(fast[2].sum(axis=(0, 1)), fast[5])
    assert (fast[5] > 0).all()
    with pytest.raises(ValueError, match="backend"):
        tile_stats(img, support, tile, backend="cuda")


def test_tile_stats_takes_the_chart_median_only_where_a_needed_tile_falls_back():
    """``need``: the chart-wide median (the fallback of a tile with no well-filled tile
    around it) is computed only when a needed tile has none; else NaN. Both backends."""
    from usdahd.numerics.noise import tile_stats

    rng = np.random.default_rng(3)
    img = rng.standard_normal((24, 30, 3))
    support = np.ones((24, 30), bool)
    support[:, 12:] = False  # tiles of columns 2-4 hold no difference
    full = tile_stats(img, support, 6)
    for backend in ("numba", "numpy"):
        need = np.zeros((4, 5), bool)
        need[:, :2] = True  # the filled tiles: each has a filled neighbour
        out = tile_stats(img, support, 6, backend, need=need, min_count=8)
        assert np.isnan(out[4]).all() and np.isfinite(full[4]).all()
        for a, b in zip(out[:4] + out[5:], full[:4] + full[5:], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-12, equal_nan=True)
        need[0, 4] = True  # two tiles from any filled one: falls back to the chart's
        out = tile_stats(img, support, 6, backend, need=need, min_count=8)
        np.testing.assert_allclose(out[4], full[4], rtol=1e-12)
    with pytest.raises(ValueError, match="need"):
        tile_stats(img, support, 6, need=np.ones((2, 2), bool))


@pytest.mark.parametrize("gain, edges", [(4.0, False), (1.5, True)])
@pytest.mark.parametrize("shape", [(1, 1), (3, 17), (24, 20)])
def test_blend_chart_kernel_is_the_canvas_blend_bit_for_bit(shape, gain, edges, monkeypatch):
    """``blend.blend_chart``'s numba kernel (the bake's) returns the numbers of its numpy
    definition (float32 canvases, ``blend_weights`` per coefficient, ``blend_sh``) bit for
    bit: on a chart with holes, unlit texels (c00 = 0, as beside a shadow), directional
    coefficients beyond the band bound and zero variances (noise-free), in one block of
    channels or one channel per block."""
    rng = np.random.default_rng(shape[0] * 7 + shape[1])
    mask = rng.random(shape) < 0.8
    mask.flat[0] = True
    ly, lx = np.nonzero(mask)
    m = len(ly)
    x = rng.exponential(size=(m, 3, 9)) * 1e2
    x[:, :, 1:] *= rng.uniform(-1.5, 1.5, size=(m, 3, 8))
    x[rng.random(m) < 0.1, :, 0] = 0.0
    d = x + rng.normal(0.0, 20.0, size=x.shape)
    var = rng.exponential(50.0, size=x.shape)
    var[rng.random(x.shape) < 0.05] = 0.0
    ref = blend.blend_chart(x, d, var, ly, lx, mask, gain=gain, edges=edges, backend="numpy")
    fast = blend.blend_chart(x, d, var, ly, lx, mask, gain=gain, edges=edges)
    np.testing.assert_array_equal(fast, ref)
    monkeypatch.setattr(blend, "_WORK_ELEMENTS", 1)
    np.testing.assert_array_equal(blend.blend_chart(x, d, var, ly, lx, mask, gain=gain,
                                                    edges=edges), ref)  # fmt: skip
    # into d itself (the bake's call: no second copy of the chart's SH), both backends
    for backend in ("numba", "numpy"):
        into = d.copy()
        got = blend.blend_chart(x, into, var, ly, lx, mask, gain=gain, edges=edges,
                                backend=backend, out=into)  # fmt: skip
        assert got is into
        np.testing.assert_array_equal(into, ref)
    with pytest.raises(ValueError, match="backend"):
        blend.blend_chart(x, d, var, ly, lx, mask, backend="cuda")
    with pytest.raises(ValueError, match="out must be"):
        blend.blend_chart(x, d, var, ly, lx, mask, out=np.empty((m, 3, 9), np.float32))


def test_second_differences_of_the_row_and_column_only_with_zero_outside():
    """``second_differences(..., directions=2, fill=0.0)`` (the blend's edge rule and the
    curvature test, which sum or take maxima) is the full 4-direction array's first two
    directions with NaN read as 0; the values are (x[p-d] - 2 x[p] + x[p+d])^2."""
    from usdahd.numerics.noise import second_differences

    rng = np.random.default_rng(7)
    img = rng.standard_normal((9, 11, 3))
    support = rng.random((9, 11)) < 0.8
    full = second_differences(img, support)
    two = second_differences(img, support, directions=2, fill=0.0)
    assert full.shape == (9, 11, 4, 3) and two.shape == (9, 11, 2, 3)
    np.testing.assert_array_equal(two, np.nan_to_num(full[:, :, :2]))
    y, x = np.argwhere(support[1:-1, 1:-1] & support[1:-1, :-2] & support[1:-1, 2:])[0] + 1
    np.testing.assert_allclose(two[y, x, 0], (img[y, x - 1] - 2 * img[y, x] + img[y, x + 1]) ** 2)


@pytest.mark.parametrize("w, h", [(1, 1), (5, 9), (12, 12), (13, 40), (30, 3)])
def test_canvas_sides_are_oidn_blocks_with_at_least_pad_context(w, h):
    # OIDN pads every side to a multiple of 16 and is timed by the padded size: the canvas
    # takes that padding as chart context, never less than PAD texels on any side.
    x0, y0 = 7, 3
    xx, yy = np.meshgrid(np.arange(x0, x0 + w), np.arange(y0, y0 + h))
    cv = canvas.Canvas(np.stack([xx.ravel(), yy.ravel()], axis=1))
    rows, cols = cv.shape
    assert rows % mosaic.OIDN_BLOCK == 0 and cols % mosaic.OIDN_BLOCK == 0
    assert min(rows, cols) >= canvas.MIN_CROP
    assert cv.lx.min() >= mosaic.PAD and cols - 1 - cv.lx.max() >= mosaic.PAD
    assert cv.ly.min() >= mosaic.PAD and rows - 1 - cv.ly.max() >= mosaic.PAD
    assert cols < w + 2 * mosaic.PAD + mosaic.OIDN_BLOCK or cols == canvas.MIN_CROP


# ------------------------------------------------------------------------------ mosaics


def test_autoexposure_is_oidns_own():
    """A canvas scaled by our autoexposure and run with inputScale 1 is what OIDN makes of
    the canvas with its own exposure (so a mosaic's tiles each keep their own exposure)."""
    den = denoise._Denoiser("high")
    rng = np.random.default_rng(1)
    for shape, level in [((32, 32), 0.02), ((48, 80), 7.0), ((33, 70), 300.0)]:
        img = (level * rng.random((*shape, 3)) ** 2).astype(np.float32)
        own = den.run(img, filter_type="RTLightmap", hdr=True)
        s = np.float32(mosaic.autoexposure(img))
        ours = den.run(img * s, filter_type="RTLightmap", hdr=True, input_scale=1.0) / s
        np.testing.assert_allclose(ours, own, rtol=0, atol=1e-5 * own.max())
    assert mosaic.autoexposure(np.zeros((16, 16, 3), np.float32)) == 1.0
    den.close()


def test_layout_tiles_do_not_overlap():
    rng = np.random.default_rng(4)
    crops = [(0, int(h), 0, int(w)) for h, w in rng.integers(3, 90, size=(60, 2))]
    gap = mosaic.MOSAIC_GAP
    (H, W), pos = mosaic.layout(crops, gap)
    assert H % mosaic.OIDN_BLOCK == 0 and W % mosaic.OIDN_BLOCK == 0
    used = np.zeros((H, W), int)
    for (y0, y1, x0, x1), (y, x) in zip(crops, pos, strict=True):
        assert y - gap >= 0 and x - gap >= 0
        used[y - gap : y + y1 - y0 + gap, x - gap : x + x1 - x0 + gap] += 1
    assert used.max() == 1
    tiles = sum((y1 - y0 + 2 * gap) * (x1 - x0 + 2 * gap) for y0, y1, x0, x1 in crops)
    assert tiles / (H * W) > 0.6  # shelf packing of tiles sorted by height wastes little


def test_layout_packs_canvases_of_different_heights_tightly():
    """The chart canvases of samples/exterior_sun_sky.usda at 128^2 (16 charts): shelves
    alone left 17 % of the mosaic empty (101,376 pixels for 86,528), and OIDN's time follows
    the mosaic's pixels; the skyline stacks the low tiles into the shelves' gaps (91,392)."""
    sides = [(144, 144)] + [(64, 64)] * 5 + [(96, 48), (96, 48), (48, 48), (96, 48), (96, 48)]
    sides += [(64, 32), (64, 32), (32, 128), (64, 128), (64, 128)]
    crops = [(0, h, 0, w) for h, w in sides]
    (H, W), pos = mosaic.layout(crops, 0)
    tiles = sum(h * w for h, w in sides)
    assert tiles == 86_528 and H * W <= 91_392, (H, W)
    used = np.zeros((H, W), int)
    for (h, w), (y, x) in zip(sides, pos, strict=True):
        used[y : y + h, x : x + w] += 1
    assert used.max() == 1
    top, _ = mosaic._shelves(sides, sorted(range(16), key=lambda i: -sides[i][0]), W)
    assert -(-top // 16) * 16 * W > H * W  # the shelves alone: more pixels at this width


def test_mosaic_matches_chart_by_chart_up_to_oidns_context():
    """One OIDN run per coefficient for every chart of several records (a mosaic of the
    charts' crops, each with its own exposure) against each chart's canvas run alone: the
    same up to the network's response to the other context (docs/time-to-quality.md states
    the bound on the samples); a bright record does not darken or brighten a dim one (the
    exposure is per tile), and noise is removed as well as chart by chart."""
    recs, cleans = [], []
    for k, (make, level) in enumerate([(two_chart_plane, 1.0), (quad_and_sliver, 100.0),
                                      (full_quad, 0.01)]):  # fmt: skip
        mesh, t = make()
        clean, noisy = noisy_field(t, 0.05, seed=10 + k)
        recs.append(dict(sh=noisy * level, texels=t, charts=charts_of(mesh, t)))
        cleans.append(clean * level)
    mos = denoise.denoise_records(recs)
    ref = denoise.denoise_records(recs, mosaic=False)
    for m, r, c, rec in zip(mos, ref, cleans, recs, strict=True):
        assert m.dtype == np.float32 and m.shape == r.shape
        rel = np.abs(sh.iz(m) - sh.iz(r)) / sh.iz(r)
        assert np.sqrt(np.mean(rel**2)) < 0.01 and rel.max() < 0.05, rel.max()
        noisy_err = rms_iz(rec["sh"], c)
        assert rms_iz(m, c) < 0.6 * noisy_err and rms_iz(m, c) < 1.3 * rms_iz(r, c)
    one = denoise.denoise_sh(recs[0]["sh"], recs[0]["texels"], charts=recs[0]["charts"])
    rel = np.abs(sh.iz(one) - sh.iz(mos[0])) / sh.iz(mos[0])
    assert rel.max() < 0.05  # its mosaic with other records' charts: the same bound


def test_chart_threads_change_nothing(monkeypatch):
    """The charts' noise estimates and blends on CHART_THREADS threads (issue 43: they were a
    third of the denoiser's CPU time, on one core): bit for bit the single-threaded result,
    on records of several charts each (charts prepared ahead across records while a batch is
    finished, an odd chart count included), in place too."""
    recs = []
    for k, (make, level) in enumerate([(two_chart_plane, 1.0), (quad_and_sliver, 100.0),
                                      (full_quad, 0.01)]):  # fmt: skip
        mesh, t = make()
        _, noisy = noisy_field(t, 0.05, seed=20 + k)
        var = np.full(noisy.shape, 1e-3 * level**2, np.float32)
        recs.append(dict(sh=noisy * level, texels=t, charts=charts_of(mesh, t), variance=var))
    kw = dict(variance_bound=True, variance_pool=denoise.VARIANCE_POOL)
    assert denoise.CHART_THREADS == 2
    # a small call stays on the calling thread; these records are small: threads all the same
    assert denoise._chart_pool(denoise.CHART_THREADS_MIN_TEXELS - 1) is None
    monkeypatch.setattr(denoise, "CHART_THREADS_MIN_TEXELS", 0)
    pool = denoise._chart_pool(1)
    assert pool is not None
    pool.shutdown()
    threaded = denoise.denoise_records(recs, **kw)
    monkeypatch.setattr(denoise, "MOSAIC_PIXELS", 1)  # a batch per chart: many _finish calls
    per_chart = denoise.denoise_records(recs, **kw)
    monkeypatch.undo()
    monkeypatch.setattr(denoise, "CHART_THREADS", 1)
    assert denoise._chart_pool(10**9) is None
    single = denoise.denoise_records(recs, **kw)
    for a, b in zip(threaded, single, strict=True):
        np.testing.assert_array_equal(a, b)
    monkeypatch.undo()
    monkeypatch.setattr(denoise, "MOSAIC_PIXELS", 1)
    monkeypatch.setattr(denoise, "CHART_THREADS", 1)
    for a, b in zip(per_chart, denoise.denoise_records(recs, **kw), strict=True):
        np.testing.assert_array_equal(a, b)
    monkeypatch.undo()
    copies = [dict(r, sh=np.array(r["sh"], np.float32)) for r in recs]
    inplace = denoise.denoise_records(copies, inplace=True, **kw)
    for a, b, c in zip(inplace, single, copies, strict=True):
        assert a is c["sh"]
        np.testing.assert_array_equal(a, b)


def test_in_order_yields_in_order_with_a_bounded_lookahead():
    """denoise._in_order: results in the items' order however the threads finish, and at
    most ``ahead`` items submitted beyond the one awaited (bounded memory)."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    started, lock = [], threading.Lock()

    def fn(k):
        with lock:
            started.append(k)
        time.sleep(0.002 * (5 - k % 5))  # later items finish first
        return k * k

    with ThreadPoolExecutor(2) as pool:
        got = []
        for r in denoise._in_order(pool, fn, iter(range(12)), 2):
            got.append(r)
            assert len(started) <= len(got) + 2
    assert got == [k * k for k in range(12)]
    assert list(denoise._in_order(None, fn, range(4), 2)) == [0, 1, 4, 9]


def test_denoise_records_checks_every_record_first():
    mesh, t = full_quad(8)
    good = dict(sh=np.zeros((len(t), 3, 9), np.float32), texels=t)
    with pytest.raises(InputError, match="shape"):
        denoise.denoise_records([good, dict(sh=np.zeros((3, 3, 9)), texels=t)])
    assert denoise.denoise_records([]) == []


def test_a_chart_above_the_mosaic_size_is_denoised_alike_and_its_scratch_released(monkeypatch):
    """A chart whose canvas exceeds MOSAIC_PIXELS runs alone with OIDN's scratch capped
    (``maxMemoryMB``) and its filter released right after (OIDN keeps ~600 MB of scratch for a
    1024^2 image while a filter that used it lives): the same output as a normal run."""
    mesh, t = full_quad()
    _, noisy = noisy_field(t, 0.05, seed=3)
    ref = denoise.denoise_sh(noisy, t)
    made = []
    real = denoise._Denoiser

    class Watched(real):
        def __init__(self, quality):
            super().__init__(quality)
            made.append(self)

    monkeypatch.setattr(denoise, "_Denoiser", Watched)
    monkeypatch.setattr(denoise, "MOSAIC_PIXELS", 64)  # every canvas is "large" now
    big = denoise.denoise_sh(noisy, t)
    np.testing.assert_array_equal(big, ref)
    assert made and all(not d.filters for d in made)  # every large run's filter released


def test_denoise_records_in_place_gives_the_same_result():
    """``inplace=True`` (what a bake passes) writes each record's result into its own float32
    SH array, chart after chart: the same values as the copying call, and the same array."""
    recs = []
    for k, make in enumerate((two_chart_plane, quad_and_sliver)):
        mesh, t = make()
        _, noisy = noisy_field(t, 0.05, seed=20 + k)
        recs.append(dict(sh=noisy.astype(np.float32), texels=t, charts=charts_of(mesh, t)))
    ref = denoise.denoise_records([dict(r, sh=r["sh"].copy()) for r in recs])
    inputs = [r["sh"] for r in recs]
    out = denoise.denoise_records(recs, inplace=True)
    for o, r, i in zip(out, ref, inputs, strict=True):
        assert o is i
        np.testing.assert_array_equal(o, r)


#: (height, width) of the 16 chart boxes of samples/exterior_sun_sky.usda at 32^2 (captured
#: from a bake, 2026-12-06): canvases of 24,576 mosaic pixels per OIDN run for 2,950 texels.
EXTERIOR_32_BOXES = [(2, 27), (8, 8), (10, 10), (10, 11), (11, 2), (11, 2), (11, 10), (11, 11)]
EXTERIOR_32_BOXES += [(11, 11), (11, 27), (11, 27), (19, 8), (19, 8), (19, 8), (19, 8), (32, 32)]


def _box_charts(boxes):
    """Charts filling the given (h, w) boxes (as _finish's batch: objects with a .cv)."""
    from types import SimpleNamespace

    out = []
    for h, w in boxes:
        ys, xs = np.mgrid[:h, :w]
        out.append(SimpleNamespace(cv=canvas.Canvas(np.stack([xs.ravel(), ys.ravel()], 1))))
    return out


def test_directional_mosaic_sends_oidn_fewer_pixels_per_texel():
    """The directional runs' mosaic (7 of 9 runs: tiles cropped to the chart's box +
    CROP_PAD, packed on MOSAIC_GRID columns) of exterior_sun_sky's 32^2 charts: <= 17,000
    pixels (16,640 measured) against the canvases' 24,576; every chart keeps CROP_PAD texels
    of context on every side and no two tiles overlap."""
    batch = _box_charts(EXTERIOR_32_BOXES)
    _, (full, _) = mosaic.plan(batch)
    crops, ((H, W), pos) = mosaic.plan(batch, cropped=True)
    assert full[0] * full[1] == 24_576
    assert H * W <= 17_000 and H % mosaic.OIDN_BLOCK == 0 and W % mosaic.OIDN_BLOCK == 0
    used = np.zeros((H, W), int)
    for ch, (y0, y1, x0, x1), (y, x) in zip(batch, crops, pos, strict=True):
        by0, by1, bx0, bx1 = ch.cv.box
        assert by0 - y0 >= mosaic.CROP_PAD and y1 - by1 >= mosaic.CROP_PAD
        assert bx0 - x0 >= mosaic.CROP_PAD and x1 - bx1 >= mosaic.CROP_PAD
        used[y : y + y1 - y0, x : x + x1 - x0] += 1
    assert used.max() == 1


def _three_noisy_records(sigma):
    recs, cleans = [], []
    for k, make in enumerate((two_chart_plane, quad_and_sliver, full_quad)):
        mesh, t = make()
        clean, noisy = noisy_field(t, sigma, seed=30 + k)
        recs.append(dict(sh=noisy, texels=t, charts=charts_of(mesh, t)))
        cleans.append(clean)
    return recs, cleans


def test_directional_mean_leaves_iz_bit_for_bit_and_halves_the_directional_noise(monkeypatch):
    """The directional ratios' in-chart mean (the default, not DIRECTIONAL_OIDN): c00 and c10
    (I_z) come back bit for bit as with OIDN's directional runs, OIDN runs only c00 and c10,
    and the directional coefficients' error on noisy smooth fields (independent noise on
    every coefficient: 0.10 relative) is at most half the input's (2.4-2.7x lower measured;
    OIDN's network 3.4-4.9x here, where the noise is white and the field smooth over the
    whole chart; on baked stages the two are within 10 %: DIRECTIONAL_OIDN's comment)."""
    recs, cleans = _three_noisy_records(0.1)
    assert not denoise.DIRECTIONAL_OIDN
    kinds = []

    class Recording(denoise._Denoiser):
        def run(self, color, **kw):
            kinds.append((kw.get("hdr", False), kw.get("directional", False)))
            return super().run(color, **kw)

    monkeypatch.setattr(denoise, "_Denoiser", Recording)
    mean = denoise.denoise_records(recs)
    assert kinds == [(True, False)] * 2  # one mosaic: c00 and c10
    monkeypatch.setattr(denoise, "DIRECTIONAL_OIDN", True)
    oidn = denoise.denoise_records(recs)
    ratio = list(blend.RATIO_COEFFS)
    for r, m, o, clean in zip(recs, mean, oidn, cleans, strict=True):
        np.testing.assert_array_equal(m[:, :, [0, 2]], o[:, :, [0, 2]])
        before, after = (np.sqrt(np.mean((x[:, :, ratio] - clean[:, :, ratio]) ** 2))
                         for x in (r["sh"], m))  # fmt: skip
        assert after <= 0.5 * before, (before, after)


def test_directional_ratios_are_clipped_and_zero_without_c00():
    x = np.zeros((3, 3, 9))
    x[0, :, 0], x[0, :, 1] = 1.0, 0.5  # ratio 0.5 / sqrt(3)
    x[1, :, 0], x[1, :, 4] = 1.0, 100.0  # beyond the bound: clipped to 1
    x[2, :, 0], x[2, :, 3] = -1.0, 2.0  # c00 <= 0: ratio 0
    r = denoise.directional_ratios(x)
    assert r.shape == (3, 3, 7) and r.dtype == np.float64
    np.testing.assert_allclose(r[0, :, 0], 0.5 / np.sqrt(3.0))
    np.testing.assert_array_equal(r[1, :, 2], 1.0)
    np.testing.assert_array_equal(r[2], 0.0)


def test_directional_crop_leaves_iz_bit_for_bit_and_direction_as_good(monkeypatch):
    """DIRECTIONAL_CROP changes only the directional coefficients' OIDN input: c00 and c10
    (I_z) come back bit for bit, and the directional coefficients' error against the clean
    field stays within 3 % of the uncropped run's (OIDN sees less context only)."""
    monkeypatch.setattr(denoise, "DIRECTIONAL_OIDN", True)  # the crop is of OIDN's runs
    recs, cleans = _three_noisy_records(0.1)
    assert denoise.DIRECTIONAL_CROP
    cropped = denoise.denoise_records(recs)
    monkeypatch.setattr(denoise, "DIRECTIONAL_CROP", False)
    full = denoise.denoise_records(recs)
    ratio = list(blend.RATIO_COEFFS)
    errs = []
    for c, f, clean in zip(cropped, full, cleans, strict=True):
        np.testing.assert_array_equal(c[:, :, [0, 2]], f[:, :, [0, 2]])
        assert not np.array_equal(c[:, :, ratio], f[:, :, ratio])  # the crop did act
        errs.append([np.sqrt(np.mean((o[:, :, ratio] - clean[:, :, ratio]) ** 2)) for o in (c, f)])
    e = np.array(errs)
    assert e[:, 0].sum() < 1.03 * e[:, 1].sum(), e


def test_fill_empty_extends_the_nearest_tile_along_rows_then_columns():
    """mosaic.fill_empty: used pixels unchanged; an empty pixel takes its row's nearest used
    pixel (the left one on a tie); a row with none takes the nearest row that has one."""
    mos = np.zeros((5, 7, 1), np.float32)
    used = np.zeros((5, 7), bool)
    used[1, 1], used[1, 5] = True, True
    used[3, 2:4] = True
    mos[1, 1], mos[1, 5], mos[3, 2], mos[3, 3] = 1.0, 5.0, 2.0, 3.0
    out = mosaic.fill_empty(mos.copy(), used)[..., 0]
    np.testing.assert_array_equal(out[1], [1, 1, 1, 1, 5, 5, 5])  # x=3: tie, the left one
    np.testing.assert_array_equal(out[3], [2, 2, 2, 3, 3, 3, 3])
    np.testing.assert_array_equal(out[0], out[1])  # no used pixel: the nearest row's
    np.testing.assert_array_equal(out[2], out[1])  # rows 1 and 3 equally near: row 1
    np.testing.assert_array_equal(out[4], out[3])
    whole = np.ones((2, 2), bool)
    m = np.arange(4, dtype=np.float32).reshape(2, 2, 1)
    np.testing.assert_array_equal(mosaic.fill_empty(m.copy(), whole), m)


def test_iz_mosaic_is_cropped_and_filled():
    """HDR_CROP: c00's and c10's runs get each chart's box + HDR_CROP_PAD texels (exterior_sun_sky
    32^2: 20,736 mosaic pixels against its canvases' 24,576), and the mosaic's pixels outside
    every tile are filled from the tiles, not 0 (zeros a crop's width from a chart put the
    noise-free gradient's I_z 0.53 % off, the bound of test_noise_free_field_comes_back_unchanged
    being 0.5 %)."""
    assert denoise.HDR_CROP
    batch = _box_charts(EXTERIOR_32_BOXES)
    crops, ((H, W), _) = mosaic.plan(batch, cropped=True, pad=mosaic.HDR_CROP_PAD)
    assert H * W == 20_736
    for ch, (y0, y1, x0, x1) in zip(batch, crops, strict=True):
        by0, by1, bx0, bx1 = ch.cv.box
        assert min(by0 - y0, y1 - by1, bx0 - x0, x1 - bx1) >= mosaic.HDR_CROP_PAD
    # what OIDN gets for c00: no zero pixel (the charts' values are all positive)
    seen = []

    class Recording(denoise._Denoiser):  # the real OIDN run, its input kept
        def run(self, color, **kw):
            seen.append((np.array(color), kw))
            return super().run(color, **kw)

    mesh, t = two_chart_plane()
    clean = field(t, "gradient").astype(np.float32)
    charts = charts_of(mesh, t)
    args = (None, None, None, "RTLightmap", False, False, 0)  # no guides or variance
    batch = [
        denoise._prepare_chart(0, np.nonzero(charts == c)[0], clean, t, *args)
        for c in np.unique(charts)
    ]
    den = Recording("high")
    try:
        denoise._finish(den, batch, [clean.copy()], "RTLightmap", False, False, True)
    finally:
        den.close()
    hdr = [c for c, kw in seen if kw.get("hdr")]
    assert len(hdr) == 2 and all((c > 0).all() for c in hdr)


def test_one_oidn_denoiser_is_kept_between_calls_and_never_shared(monkeypatch):
    """A process baking stage after stage keeps one OIDN device and its last small filters (a
    new filter's first run costs more): the next call takes them and returns the same bits;
    two denoisers at once never share one (the second makes its own, released when it
    closes); large filters and the least recently used are not kept; the quality is part of
    a filter's key."""
    mesh, t = two_chart_plane()
    _, noisy = noisy_field(t, 0.05, seed=3)
    rec = dict(sh=noisy, texels=t, charts=charts_of(mesh, t))
    first = denoise.denoise_records([rec])[0]
    assert len(denoise._IDLE) == 1
    kept = denoise._IDLE[0]
    assert 0 < len(kept.filters) <= denoise.IDLE_FILTERS
    a = denoise._Denoiser.take("high")
    assert a is kept and not denoise._IDLE
    b = denoise._Denoiser.take("high")
    assert b is not kept and not b.filters
    b.close()
    assert denoise._IDLE == [b]  # the first one back is kept
    a.close()
    assert denoise._IDLE == [b]  # one at most: a released
    np.testing.assert_array_equal(denoise.denoise_records([rec])[0], first)
    den = denoise._IDLE[0]
    fast = denoise.denoise_records([rec], quality="fast")[0]
    assert denoise._IDLE == [den] and den.quality == den.qualities["fast"]
    assert list(den.filters)[-1][-1] == den.qualities["fast"]  # the latest kept last
    assert np.isfinite(fast).all()
    # at most IDLE_FILTERS, only small ones, the most recently used
    den = denoise._Denoiser.take("high")
    img = np.ones((8, 8, 3), np.float32)
    for w in (8, 9, 10):
        den.run(img[:, :1].repeat(w, axis=1), filter_type="RT", hdr=True)
    monkeypatch.setattr(denoise, "IDLE_FILTER_PIXELS", 8 * 9)
    den.close()
    assert [k[3] for k in den.filters] == [(8, 8, 3), (8, 9, 3)]
