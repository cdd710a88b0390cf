"""Brute-force references for tests/test_hemi*.py: exact quadrature, no closed forms.

Every integrand below is a polynomial of bounded degree on the region it is integrated over
(a cap z' > cos(alpha) of a rotated frame), so Gauss-Legendre in z' times a uniform rule in phi
is exact to rounding; the band-l projections use the Legendre addition theorem
``sum_m Y_lm(a) Y_lm(b) = (2l+1)/(4 pi) P_l(a.b)``, which is basis-free.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from usdahd.numerics import sh

#: Normalized clamped-cosine band factors A_l (radiance -> irradiance), l = 0..6.
A_L = [1.0, 2.0 / 3.0, 1.0 / 4.0, 0.0, -1.0 / 24.0, 0.0, 1.0 / 64.0]


def frame(n):
    """Rows t1, t2, n of a right-handed orthonormal frame with third axis n (3,)."""
    n = np.asarray(n, float)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(a, n)
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n])


def cap_quadrature(cos_alpha=0.0, n=None, n_theta=24, n_phi=48):
    """Exact rule on the cap {w : w.n > cos_alpha} (n defaults to z). returns dirs, weights."""
    u, wu = legendre.leggauss(n_theta)
    z = cos_alpha + (1 - cos_alpha) * (u + 1) / 2
    wz = wu * (1 - cos_alpha) / 2
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    s = np.sqrt(np.clip(1 - z * z, 0, None))
    x, y = (s[:, None] * np.cos(phi)).ravel(), (s[:, None] * np.sin(phi)).ravel()
    d = np.stack([x, y, np.repeat(z, n_phi)], -1)
    w = np.repeat(wz, n_phi) * (2 * np.pi / n_phi)
    if n is not None:
        d = d @ frame(n)
    return d, w


def convolution_kernel(a, b, lmax, factors=A_L):
    """sum_{l<=lmax} A_l (2l+1)/(4 pi) P_l(a.b): projects into bands <= lmax and convolves."""
    cos = np.clip(a @ b.T, -1, 1)
    return sum(
        factors[l] * (2 * l + 1) / (4 * np.pi) * legendre.legval(cos, [0] * l + [1])
        for l in range(lmax + 1)
    )


def hlsh_multiply_reference(l, n, cos_alpha=0.0, lmax=4, iz_mode="exact"):
    """Cone-multiply radiance SH ``l`` (C, 9) around ``n``, convolve through band ``lmax``, solve
    the IrradZ-constrained HLSH least squares over the hemisphere around n (2024 Eq 19-22).

    iz_mode: "exact" (I_z of the untruncated product) or "truncated" (of the band-lmax one).
    returns ca (C,), c (C, 3) Cartesian, iz (C,).
    """
    n = np.asarray(n, float)
    f = frame(n)
    dc, wc = cap_quadrature(cos_alpha, n)  # where the masked radiance lives
    dh, wh = cap_quadrature(0.0, n)  # where the error is measured
    rad = np.asarray(l, float) @ sh.basis(dc).T  # (C, nc)
    irr = (convolution_kernel(dh, dc, lmax) @ (wc * rad).T).T  # (C, nh)
    if iz_mode == "exact":
        iz = (rad * (dc @ n) * wc).sum(-1) / np.pi
    else:
        iz = (convolution_kernel(n[None], dc, lmax) @ (wc * rad).T)[0]
    t = dh @ f.T  # local coordinates
    b = np.stack([1 - t[:, 2], t[:, 0], t[:, 1]], -1)
    gb = np.einsum("ni,nj,n->ij", b, b, wh)
    bz = np.einsum("ni,n->i", b * t[:, 2:3], wh)
    rhs = np.einsum("ni,cn,n->ci", b, irr, wh) - iz[:, None] * bz
    sol = np.linalg.solve(gb, rhs.T).T  # (C, 3): ca, cx, cy in the local frame
    ca = sol[:, 0]
    c = sol[:, 1:2] * f[0] + sol[:, 2:3] * f[1] + (iz - ca)[:, None] * f[2]
    return ca, c, iz


def tangent_hlsh_matrix_reference(cos_alpha=0.0, lmax=4, iz_mode="exact"):
    """(3, 9) matrix radiance SH -> [C_a, c_x, c_y] in tangent space, by the reference above."""
    eye = np.eye(9)
    ca, c, _ = hlsh_multiply_reference(eye, [0.0, 0.0, 1.0], cos_alpha, lmax, iz_mode)
    return np.stack([ca, c[:, 0], c[:, 1]])


def hemisphere_project(l, n, lmax_out=1):
    """First (lmax_out+1)^2 SH coefficients of H_n(w) * (l . Y(w)), l (C, 9). Exact."""
    d, w = cap_quadrature(0.0, n, 16, 32)
    y = sh.basis(d)
    k = (lmax_out + 1) ** 2
    return np.einsum("cn,nk,n->ck", np.asarray(l, float) @ y.T, y[:, :k], w)


def lune_integral(f, h, m, n_t=48, n_psi=96):
    """Integral of f(w) over the lune {h.w > 0, m.w > 0} for unit h, m not parallel.

    With a = h x m / |h x m|, w = sin(b) a + cos(b)(cos psi h + sin psi (a x h)),
    dw = cos(b) db dpsi, and the lune is psi in (gamma - pi/2, pi/2), gamma = angle(h, m). f must
    be smooth on the lune (e.g. polynomial): Gauss-Legendre in b and psi then converges
    spectrally (the integrand is analytic in both).
    f : (n, 3) -> (n, ...). returns : (...).
    """
    h, m = np.asarray(h, float), np.asarray(m, float)
    a = np.cross(h, m)
    a /= np.linalg.norm(a)
    e2 = np.cross(a, h)
    gamma = np.arccos(np.clip(h @ m, -1, 1))
    u_b, w_b = legendre.leggauss(n_t)
    beta = u_b * np.pi / 2
    t = np.sin(beta)
    wt = w_b * (np.pi / 2) * np.cos(beta)
    u, wu = legendre.leggauss(n_psi)
    lo, hi = gamma - np.pi / 2, np.pi / 2
    psi = lo + (hi - lo) * (u + 1) / 2
    wpsi = wu * (hi - lo) / 2
    s = np.cos(beta)
    circ = np.cos(psi)[:, None] * h + np.sin(psi)[:, None] * e2  # (n_psi, 3)
    d = (t[:, None, None] * a + s[:, None, None] * circ[None]).reshape(-1, 3)
    w = (wt[:, None] * wpsi[None]).reshape(-1)
    v = np.asarray(f(d))
    return np.tensordot(w, v, axes=(0, 0))
