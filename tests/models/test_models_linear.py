"""Linear-basis models (hemisphere, sh_l1, sh_l2, ambient_cube, hl2) against brute force."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import legendre

from tests._hemi_brute import cap_quadrature
from usdahd import models
from usdahd.errors import InputError, ModelError
from usdahd.models import ambient_cube, hl2, sh_l1, sh_l2
from usdahd.models.base import FORMATS, ROLES
from usdahd.numerics import hemi, sh

TOL = 1e-9  # fits are fixed linear maps built from exact (or ~1e-11 converged) quadrature
LINEAR = ["hemisphere", "sh_l1", "sh_l2", "ambient_cube", "hl2"]
CASES = [
    (name, ratio, solver)
    for name in LINEAR
    for ratio in models.get(name).RATIOS
    for solver in models.get(name).SOLVERS
]
FMT_DTYPE = {"half": np.float16, "unorm8": np.uint8, "snorm8": np.int8, "float": np.float32}


def _random_hemi_sh(rng, n):
    """Tangent-space radiance SH of random positive upper-hemisphere environments (n, 3, 9)."""
    d, w = sh.hemisphere_quadrature(24)
    lobes = rng.normal(size=(n, 3, 3))
    lobes /= np.linalg.norm(lobes, axis=-1, keepdims=True)
    lobes[..., 2] = np.abs(lobes[..., 2])
    sharp = rng.uniform(1, 30, size=(n, 3))
    colour = rng.uniform(0.1, 5, size=(n, 3, 3))
    rad = np.einsum("nlc,nld->ndc", colour, np.exp(sharp[..., None] * (lobes @ d.T - 1)))
    rad += rng.uniform(0, 0.5, size=(n, 1, 3))
    return np.einsum("ndc,dk,d->nck", rad, sh.basis(d), w)


def _theta_quadrature(n_theta=48, n_phi=48, quadrants=True):
    """Upper hemisphere, GL in theta (analytic in theta) x GL in phi per quadrant (the
    ambient-cube kinks lie on quadrant boundaries): spectrally convergent, no kink inside."""
    u, wu = legendre.leggauss(n_theta)
    th = (u + 1) * np.pi / 4
    wt = wu * np.pi / 4 * np.sin(th)
    v, wv = legendre.leggauss(n_phi)
    dirs, ws = [], []
    for q in range(4):
        phi = q * np.pi / 2 + (v + 1) * np.pi / 4
        x = (np.sin(th)[:, None] * np.cos(phi)).ravel()
        y = (np.sin(th)[:, None] * np.sin(phi)).ravel()
        dirs.append(np.stack([x, y, np.repeat(np.cos(th), n_phi)], -1))
        ws.append((wt[:, None] * wv * np.pi / 4).ravel())
    return np.concatenate(dirs), np.concatenate(ws)


def _lstsq_brute(basis_vals, target, w):
    """Weighted least squares per colour: basis (n, N), target (n, 3) -> (N, 3)."""
    sw = np.sqrt(w)[:, None]
    return np.linalg.lstsq(basis_vals * sw, target * sw, rcond=None)[0]


# --- interface ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", LINEAR)
def test_module_interface(name):
    mod = models.get(name)
    assert mod.NAME == name
    assert mod.DEFAULT_SOLVER in mod.SOLVERS
    for ratio in mod.RATIOS:
        for tex in mod.layout(ratio):
            assert tex.role in ROLES and tex.format in FORMATS
            assert tex.color_space in ("raw", "lin_rec709_scene")


@pytest.mark.parametrize("name,ratio,solver", CASES)
def test_fit_encode_decode_roundtrip(name, ratio, solver):
    rng = np.random.default_rng(0)
    x = _random_hemi_sh(rng, 20).reshape(4, 5, 3, 9)
    mod = models.get(name)
    f = models.fit(x, name, ratio=ratio, solver=solver)
    for v in f.params.values():
        assert v.dtype == np.float32 and v.shape[:2] == (4, 5)
    assert np.all(f.params["invalid"] == 0)
    channels, factors = f.encode()
    lay = {t.role: t for t in mod.layout(ratio)}
    assert set(channels) == set(lay)
    for role, arr in channels.items():
        assert arr.shape == (4, 5, len(lay[role].channels))
        assert arr.dtype == FMT_DTYPE[lay[role].format]
    dec = mod.decode(channels, ratio=ratio, factors=factors)
    assert set(dec) == set(f.params)
    d, _ = cap_quadrature(0.0, None, 8, 16)
    n = np.broadcast_to(d, (4, 5, len(d), 3))  # several normals per texel (prefix shape)
    before, after = f.evaluate(n), mod.evaluate(dec, n)
    assert before.shape == after.shape == (4, 5, len(d), 3) and after.dtype == np.float32
    one = f.evaluate(np.broadcast_to(d[7], (4, 5, 3)))  # one normal per texel
    np.testing.assert_allclose(one, before[:, :, 7], rtol=1e-6, atol=1e-6 * np.abs(one).max())
    if ratio == "8bit" and solver == "hemisphere":  # |L1| > L0 is clamped (documented)
        assert np.all(np.isfinite(after))
        return
    # float16: relative 2^-11 per coefficient; 8-bit: ratio step 1/127, sqrt(L0) step 1/255
    rel = 0.05 if ratio == "8bit" else 4e-3
    scale = np.abs(before).max()
    np.testing.assert_allclose(after, before, atol=rel * scale)


@pytest.mark.parametrize("name", LINEAR)
def test_self_bounce_added_with_albedo(name):
    rng = np.random.default_rng(1)
    f = models.fit(_random_hemi_sh(rng, 6), name)
    n = rng.normal(size=(6, 3)) + [0, 0, 1.5]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    albedo = rng.uniform(0, 1, size=(6, 3))
    iz = f.evaluate(np.tile([0.0, 0.0, 1.0], (6, 1)))
    expect = f.evaluate(n) + hemi.self_bounce(iz, n, albedo)
    np.testing.assert_allclose(f.evaluate(n, albedo=albedo), expect, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("name", LINEAR)
def test_non_finite_texel_is_black_and_flagged(name):
    rng = np.random.default_rng(2)
    x = _random_hemi_sh(rng, 4)
    x[1, 0, 3] = np.nan
    x[2, 2, 0] = np.inf
    f = models.fit(x, name)
    np.testing.assert_array_equal(f.params["invalid"][:, 0], [0, 1, 1, 0])
    out = f.evaluate(np.array([0.3, 0.1, 0.9]) / np.linalg.norm([0.3, 0.1, 0.9]))
    assert np.all(np.isfinite(out)) and np.all(out[1:3] == 0) and np.all(out[[0, 3]] != 0)


@pytest.mark.parametrize("name", LINEAR)
def test_bad_input_messages(name):
    mod = models.get(name)
    with pytest.raises(InputError, match=r"\(\.\.\., 3, 9\)"):
        mod.fit(np.zeros((4, 9)))
    with pytest.raises(ModelError, match="ratio"):
        mod.fit(np.zeros((1, 3, 9)), ratio="bogus")
    with pytest.raises(ModelError, match="solver"):
        mod.fit(np.zeros((1, 3, 9)), solver="bogus")
    with pytest.raises(InputError, match="texture"):
        mod.decode({}, factors={})


@pytest.mark.parametrize("name", LINEAR)
def test_hdr_scales_through_float16(name):
    rng = np.random.default_rng(3)
    x = _random_hemi_sh(rng, 5) * 1e5  # irradiance ~1e5-1e6 overflows float16 without a scale
    f = models.fit(x, name)
    channels, factors = f.encode()
    assert all(np.all(np.isfinite(c.astype(np.float64))) for c in channels.values())
    dec = models.get(name).decode(channels, ratio=f.ratio, factors=factors)
    n = np.array([0.2, -0.3, 0.9]) / np.linalg.norm([0.2, -0.3, 0.9])
    np.testing.assert_allclose(
        models.get(name).evaluate(dec, n), f.evaluate(n), rtol=0.05 if f.ratio == "8bit" else 4e-3
    )
    huge = models.fit(x * 1e195, name)  # beyond float32: clipped, never Inf/NaN
    assert all(np.all(np.isfinite(v)) for v in huge.params.values())


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    log_scale=st.floats(-30, 30),
    name=st.sampled_from(LINEAR),
)
def test_property_outputs_finite(seed, log_scale, name):
    x = np.random.default_rng(seed).normal(size=(3, 3, 9)) * 10.0**log_scale
    mod = models.get(name)
    for ratio in mod.RATIOS:
        f = models.fit(x, name, ratio=ratio)
        out = f.evaluate(np.array([0.0, 0.6, 0.8]))
        assert np.all(np.isfinite(out))
        channels, factors = f.encode()
        assert np.all(
            np.isfinite(
                mod.evaluate(
                    mod.decode(channels, ratio=ratio, factors=factors), np.array([0.0, 0.6, 0.8])
                )
            )
        )


# --- hemisphere -----------------------------------------------------------------------------


def test_hemisphere_model_exact_for_white_hemisphere_sky():
    d, w = cap_quadrature(0.0, None, 16, 32)
    x = np.stack([sh.project(np.ones((len(d), 3)), d, w)])  # radiance 1 above the horizon
    n, _ = cap_quadrature(0.0, None, 6, 12)
    for solver in ("iz", "hemisphere"):
        f = models.fit(x, "hemisphere", solver=solver)
        np.testing.assert_allclose(f.ambient, 1.0, atol=1e-6)
        np.testing.assert_allclose(f.evaluate(n[:, None])[:, 0], (1 + n[:, 2:]) / 2 + 0 * n, 1e-6)


def test_hemisphere_iz_solver_is_exact_iz_and_lsq_is_optimal():
    rng = np.random.default_rng(4)
    x = _random_hemi_sh(rng, 3)
    np.testing.assert_allclose(models.fit(x, "hemisphere").ambient, sh.iz(x), rtol=1e-6)
    d, w = cap_quadrature(0.0, None, 8, 16)
    for i in range(3):
        target = sh.irradiance(x[i], d)
        ref = _lstsq_brute(((1 + d[:, 2]) / 2)[:, None], target, w)
        got = models.fit(x[i : i + 1], "hemisphere", solver="hemisphere").ambient[0]
        np.testing.assert_allclose(got, np.maximum(ref[0], 0), rtol=1e-6)


# --- sh_l1 ----------------------------------------------------------------------------------


def test_sh_l1_hemisphere_solver_is_least_squares_optimum():
    rng = np.random.default_rng(5)
    x = _random_hemi_sh(rng, 3)
    d, w = cap_quadrature(0.0, None, 8, 16)
    y = sh.basis(d)[:, :4] * sh.COSINE_FACTORS[:4]  # linear irradiance of unit radiance coeffs
    got = sh_l1.fit(x, ratio="linear", solver="hemisphere")["coefficients"]
    for i in range(3):
        ref = _lstsq_brute(y, sh.irradiance(x[i], d), w)
        np.testing.assert_allclose(got[i], ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())


def test_sh_l1_project_is_truncation_and_linear_eval():
    rng = np.random.default_rng(6)
    x = _random_hemi_sh(rng, 2)
    f = sh_l1.fit(x, ratio="linear", solver="project")
    np.testing.assert_allclose(f["coefficients"], np.swapaxes(x[..., :4], -1, -2), rtol=1e-6)
    x4 = x.copy()
    x4[..., 4:] = 0
    n, _ = cap_quadrature(0.0, None, 4, 8)
    np.testing.assert_allclose(
        sh_l1.evaluate(f, np.broadcast_to(n, (2,) + n.shape)),
        sh.irradiance(x4[:, None], n[None]),
        rtol=1e-5,
        atol=1e-6,
    )


def test_enlighten_l0_l1_are_mean_and_first_moment():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(3, 9))
    d, w = sh.sphere_quadrature(16)
    rad = sh.evaluate(x, d)  # (n, 3)
    l0, l1 = sh_l1.to_enlighten(np.swapaxes(x[:, :4], 0, 1))
    np.testing.assert_allclose(l0, (rad * w[:, None]).sum(0) / (4 * np.pi), atol=1e-12)
    np.testing.assert_allclose(l1, np.einsum("nc,nk,n->ck", rad, d, w) / (4 * np.pi), atol=1e-12)
    np.testing.assert_allclose(sh_l1.from_enlighten(l0, l1), np.swapaxes(x[:, :4], 0, 1), 1e-12)


def test_nonlinear_l1_conserves_energy_and_is_nonnegative():
    # Zonal about L1 = z: Gauss-Legendre in z is accurate (integrand C^1 or smoother).
    u, wu = legendre.leggauss(2000)
    n = np.stack([np.sqrt(1 - u * u), 0 * u, u], -1)
    for r in [0.0, 0.1, 0.5, 0.9, 1.0]:
        l0 = np.array([2.0])
        l1 = np.array([[0.0, 0.0, 2.0 * r]])
        val = sh_l1.nonlinear_irradiance(l0, l1, n)[:, 0]
        assert val.min() >= 0
        np.testing.assert_allclose((val * wu).sum() / 2, 2.0, rtol=1e-9)  # spherical mean = L0
    # r = 1 (a delta light): 4 L0 q^3; r = 0: constant L0
    q = (1 + u) / 2
    np.testing.assert_allclose(
        sh_l1.nonlinear_irradiance([1.0], [[0, 0, 1.0]], n)[:, 0], 4 * q**3, rtol=1e-12
    )
    np.testing.assert_allclose(sh_l1.nonlinear_irradiance([3.0], [[0, 0, 0.0]], n), 3.0)
    assert np.all(sh_l1.nonlinear_irradiance([-1.0], [[0, 0, 0.5]], n) == 0)


def test_nonlinear_matches_enlighten_shader_formula():
    rng = np.random.default_rng(8)
    l0, l1 = rng.uniform(0.5, 2, size=4), rng.normal(size=(4, 3)) * 0.3
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    for c in range(4):  # NonlinearL1ComputeChannel, transcribed literally
        mod = np.linalg.norm(l1[c])
        q = 0.5 + 0.5 * n @ (l1[c] / mod)
        r = mod / l0[c]
        p = 1 + 2 * r
        a = (1 - r) / (1 + r)
        x = (1 + p) * q**p
        ref = max(0.0, l0[c] * (x + a * (1 - x)))  # lerp(x, 1, a)
        got = sh_l1.nonlinear_irradiance(l0[c : c + 1], l1[c : c + 1], n)[0]
        np.testing.assert_allclose(got, ref, rtol=1e-12)


def test_sh_l1_8bit_codes_follow_enlighten_decode():
    # L0 = 0.25 = l0Scale -> code 255; L1/L0 = (0.25, -1, 0) -> 158.75, 0, 127
    l0 = np.full(3, 0.25)
    l1 = np.tile([0.0625, -0.25, 0.0], (3, 1))
    params = {"coefficients": sh_l1.from_enlighten(l0, l1).astype(np.float32)}
    ch, fac = sh_l1.encode(params, ratio="8bit")
    assert fac["l0Scale"] == 0.25  # power of two >= max L0
    # one RGBA texture per colour: coefficients0 = red (L0, L1x, L1y, L1z)
    assert set(ch) == {"coefficients0", "coefficients1", "coefficients2"}
    codes = np.stack([ch[f"coefficients{i}"] for i in range(3)])
    np.testing.assert_array_equal(codes[0], [255, 159, 0, 127])
    dec = sh_l1.decode(ch, ratio="8bit", factors=fac)
    dl0, dl1 = sh_l1.to_enlighten(dec["coefficients"])
    u = codes[0].astype(float)
    np.testing.assert_allclose(dl0[0], 0.25 * (u[0] / 255) ** 2, rtol=1e-6)  # C++ decode
    np.testing.assert_allclose(dl1[0], (u[1:] - 127) * dl0[0] / 127, rtol=1e-6)


def test_sh_l1_8bit_clamps_ratio_beyond_one():
    params = {"coefficients": sh_l1.from_enlighten(np.ones(3), np.tile([3.0, 0, 0], (3, 1)))}
    ch, fac = sh_l1.encode(params, ratio="8bit")
    assert ch["coefficients0"][1] == 254


# --- sh_l2 ----------------------------------------------------------------------------------


def test_sh_l2_evaluates_sh_irradiance():
    rng = np.random.default_rng(9)
    x = rng.normal(size=(5, 3, 9))
    n = rng.normal(size=(5, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    f = models.fit(x, "sh_l2")
    np.testing.assert_allclose(f.evaluate(n), sh.irradiance(x, n), rtol=1e-5, atol=1e-6)


def test_enlighten_matrix_equals_direct_evaluation_with_axis_swap():
    rng = np.random.default_rng(10)
    x = rng.normal(size=(4, 3, 9))
    n = rng.normal(size=(4, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    c = np.swapaxes(x, -1, -2)
    m = sh_l2.enlighten_matrix(sh_l2.enlighten_coefficients(c))
    assert np.allclose(m, np.swapaxes(m, -1, -2))
    direct = sh.irradiance(x, n)
    np.testing.assert_allclose(sh_l2.evaluate_enlighten(m, n, clamp=False), direct, atol=1e-12)
    np.testing.assert_allclose(sh_l2.evaluate_enlighten(m, n), np.maximum(direct, 0), atol=1e-12)
    # the polynomial form of the documentation, in Enlighten axes (x, y, z)_E = (x, z, y)_ours
    e = sh_l2.enlighten_coefficients(c)
    xe, ye, ze = n[:, 0], n[:, 2], n[:, 1]
    poly = np.stack(
        [1 + 0 * xe, xe, ye, ze, 3 * ye**2 - 1, xe * ye, ye * ze, xe * ze, xe**2 - ze**2], -1
    )
    np.testing.assert_allclose(np.einsum("nj,njc->nc", poly, e), direct, atol=1e-12)
    # without the swap the result is wrong
    unswapped = np.stack([n[:, 0], n[:, 2], n[:, 1]], -1)
    assert np.abs(sh_l2.evaluate_enlighten(m, unswapped, clamp=False) - direct).max() > 1e-2


# --- ambient cube and HL2 -------------------------------------------------------------------


def test_ambient_cube_fit_matrices_match_quadrature():
    d, w = _theta_quadrature()
    b = ambient_cube.weights(d)[:, :5]
    np.testing.assert_allclose(np.einsum("ni,nj,n->ij", b, b, w), ambient_cube.GRAM, atol=1e-13)
    cross = np.einsum("ni,nk,n->ik", b, sh.basis(d), w)
    np.testing.assert_allclose(cross, ambient_cube.CROSS, atol=1e-13)


def test_ambient_cube_fit_is_least_squares_optimum():
    rng = np.random.default_rng(11)
    x = _random_hemi_sh(rng, 3)
    d, w = _theta_quadrature(24, 24)
    b = ambient_cube.weights(d)[:, :5]
    got = ambient_cube.fit(x)["coefficients"]
    for i in range(3):
        ref = _lstsq_brute(b, sh.irradiance(x[i], d), w)
        np.testing.assert_allclose(got[i, :5], ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())
        assert np.all(got[i, 5] == 0)


def test_hl2_fit_matrices_match_brute_force_quadrature():
    d, w = sh.hemisphere_quadrature(600)  # 7.2e5 points, no knowledge of the kinks
    b = hl2.weights(d)
    np.testing.assert_allclose(np.einsum("ni,nj,n->ij", b, b, w), hl2.GRAM, atol=1e-8)
    np.testing.assert_allclose(np.einsum("ni,nk,n->ik", b, sh.basis(d), w), hl2.CROSS, atol=1e-8)
    d2, w2 = hl2.kink_quadrature(2 * hl2.QUAD_THETA, 2 * hl2.QUAD_PHI)  # converged
    b2 = hl2.weights(d2)
    np.testing.assert_allclose(np.einsum("ni,nj,n->ij", b2, b2, w2), hl2.GRAM, atol=1e-11)


def test_hl2_basis_and_shader_weights():
    np.testing.assert_allclose(np.linalg.norm(hl2.BUMP_BASIS, axis=1), 1, atol=1e-15)
    np.testing.assert_allclose(hl2.BUMP_BASIS @ hl2.BUMP_BASIS.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(hl2.weights(np.array([0, 0, 1.0])), [1 / 3] * 3, atol=1e-15)
    np.testing.assert_allclose(hl2.weights(hl2.BUMP_BASIS), np.eye(3), atol=1e-15)


@pytest.mark.parametrize("name", ["ambient_cube", "hl2", "sh_l1"])
def test_constant_irradiance_is_reproduced(name):
    x = np.zeros((1, 3, 9))
    x[0, :, 0] = 2 * np.sqrt(np.pi) * np.array([1.0, 2.0, 0.5])  # uniform sphere radiance
    f = models.fit(x, name)
    n, _ = cap_quadrature(0.0, None, 6, 12)
    np.testing.assert_allclose(
        f.evaluate(n[:, None])[:, 0], np.tile([1, 2, 0.5], (len(n), 1)), rtol=1e-6
    )
