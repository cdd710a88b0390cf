"""Statistical checks shared by the Monte Carlo tests: one home for the tolerance rules.

- :func:`assert_mean`: a Monte Carlo mean equals its exact value within ``z`` standard errors
  of the estimator (the sample standard deviation over sqrt(n), measured in the test).
- :func:`assert_same_mean`: two independent sample sets have the same mean (combined SE).
- :func:`chi2_directions`: a direction sampler draws directions with the density its pdf
  claims: Pearson's chi-square test on a (cos theta, phi) histogram, in the style of
  Mitsuba's ``chi2.py`` (expected counts integrated from the pdf per cell, cells with fewer
  than 5 expected samples pooled, Sidak-corrected significance).

``SIGMAS`` = 5 standard errors: a correct estimator fails a two-sided check with probability
< 6e-7 (normal tail), so the suite's few hundred checks have no false failures in practice,
while a bias of ~5 SE is caught. (``Z`` in the tests is the unit vector (0, 0, 1); the bound is
never called Z.)
"""

from __future__ import annotations

import math

import numpy as np

#: Tolerance of every Monte Carlo check, in standard errors of the estimator.
SIGMAS = 5.0


def standard_error(values) -> float:
    """Standard error of the mean of ``values`` (n,): sample std (ddof=1) / sqrt(n)."""
    v = np.asarray(values, np.float64).ravel()
    return float(v.std(ddof=1) / np.sqrt(len(v)))


def assert_mean(values, exact, z: float = SIGMAS, *, rel: float = 0.0, atol: float = 0.0, what=""):
    """Assert ``|mean(values) - exact| < z * SE + rel * |exact| + atol``.

    values : (n,) independent samples of an unbiased estimator; exact : float.
    ``rel``/``atol`` are float slack (float32 arithmetic, quadrature error of ``exact``): give
    the reason where they are used. Returns the standard error.
    """
    v = np.asarray(values, np.float64).ravel()
    mean, se = float(v.mean()), standard_error(v)
    tol = z * se + rel * abs(exact) + atol
    assert abs(mean - exact) < tol, (what, mean, exact, se, tol)
    return se


def assert_same_mean(a, b, z: float = SIGMAS, *, rel: float = 0.0, atol: float = 0.0, what=""):
    """Assert two independent sample sets (n,), (m,) have the same mean within ``z`` combined
    standard errors ``sqrt(se_a^2 + se_b^2)`` plus ``rel * |mean(b)| + atol``. Returns the SE.

    For paired samples (the same texels, independent streams) compare the differences with
    ``assert_mean(a - b, 0.0, ...)`` instead: spatial variation cancels.
    """
    a = np.asarray(a, np.float64).ravel()
    b = np.asarray(b, np.float64).ravel()
    se = float(np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)))
    tol = z * se + rel * abs(b.mean()) + atol
    assert abs(a.mean() - b.mean()) < tol, (what, a.mean(), b.mean(), se, tol)
    return se


# --------------------------------------------------------------------------------------------
# chi-square test of a direction sampler


def chi2_sf(x: float, dof: int) -> float:
    """P(X > x) for X ~ chi-square with ``dof`` degrees of freedom (regularized upper
    incomplete gamma Q(dof/2, x/2); series / continued fraction, Numerical Recipes 6.2)."""
    a, x = 0.5 * dof, 0.5 * x
    if x <= 0.0:
        return 1.0
    log_pre = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:  # series for P, then Q = 1 - P
        term = total = 1.0 / a
        k = a
        for _ in range(10_000):
            k += 1.0
            term *= x / k
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return max(0.0, 1.0 - total * math.exp(log_pre))
    tiny = 1e-300  # Lentz's continued fraction for Q
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return math.exp(log_pre) * h


