"""Samplers: pdfs integrate to one and match the sample density; LD set properties."""

import numpy as np
import pytest

from usdahd.numerics import sampling as S
from usdahd.numerics import sh

N = 200_000  # MC checks: tolerance 5 SE of the estimator, computed below


def _mc_ok(vals, exact):
    se = vals.std(ddof=1) / np.sqrt(len(vals))
    assert abs(vals.mean() - exact) < 5 * se + 1e-12, (vals.mean(), exact, se)


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


def test_cone_sampler_pdf_and_support():
    u = np.random.default_rng(1).random((N, 2))
    cm = np.cos(0.3)
    d, pdf = S.uniform_cone(u, cm)
    assert d[:, 2].min() >= cm - 1e-12
    np.testing.assert_allclose(pdf, 1 / (2 * np.pi * (1 - cm)))
    np.testing.assert_allclose(S.cone_pdf(cm), pdf[0])
    _mc_ok(d[:, 2] / pdf, np.pi * np.sin(0.3) ** 2)  # projected solid angle of a cap


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
