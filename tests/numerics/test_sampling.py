"""Samplers: pdfs integrate to one and match the sample density; LD set properties."""

import math

import numpy as np
import pytest

from tests import stats
from tests.stats import assert_mean, chi2_directions
from usdahd.numerics import sampling as S
from usdahd.numerics import sh

N = 200_000  # MC checks: tolerance stats.SIGMAS standard errors of the estimator


def _mc_ok(vals, exact):
    assert_mean(vals, exact, atol=1e-12)  # atol: exact zero-variance estimators (1/p constant)


@pytest.mark.parametrize(
    "fn,solid",
    [
        (S.uniform_hemisphere, 2 * np.pi),
        (S.cosine_hemisphere, 2 * np.pi),
        (S.uniform_sphere, 4 * np.pi),
    ],
)
def test_direction_samplers_unit_and_unbiased(fn, solid):
    u = np.random.default_rng(0).random((N, 2))
    d, pdf = fn(u)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    _mc_ok(1.0 / pdf, solid)  # E[1/p] = measure of the support
    # E[f/p] = integral of f for f = Y20 + 1 (compared with exact Gauss-Legendre quadrature)
    f = lambda x: sh.basis(x)[:, 6] + 1.0
    q, w = sh.hemisphere_quadrature(16) if solid < 7 else sh.sphere_quadrature(16)
    _mc_ok(f(d) / pdf, float(f(q) @ w))


CM = np.cos(0.3)
#: (sampler, its solid-angle pdf, cos theta range of its support) for the chi-square tests.
CHI2_CASES = {
    "uniform_hemisphere": (
        S.uniform_hemisphere,
        lambda d: np.full(len(d), 1 / (2 * np.pi)),
        (0, 1),
    ),
    "cosine_hemisphere": (S.cosine_hemisphere, lambda d: np.clip(d[:, 2], 0, None) / np.pi, (0, 1)),
    "texel_hemisphere": (S.texel_hemisphere, lambda d: S.texel_hemisphere_pdf(d[:, 2]), (0, 1)),
    "uniform_sphere": (S.uniform_sphere, lambda d: np.full(len(d), 1 / (4 * np.pi)), (-1, 1)),
    "uniform_cone": (
        lambda u: S.uniform_cone(u, CM),
        lambda d: np.full(len(d), float(S.cone_pdf(CM))),
        (CM, 1),
    ),
}


@pytest.mark.parametrize("name", sorted(CHI2_CASES))
def test_samplers_draw_the_density_their_pdf_claims(name):
    sample, pdf, cos_range = CHI2_CASES[name]
    chi2_directions(sample, pdf, cos_range=cos_range, tests=len(CHI2_CASES))


def test_chi2_rejects_a_wrong_pdf_and_matches_the_chi2_distribution():
    # cosine-distributed samples claimed uniform: a clear failure
    with pytest.raises(AssertionError, match="does not draw the density"):
        chi2_directions(
            S.cosine_hemisphere, lambda d: np.full(len(d), 1 / (2 * np.pi)), cos_range=(0, 1)
        )
    # the survival function against closed forms: dof 1 -> erfc(sqrt(x/2)); even dof 2k ->
    # exp(-x/2) sum_{i<k} (x/2)^i / i! (both branches: series below x/2 = k + 1, else fraction)
    for x in (0.1, 1.0, 7.5, 40.0, 150.0, 260.0):
        assert stats.chi2_sf(x, 1) == pytest.approx(math.erfc(math.sqrt(x / 2)), rel=1e-9)
        for k in (1, 3, 100):
            h = x / 2
            exact = math.exp(-h) * sum(
                math.exp(i * math.log(h) - math.lgamma(i + 1)) for i in range(k)
            )
            assert stats.chi2_sf(x, 2 * k) == pytest.approx(exact, rel=1e-9, abs=1e-300)


def test_cone_sampler_pdf_and_support():
    u = np.random.default_rng(1).random((N, 2))
    cm = np.cos(0.3)
    d, pdf = S.uniform_cone(u, cm)
    assert d[:, 2].min() >= cm - 1e-12
    np.testing.assert_allclose(pdf, 1 / (2 * np.pi * (1 - cm)))
    np.testing.assert_allclose(S.cone_pdf(cm), pdf[0])
    _mc_ok(d[:, 2] / pdf, np.pi * np.sin(0.3) ** 2)  # projected solid angle of a cap


def test_cone_sampler_is_stable_for_tiny_cones():
    """uniform_cone is numerics.sampling.cone_local (the lights' rule): the sine of a direction
    in a 1e-6 rad cone is exact to rounding, where sqrt(1 - z^2) cancels to ~1e-4 relative."""
    u = np.random.default_rng(3).random((1000, 2))
    cm = np.cos(1e-6)
    d, _ = S.uniform_cone(u, cm)
    omc = 1.0 - cm
    want = np.sqrt(u[:, 0] * omc * (2.0 - u[:, 0] * omc))
    np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), want, rtol=1e-12)
    np.testing.assert_array_equal(d, S.cone_local(u, omc))


def test_concentric_disk_uniform():
    p = S.concentric_disk(np.random.default_rng(2).random((N, 2)))
    r2 = (p**2).sum(1)
    assert r2.max() <= 1 + 1e-12
    _mc_ok(r2, 0.5)  # E[r^2] = 1/2 for uniform area


def test_r2_and_cranley_patterson():
    p = S.r2_sequence(256)
    assert p.min() >= 0 and p.max() < 1
    # stratification: every cell of a 8x8 grid holds 4 +- 2 points (random would not)
    h, _, _ = np.histogram2d(p[:, 0], p[:, 1], bins=8, range=[[0, 1], [0, 1]])
    assert h.min() >= 2 and h.max() <= 6
    np.testing.assert_array_equal(S.r2_sequence(4, 2), p[2:6])
    q = S.cranley_patterson(p, np.array([[0.5, 0.25], [0.0, 0.0]]))
    assert q.shape == (2, 256, 2) and q.max() < 1
    np.testing.assert_allclose(q[1], p)


def test_orthonormal_basis_and_transforms():
    n = S.uniform_sphere(np.random.default_rng(3).random((1000, 2)))[0]
    n = np.vstack([n, [[0, 0, 1.0], [0, 0, -1.0]]])
    f = S.orthonormal_basis(n)
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", f, f), np.tile(np.eye(3), (len(n), 1, 1)), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(f), 1.0, atol=1e-12)
    v = np.random.default_rng(4).normal(size=(len(n), 3))
    np.testing.assert_allclose(S.to_world(S.to_local(v, f), f), v, atol=1e-12)


def test_discrete_and_balance():
    cdf = np.cumsum([0.2, 0.3, 0.5])
    idx = S.sample_discrete(cdf, np.random.default_rng(5).random(N))
    np.testing.assert_allclose(np.bincount(idx) / N, [0.2, 0.3, 0.5], atol=5e-3)
    np.testing.assert_allclose(
        S.balance_heuristic(np.array([1.0, 0.0]), np.array([3.0, 0.0])), [0.25, 0.0]
    )
