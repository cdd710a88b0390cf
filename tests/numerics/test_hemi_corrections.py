"""One test per corrected row of the 2024 paper (issue 2's corrections table) that hemi.py uses.

Each test shows the printed value disagrees with brute-force quadrature and ours agrees to
TOL (1e-10: every reference here is an exact quadrature, so only rounding remains).
"""

import numpy as np

from tests._hemi_brute import (
    cap_quadrature,
    frame,
    lune_integral,
    tangent_hlsh_matrix_reference,
)
from usdahd.numerics import hemi, sh

TOL = 1e-10  # exact quadratures: the remaining error is float64 rounding
WRONG = 1e-3  # a printed value counts as wrong when it misses the reference by more than this

R5, SPI, S3PI = np.sqrt(5.0), np.sqrt(np.pi), np.sqrt(3 * np.pi)


def test_eq47_gram_row6_col2_is_3sqrt5_over_16():
    d, w = cap_quadrature(0.0, None, 8, 16)  # products of SH are degree <= 4: exact
    y = sh.basis(d)
    gram = np.einsum("nk,nl,n->kl", y, y, w)
    printed, ours = 3 * R5 / 15, hemi.HEMISPHERE_GRAM[5, 1]
    assert abs(printed - gram[5, 1]) > WRONG
    np.testing.assert_allclose(ours, 3 * R5 / 16, rtol=0, atol=0)
    np.testing.assert_allclose(hemi.HEMISPHERE_GRAM, gram, atol=TOL)
    np.testing.assert_array_equal(hemi.HEMISPHERE_GRAM, hemi.HEMISPHERE_GRAM.T)


def _p2_by_definition(l2, n):
    """[l2^-1', 0, l2^1'] in the frame with z' = n, rotated back (SH slot order), by quadrature."""
    d, w = cap_quadrature(-1.0, None, 16, 32)  # whole sphere, exact for degree <= 4
    f2 = l2 @ sh.basis(d)[:, 4:].T
    fr = frame(n)
    loc = d @ fr.T  # local coordinates x', y', z'
    c2 = np.sqrt(15 / (4 * np.pi))
    lm1 = np.sum(w * f2 * (-c2 * loc[:, 1] * loc[:, 2]))
    lp1 = np.sum(w * f2 * (-c2 * loc[:, 0] * loc[:, 2]))
    v = fr.T @ np.array([-lp1, -lm1, 0.0])  # linear SH [c-1, c0, c1] <-> v = (-c1, -c-1, c0)
    return np.array([-v[1], v[2], -v[0]])


def test_eq35_row2_col5_is_times_nz():
    rng = np.random.default_rng(35)
    n = np.array([0.6, -0.3, 0.2])
    n /= np.linalg.norm(n)
    l2 = np.array([0.0, 0.0, 0.0, 0.0, 1.0])  # only l2^2 exercises column 5
    ref = _p2_by_definition(l2, n)
    ours = hemi.p2_vector(l2, n)
    x, y, z = n
    printed = ours.copy()
    printed[1] += (y * y - x * x) * x - (y * y - x * x) * z  # the printed "... n_x" entry
    assert abs(printed[1] - ref[1]) > WRONG
    np.testing.assert_allclose(ours, ref, atol=TOL)
    for _ in range(5):  # and the whole matrix on random input
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        l2 = rng.normal(size=5)
        np.testing.assert_allclose(hemi.p2_vector(l2, n), _p2_by_definition(l2, n), atol=TOL)