def _cell_integrals(pdf, cos_edges, phi_edges, sub: int) -> np.ndarray:
    """Integral of the solid-angle pdf over each (cos theta, phi) cell, by a ``sub`` x ``sub``
    Gauss-Legendre rule per cell (d omega = d cos theta d phi). returns (n_cos, n_phi)."""
    g, w = np.polynomial.legendre.leggauss(sub)
    c0, c1 = cos_edges[:-1], cos_edges[1:]
    p0, p1 = phi_edges[:-1], phi_edges[1:]
    cz = (0.5 * (c1 - c0))[:, None] * g[None, :] + (0.5 * (c0 + c1))[:, None]  # (nc, sub)
    ph = (0.5 * (p1 - p0))[:, None] * g[None, :] + (0.5 * (p0 + p1))[:, None]  # (np, sub)
    z = cz[:, None, :, None]
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = ph[None, :, None, :]
    dirs = np.stack(np.broadcast_arrays(s * np.cos(phi), s * np.sin(phi), z), axis=-1)
    vals = np.asarray(pdf(dirs.reshape(-1, 3)), np.float64).reshape(dirs.shape[:-1])
    weight = w[:, None] * w[None, :]
    jac = (0.5 * (c1 - c0))[:, None] * (0.5 * (p1 - p0))[None, :]
    return np.einsum("abij,ij->ab", vals, weight) * jac


def chi2_directions(
    sample,
    pdf,
    *,
    n: int = 200_000,
    res: tuple[int, int] = (10, 20),
    cos_range: tuple[float, float] = (-1.0, 1.0),
    seed: int = 0,
    alpha: float = 0.01,
    tests: int = 1,
    sub: int = 8,
) -> float:
    """Chi-square test that ``sample`` draws unit directions with density ``pdf``.

    sample : u (n, 2) uniform in [0, 1) -> dirs (n, 3) (extra return values are ignored);
    pdf : dirs (m, 3) -> (m,) solid-angle density. Directions are histogrammed on ``res`` =
    (cos theta, phi) cells over ``cos_range`` (align it with a discontinuity of the pdf, e.g. a
    cone's edge, so every cell integrates a smooth function); the expected count of a cell is
    ``n`` times the pdf's integral over it. Cells expecting fewer than 5 samples are pooled
    into one; a sample outside every cell, or in a cell the pdf says is empty, fails at once.
    The null hypothesis is rejected below the Sidak-corrected level
    ``1 - (1 - alpha) ** (1 / tests)`` (``tests`` = checks in the family). Returns the p-value.
    """
    rng = np.random.default_rng(seed)
    out = sample(rng.random((n, 2)))
    d = np.asarray(out[0] if isinstance(out, tuple) else out, np.float64)
    cos_edges = np.linspace(cos_range[0], cos_range[1], res[0] + 1)
    phi_edges = np.linspace(0.0, 2.0 * np.pi, res[1] + 1)
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2.0 * np.pi)
    z = np.clip(d[:, 2], -1.0, 1.0)
    inside = (z >= cos_range[0] - 1e-12) & (z <= cos_range[1] + 1e-12)
    assert inside.all(), f"{int((~inside).sum())} of {n} samples outside cos theta {cos_range}"
    obs, _, _ = np.histogram2d(
        np.clip(z, cos_range[0], cos_range[1]), phi, bins=[cos_edges, phi_edges]
    )
    expected = n * _cell_integrals(pdf, cos_edges, phi_edges, sub)
    empty = (expected <= 0.0) & (obs > 0)
    assert not empty.any(), f"{int(obs[empty].sum())} samples where the pdf is 0"
    obs, expected = obs.ravel(), expected.ravel()
    order = np.argsort(expected)
    obs, expected = obs[order], expected[order]
    pool = np.cumsum(expected) < 5.0  # smallest cells, pooled until they expect 5
    pool |= expected < 5.0
    o = np.concatenate([[obs[pool].sum()], obs[~pool]]) if pool.any() else obs
    e = np.concatenate([[expected[pool].sum()], expected[~pool]]) if pool.any() else expected
    keep = e > 0
    o, e = o[keep], e[keep]
    stat = float(((o - e) ** 2 / e).sum())
    dof = len(e) - 1
    p = chi2_sf(stat, dof)
    level = 1.0 - (1.0 - alpha) ** (1.0 / tests)
    assert p >= level, (
        f"chi-square {stat:.1f} on {dof} dof: p = {p:.3g} < {level:.3g}; the sampler does not "
        "draw the density its pdf claims"
    )
    return p
