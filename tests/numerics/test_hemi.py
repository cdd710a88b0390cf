"""usdahd.numerics.hemi against brute-force (exact) quadrature."""

import numpy as np
import pytest

from tests._hemi_brute import (
    cap_quadrature,
    hemisphere_project,
    hlsh_multiply_reference,
    lune_integral,
    tangent_hlsh_matrix_reference,
)
from usdahd.numerics import hemi, sh

TOL = 1e-10  # every reference is an exact quadrature (polynomial integrands): rounding only


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_gram_closed_form_matches_exact_quadrature_and_is_spd():
    np.testing.assert_allclose(hemi.HEMISPHERE_GRAM, sh.hemispherical_gram(), atol=TOL)
    assert np.all(np.linalg.eigvalsh(hemi.HEMISPHERE_GRAM) > 0)
    assert not hemi.HEMISPHERE_GRAM.flags.writeable


def test_hemisphere_multiply_linear_matches_projection():
    rng = np.random.default_rng(1)
    for _ in range(6):
        n = _unit(rng.normal(size=3))
        l = rng.normal(size=(3, 9))
        ref = hemisphere_project(l, n, lmax_out=1)
        np.testing.assert_allclose(hemi.hemisphere_multiply_linear(l, n), ref, atol=TOL)


def test_hemisphere_multiply_linear_tangent_space_is_gram_rows():
    l = np.random.default_rng(2).normal(size=(3, 9))
    out = hemi.hemisphere_multiply_linear(l, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(out, hemi.tangent_hemisphere_multiply(l)[:, :4], atol=TOL)


def test_hemisphere_multiply_linear_vectorized_over_texels():
    rng = np.random.default_rng(3)
    n = _unit(rng.normal(size=(5, 3)))
    l = rng.normal(size=(5, 3, 9))
    out = hemi.hemisphere_multiply_linear(l, n)
    assert out.shape == (5, 3, 4)
    for i in range(5):
        np.testing.assert_allclose(out[i], hemisphere_project(l[i], n[i]), atol=TOL)


def test_p2_has_no_normal_component():
    rng = np.random.default_rng(4)
    n = _unit(rng.normal(size=(50, 3)))
    p2 = hemi.p2_vector(rng.normal(size=(50, 5)), n)
    nsh = np.stack([-n[:, 1], n[:, 2], -n[:, 0]], -1)
    np.testing.assert_allclose(np.einsum("nk,nk->n", p2, nsh), 0, atol=1e-12)


def test_zonal_l2_is_the_rotated_frame_l20():
    rng = np.random.default_rng(5)
    n = _unit(rng.normal(size=3))
    l2 = rng.normal(size=5)
    d, w = cap_quadrature(-1.0, None, 16, 32)
    y20 = np.sqrt(5 / (16 * np.pi)) * (3 * (d @ n) ** 2 - 1)
    ref = np.sum(w * (l2 @ sh.basis(d)[:, 4:].T) * y20)
    np.testing.assert_allclose(hemi.zonal_l2(l2, n), ref, atol=TOL)


@pytest.mark.parametrize("alpha", [np.pi / 2, 0.3, 1.0, 2.0, np.pi])
def test_cone_matrix_matches_band4_reference(alpha):
    ref = tangent_hlsh_matrix_reference(np.cos(alpha))
    np.testing.assert_allclose(hemi.cone_hlsh_matrix(alpha)[1:], ref, atol=TOL)


def test_cone_matrix_iz_row_is_exact_irradiance_of_masked_radiance():
    rng = np.random.default_rng(6)
    for alpha in [0.4, np.pi / 2, 2.5]:
        l = rng.normal(size=9)
        d, w = cap_quadrature(np.cos(alpha), None, 16, 32)
        ref = np.sum(w * (l @ sh.basis(d).T) * d[:, 2]) / np.pi
        np.testing.assert_allclose(hemi.cone_hlsh_matrix(alpha)[0] @ l, ref, atol=TOL)


def test_cone_closed_cone_gives_zero_and_vectorizes():
    np.testing.assert_allclose(hemi.cone_hlsh_matrix(0.0), 0.0, atol=1e-14)
    m = hemi.cone_hlsh_matrix(np.array([[0.3, 1.0], [np.pi / 2, 2.0]]))
    assert m.shape == (2, 2, 4, 9)
    np.testing.assert_allclose(m[1, 0, 1:], hemi.HLSH_HEMISPHERE_MATRIX, atol=0)


def test_hemisphere_matrix_is_printed_eq37():
    spi, s3pi = np.sqrt(np.pi), np.sqrt(3 * np.pi)
    printed = np.zeros((3, 9))
    printed[0, [0, 2, 6]] = [1 / (4 * spi), 2203 / (8192 * s3pi), -7 * np.sqrt(5) / (128 * spi)]
    printed[1, [3, 7]] = [-2573 / (4096 * s3pi), -11 * np.sqrt(15) / (128 * spi)]
    printed[2, [1, 5]] = printed[1, [3, 7]]
    np.testing.assert_allclose(hemi.HLSH_HEMISPHERE_MATRIX, printed, rtol=1e-15, atol=0)


@pytest.mark.parametrize("alpha", [np.pi / 2, 0.7, 1.3])
def test_world_space_hlsh_multiply_matches_reference(alpha):
    rng = np.random.default_rng(7)
    for _ in range(4):
        n = _unit(rng.normal(size=3))
        l = rng.normal(size=(3, 9))
        ca, c = hemi.hlsh_multiply(l, n, alpha)
        rca, rc, riz = hlsh_multiply_reference(l, n, np.cos(alpha))
        np.testing.assert_allclose(ca, rca, atol=TOL)
        np.testing.assert_allclose(c, rc, atol=TOL)
        np.testing.assert_allclose(hemi.hlsh_irradiance(ca, c, n), riz, atol=TOL)


def test_world_space_hlsh_multiply_preserves_iz_and_vectorizes():
    rng = np.random.default_rng(8)
    n = _unit(rng.normal(size=(7, 3)))
    l = rng.normal(size=(7, 3, 9))
    alpha = rng.uniform(0.1, np.pi / 2, size=7)
    ca, c = hemi.hlsh_multiply(l, n)
    assert ca.shape == (7, 3) and c.shape == (7, 3, 3)
    np.testing.assert_allclose(hemi.hlsh_irradiance(ca, c, n), sh.irradiance(l, n), atol=TOL)
    ca2, c2 = hemi.hlsh_multiply(l, n, alpha)
    for i in range(7):
        rca, rc, _ = hlsh_multiply_reference(l[i], n[i], np.cos(alpha[i]))
        np.testing.assert_allclose(ca2[i], rca, atol=TOL)
        np.testing.assert_allclose(c2[i], rc, atol=TOL)


def test_tangent_multiply_is_not_idempotent():
    # Why hemi.py warns against multiplying data that is already hemispherical.
    g = hemi.HEMISPHERE_GRAM
    assert np.abs(g @ g - g).max() > 0.1
    d, w = cap_quadrature(0.0, None, 16, 32)
    l = sh.project(np.ones((len(d), 1)), d, w)  # white upper hemisphere, tangent space
    once = hemi.tangent_hemisphere_multiply(l)
    dirs, _ = cap_quadrature(0.0, None, 8, 16)
    err0 = np.abs(sh.irradiance(l, dirs) - (1 + dirs[:, 2:]) / 2).max()
    err1 = np.abs(sh.irradiance(once, dirs) - (1 + dirs[:, 2:]) / 2).max()
    assert err0 < 1e-12 < 0.05 < err1  # the exact linear signal is damaged by a second multiply


def test_hemisphere_light_sh_is_projection_of_indicator():
    rng = np.random.default_rng(9)
    for _ in range(3):
        h = _unit(rng.normal(size=3))
        d, w = cap_quadrature(0.0, h, 16, 32)
        ref = np.einsum("nk,n->k", sh.basis(d), w)
        np.testing.assert_allclose(hemi.hemisphere_light_sh(h), ref, atol=TOL)


def test_self_bounce_matches_lambertian_plane_quadrature():
    # A Lambertian plane (the surface, below z = 0) of albedo a lit by I_z has radiance a*I_z;
    # the normalized irradiance it sends into a tilted normal n is (1/pi) int_{z<0,n.w>0} a I_z n.w
    rng = np.random.default_rng(10)
    albedo, iz = np.array([0.2, 0.5, 0.9]), np.array([1.5, 0.3, 2.0])
    for _ in range(4):
        n = _unit(rng.normal(size=3) + [0, 0, 1.0])
        ref = albedo * iz * lune_integral(lambda d, n=n: d @ n, [0.0, 0.0, -1.0], n) / np.pi
        np.testing.assert_allclose(hemi.self_bounce(iz, n, albedo), ref, atol=TOL)
        up = _unit(rng.normal(size=3))
        world = hemi.self_bounce(iz, n, albedo, vertex_normals=up)
        np.testing.assert_allclose(world, albedo * iz * (1 - n @ up) / 2, atol=1e-15)
    assert hemi.self_bounce(iz, np.array([0.0, 0.0, 1.0]), albedo).max() == 0.0