def test_eq43_hemisphere_irradiance_is_sqrt3pi_over_3():
    h = np.array([0.3, -0.4, 0.5])
    h /= np.linalg.norm(h)
    n = np.array([-0.7, 0.1, 0.2])
    n /= np.linalg.norm(n)
    # brute force: normalized irradiance in n of a unit hemisphere light around h (a lune)
    ref = lune_integral(lambda d: d @ n, h, n) / np.pi
    hsh = np.array([-h[1], h[2], -h[0]])
    printed = np.concatenate([[SPI], np.sqrt(3) * np.pi / 3 * hsh, np.zeros(5)])
    ours = hemi.hemisphere_light_irradiance_sh(h)
    assert abs(sh.evaluate(printed[None], n)[0] - ref) > WRONG
    np.testing.assert_allclose(ours[1:4], S3PI / 3 * hsh, rtol=1e-15)
    np.testing.assert_allclose(sh.evaluate(ours[None], n)[0], ref, atol=TOL)
    np.testing.assert_allclose(ref, (1 + h @ n) / 2, atol=TOL)  # Eq 45


def test_eq37_is_band4_multiply_with_untruncated_iz():
    ref = tangent_hlsh_matrix_reference(0.0, lmax=4, iz_mode="exact")
    np.testing.assert_allclose(hemi.HLSH_HEMISPHERE_MATRIX, ref, atol=TOL)
    # the printed rationals, reproduced exactly by this reading
    assert round(ref[0, 2] * 8192 * S3PI, 9) == 2203
    assert round(-ref[1, 3] * 4096 * S3PI, 9) == 2573
    assert round(-ref[2, 1] * 4096 * S3PI, 9) == 2573
    np.testing.assert_allclose(ref[0, [0, 6]], [1 / (4 * SPI), -7 * R5 / (128 * SPI)], atol=TOL)
    np.testing.assert_allclose(ref[1, 7], -11 * np.sqrt(15) / (128 * SPI), atol=TOL)
    # other readings of "order-4 multiply" do not reproduce them
    trunc = tangent_hlsh_matrix_reference(0.0, lmax=4, iz_mode="truncated")
    band2 = tangent_hlsh_matrix_reference(0.0, lmax=2, iz_mode="exact")
    np.testing.assert_allclose(trunc[0, 2] * 8192 * S3PI, 2211, atol=1e-8)
    np.testing.assert_allclose(band2[0, 2] * 8192 * S3PI, 2200, atol=1e-8)
    np.testing.assert_allclose(-band2[1, 3] * 4096 * S3PI, 2588, atol=1e-8)


def test_eq20_iz_term_integrates_over_upper_hemisphere():
    # B = (1 - z, x, y); Eq 22's pi/3 is int_{Omega+} B z, not int_Omega B z = -4 pi / 3.
    def b_z(cos_alpha):
        d, w = cap_quadrature(cos_alpha, None, 8, 16)
        b = np.stack([1 - d[:, 2], d[:, 0], d[:, 1]], -1)
        return np.einsum("ni,n->i", b * d[:, 2:3], w)

    upper, sphere = b_z(0.0), b_z(-1.0)
    np.testing.assert_allclose(hemi.HLSH_B_Z, upper, atol=TOL)
    assert abs(sphere[0] - np.pi / 3) > WRONG
    # Eq 22 with the Omega+ term is the constrained least-squares optimum (brute-force lstsq).
    rng = np.random.default_rng(20)
    i = rng.normal(size=9)  # irradiance SH
    iz = sh.evaluate(i[None], [0.0, 0.0, 1.0])[0]
    d, w = cap_quadrature(0.0, None, 8, 16)
    b = np.stack([1 - d[:, 2], d[:, 0], d[:, 1]], -1)
    target = sh.evaluate(i[None], d)[:, 0] - iz * d[:, 2]
    sw = np.sqrt(w)
    brute = np.linalg.lstsq(b * sw[:, None], target * sw, rcond=None)[0]
    g_by = np.einsum("ni,nk,n->ik", b, sh.basis(d), w)
    eq22 = np.linalg.solve(hemi.HLSH_GRAM_B, g_by @ i - iz * hemi.HLSH_B_Z)
    np.testing.assert_allclose(eq22, brute, atol=TOL)
    wrong = np.linalg.solve(hemi.HLSH_GRAM_B, g_by @ i - iz * sphere)
    assert np.abs(wrong - brute).max() > WRONG
