"""SH conventions checked against brute-force quadrature."""

import numpy as np
import pytest

from usdahd.numerics import sh


def test_basis_orthonormal_on_sphere():
    d, w = sh.sphere_quadrature(16)
    y = sh.basis(d)
    gram = np.einsum("nk,nl,n->kl", y, y, w)
    np.testing.assert_allclose(gram, np.eye(9), atol=1e-12)


@pytest.mark.parametrize(
    "k,fn",
    [
        (1, lambda x, y, z: -np.sqrt(3 / (4 * np.pi)) * y),
        (2, lambda x, y, z: np.sqrt(3 / (4 * np.pi)) * z),
        (3, lambda x, y, z: -np.sqrt(3 / (4 * np.pi)) * x),
        (4, lambda x, y, z: np.sqrt(15 / (4 * np.pi)) * x * y),
        (5, lambda x, y, z: -np.sqrt(15 / (4 * np.pi)) * y * z),
        (6, lambda x, y, z: np.sqrt(5 / (16 * np.pi)) * (3 * z * z - 1)),
        (7, lambda x, y, z: -np.sqrt(15 / (4 * np.pi)) * x * z),
        (8, lambda x, y, z: np.sqrt(15 / (16 * np.pi)) * (x * x - y * y)),
    ],
)
def test_basis_signs_match_2024_eq2_3(k, fn):
    d = sh.fibonacci_sphere(50)
    np.testing.assert_allclose(sh.basis(d)[:, k], fn(*d.T), atol=1e-14)


def _frame(n):
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(a, n)
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n])


def _brute_irradiance(radiance_fn, n, quad=96):
    # Gauss-Legendre over the hemisphere around n: exact for polynomial radiance, no kink.
    d, w = sh.hemisphere_quadrature(quad)
    d = d @ _frame(np.asarray(n, float))
    return (radiance_fn(d) * (d @ n) * w).sum() / np.pi


def test_uniform_white_sky_gives_one():
    d, w = sh.sphere_quadrature(32)
    coeffs = sh.project(np.ones((len(d), 1)), d, w)
    for n in sh.fibonacci_sphere(7):
        np.testing.assert_allclose(sh.irradiance(coeffs, n), 1.0, atol=1e-12)


def test_cosine_band_factors_by_quadrature():
    # The clamped cosine max(0, z)/pi projected into zonal harmonics gives the band factors.
    d, w = sh.hemisphere_quadrature(32)  # the lobe is zero below the horizon: exact
    y = sh.basis(d)
    lobe = d[:, 2] / np.pi
    for band, k in [(0, 0), (1, 2), (2, 6)]:
        z_l = (lobe * y[:, k] * w).sum()
        factor = np.sqrt(4 * np.pi / (2 * band + 1)) * z_l
        assert abs(factor - sh.COSINE_BAND_FACTORS[band]) < 1e-12


def test_irradiance_matches_brute_force_for_band_limited_radiance():
    rng = np.random.default_rng(1)
    c = rng.normal(size=(1, 9))
    fn = lambda d: sh.basis(d) @ c[0]
    for n in sh.fibonacci_sphere(5):
        # Quadratic radiance: SH convolution is exact (irradiance has no band > 2 content).
        np.testing.assert_allclose(sh.irradiance(c, n)[0], _brute_irradiance(fn, n), atol=1e-12)


def test_iz_from_l10_for_hemispherical_radiance():
    # Radiance zero below the horizon: I_z = 2/sqrt(3 pi) * l_1^0 exactly.
    fn = lambda d: (1.0 + d[:, 0] + 2 * d[:, 2] ** 2) * (d[:, 2] > 0)
    d, w = sh.hemisphere_quadrature(32)  # fn vanishes below the horizon: exact projection
    coeffs = sh.project(fn(d)[:, None], d, w)
    brute = _brute_irradiance(fn, np.array([0.0, 0.0, 1.0]), quad=32)
    np.testing.assert_allclose(sh.iz(coeffs)[0], brute, rtol=1e-12)
    assert abs(sh.IZ_FROM_L10 - 2 / np.sqrt(3 * np.pi)) < 1e-15


def test_hemisphere_quadrature_area():
    d, w = sh.hemisphere_quadrature(8)
    assert abs(w.sum() - 2 * np.pi) < 1e-12
    assert (d[:, 2] > 0).all()


def test_hemispherical_gram_exact_and_symmetric():
    g = sh.hemispherical_gram()
    np.testing.assert_allclose(g, g.T, atol=1e-15)
    np.testing.assert_allclose(g, sh.hemispherical_gram(40), atol=1e-13)
    # Y00 * Y00 over the hemisphere = 1/2.
    assert abs(g[0, 0] - 0.5) < 1e-14
    assert np.linalg.eigvalsh(g).min() > 0
