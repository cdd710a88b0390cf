"""IrradZ numba kernels and their driver :func:`fit`.

Work arrays have named rows (``_BLK_*``, ``_WK_*``). Every constant the kernels read is a
module-level global frozen at compile time; the ones from other modules are tracked for the
on-disk cache by :mod:`usdahd.numerics.numba_cache`. numpy twins: :mod:`.reference`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from usdahd.errors import InputError, UsageError
from usdahd.models.base import check_choice
from usdahd.models.irradz import reference
from usdahd.models.irradz.reference import (
    DZ_FLOOR,
    GOLDEN_ITERS,
    GOLDEN_SCAN,
    GRAM_I,
    GRAM_J,
    IZ_MAX,
    IZ_TINY,
    KINDS,
    PHI_HALF_WIDTH,
    PHI_ITERS,
    PHI_SCAN,
    SOLVERS,
    SQRT_PI,
    WA_ONE,
    ambient_sh,
    gram_hemi,
    sparse_gram,
)
from usdahd.numerics import encoding, numba_cache
from usdahd.numerics import sh as shm

__all__ = ["BLK_ROWS", "BLOCK", "dir_error", "fit", "line_coeffs", "line_error"]

# ---------------------------------------------------------------------------------------------
# numba kernels. The directional light of colour C_d in direction d has irradiance SH
# C_d * pi * conv(Y(d)); with the I_z constraint C_a = I_z - d_z C_d the model is
#   M = I_z a + C_d u,   u = pi conv(Y(d)) - d_z a,
# so for a target t the hemispherical error is E(C_d) = e0 - 2 C_d p + C_d^2 q with
# e0 = r^T G r, r = t - I_z a, p = u^T G r, q = u^T G u: quadratic, minimised in closed form
# (this is Eq 33 solved for C_d = c I_z; w_a = 1 - c d_z) and clipped to the feasible
# interval C_d in [0, I_z / d_z] <=> w_a in [0, 1] <=> 2018's t in [t_min, t_max].

_PK0 = np.pi * shm.C0
_PK1 = np.pi * (2.0 / 3.0) * shm.C1
_PK2 = np.pi * 0.25 * shm.C2
_PK20 = np.pi * 0.25 * shm.C20
_PK22 = np.pi * 0.25 * shm.C22


@njit(cache=True, fastmath=False)
def dir_error(dx, dy, dz, gt, e0, iz, nc, amb, gd, go, constrain, u, cd):
    """Error of the best colours for direction d; writes C_d per channel into cd."""
    u[0] = _PK0 - dz * amb[0]
    u[1] = -_PK1 * dy - dz * amb[1]
    u[2] = _PK1 * dz - dz * amb[2]
    u[3] = -_PK1 * dx - dz * amb[3]
    u[4] = _PK2 * dx * dy - dz * amb[4]
    u[5] = -_PK2 * dy * dz - dz * amb[5]
    u[6] = _PK20 * (3.0 * dz * dz - 1.0) - dz * amb[6]
    u[7] = -_PK2 * dx * dz - dz * amb[7]
    u[8] = _PK22 * (dx * dx - dy * dy) - dz * amb[8]
    q = 0.0
    for k in range(9):
        q += gd[k] * u[k] * u[k]
    q += 2.0 * (go[0] * u[0] * u[2] + go[1] * u[1] * u[5] + go[2] * u[2] * u[6])
    q += 2.0 * go[3] * u[3] * u[7]
    err = 0.0
    for c in range(nc):
        p = 0.0
        for k in range(9):
            p += gt[c, k] * u[k]
        x = p / q if q > 0.0 else 0.0
        if constrain:
            hi = iz[c] / dz
            if x > hi:
                x = hi
            if x < 0.0:
                x = 0.0
        cd[c] = x
        err += e0[c] - 2.0 * x * p + x * x * q
    return err


@njit(cache=True, fastmath=False)
def line_coeffs(cph, sph, gt, e0, iz, nc, amb, gd, go, j, blk):
    """Store texel j's error along the azimuth (cos, sin) = (cph, sph) into the block ``blk``.

    With d = (s cph, s sph, z), s = sqrt(1 - z^2), and an ambient term nonzero only in
    coefficients 0 and 2 (AMB_AHD, AMB_HHD), every u_k is a combination of 1, z, z^2, s, s z,
    so  p_c(z) = R[c] . (1, z, z^2, s, s z)  and, with s^2 = 1 - z^2 and the sparse Gram,
    q(z) = u^T G u = sum_k Q[k] z^k (degree 4, no s term). blk rows: R (15: c * 5 + k),
    Q (5), e0 (3), I_z (3); see _BLK_*. Checked against :func:`dir_error` in the tests.
    """
    a0 = amb[0]
    b = _PK1 - amb[2]
    cs = cph * sph
    w = cph * cph - sph * sph
    s2 = sph * sph
    c2 = cph * cph
    for c in range(nc):
        r = 5 * c
        blk[r, j] = gt[c, 0] * _PK0 + gt[c, 4] * _PK2 * cs - gt[c, 6] * _PK20 + gt[c, 8] * _PK22 * w
        blk[r + 1, j] = gt[c, 2] * b - gt[c, 0] * a0
        blk[r + 2, j] = 3.0 * gt[c, 6] * _PK20 - gt[c, 4] * _PK2 * cs - gt[c, 8] * _PK22 * w
        blk[r + 3, j] = -_PK1 * (gt[c, 1] * sph + gt[c, 3] * cph)
        blk[r + 4, j] = -_PK2 * (gt[c, 5] * sph + gt[c, 7] * cph)
        blk[_BLK_E0 + c, j] = e0[c]
        blk[_BLK_IZ + c, j] = iz[c]
    k4 = gd[4] * (_PK2 * cs) ** 2 + gd[8] * (_PK22 * w) ** 2  # u4, u8 ~ (1 - z^2)
    m57 = _PK2 * _PK2 * (gd[5] * s2 + gd[7] * c2)  # u5, u7 ~ s z
    l13 = _PK1 * _PK1 * (gd[1] * s2 + gd[3] * c2)  # u1, u3 ~ s
    g6 = gd[6] * _PK20 * _PK20  # u6 ~ 3 z^2 - 1
    n15 = 2.0 * _PK1 * _PK2 * (go[1] * s2 + go[3] * c2)  # u1 u5, u3 u7 ~ (1 - z^2) z
    o26 = 2.0 * go[2] * b * _PK20  # u2 u6 ~ 3 z^3 - z
    o02 = 2.0 * go[0] * b  # u0 u2 ~ (PK0 - a0 z) z
    q = _BLK_Q
    blk[q, j] = gd[0] * _PK0 * _PK0 + l13 + k4 + g6
    blk[q + 1, j] = -2.0 * gd[0] * _PK0 * a0 + o02 * _PK0 + n15 - o26
    blk[q + 2, j] = gd[0] * a0 * a0 - l13 + gd[2] * b * b - 2.0 * k4 + m57 - 6.0 * g6 - o02 * a0
    blk[q + 3, j] = 3.0 * o26 - n15
    blk[q + 4, j] = k4 - m57 + 9.0 * g6


@njit(cache=True, fastmath=False)
def line_error(z, j, blk, nc, cdb, write):
    """:func:`dir_error` (constrained) of block texel j at d_z = z along its azimuth, from the
    coefficients of :func:`line_coeffs`; writes C_d into cdb[:, j] if ``write``."""
    s = np.sqrt(max(0.0, 1.0 - z * z))
    q = _BLK_Q
    qz = blk[q, j] + z * (
        blk[q + 1, j] + z * (blk[q + 2, j] + z * (blk[q + 3, j] + z * blk[q + 4, j]))
    )
    err = 0.0
    for c in range(nc):
        r = 5 * c
        p = (
            blk[r, j]
            + z * (blk[r + 1, j] + z * blk[r + 2, j])
            + s * (blk[r + 3, j] + z * blk[r + 4, j])
        )
        x = p / qz if qz > 0.0 else 0.0
        izc = blk[_BLK_IZ + c, j]
        x = izc / z if x * z > izc else x
        x = 0.0 if x < 0.0 else x
        if write:
            cdb[c, j] = x
        err += blk[_BLK_E0 + c, j] - 2.0 * x * p + x * x * qz
    return err


@njit(cache=True, fastmath=False)
def _search_block(m, lo, blk, nc, wk, fs, cdb):
    """d_z search (solver "golden") for block texels 0..m-1, in lockstep and branch-free so
    that the texels' serial dependency chains overlap (a per-texel search is latency- and
    branch-miss-bound). Scan GOLDEN_SCAN points; golden section on the bracket around the best
    one for GOLDEN_ITERS steps; one parabolic step through the best golden point and its
    bracket neighbours, kept only where it lowers the error. Writes d_z into wk[_WK_Z],
    the error into wk[_WK_E], C_d into cdb[:, j]."""
    n_scan = fs.shape[0]
    step = (1.0 - lo) / (n_scan - 1)
    for j in range(m):
        wk[_WK_E, j] = np.inf
        wk[_WK_Z, j] = 1.0
        wk[_WK_J, j] = 0.0
    for k in range(n_scan):
        z = lo + step * k
        for j in range(m):
            e = line_error(z, j, blk, nc, cdb, False)
            fs[k, j] = e
            better = e < wk[_WK_E, j]
            wk[_WK_E, j] = e if better else wk[_WK_E, j]
            wk[_WK_Z, j] = z if better else wk[_WK_Z, j]
            wk[_WK_J, j] = k if better else wk[_WK_J, j]
    g = 0.6180339887498949
    for j in range(m):
        jb = int(wk[_WK_J, j])
        ja = max(jb - 1, 0)
        jc = min(jb + 1, n_scan - 1)
        a = lo + step * ja
        b = lo + step * jc
        wk[_WK_A, j] = a
        wk[_WK_B, j] = b
        wk[_WK_FA, j] = fs[ja, j]
        wk[_WK_FB, j] = fs[jc, j]
        wk[_WK_X1, j] = b - g * (b - a)
        wk[_WK_X2, j] = a + g * (b - a)
        wk[_WK_F1, j] = line_error(wk[_WK_X1, j], j, blk, nc, cdb, False)
        wk[_WK_F2, j] = line_error(wk[_WK_X2, j], j, blk, nc, cdb, False)
    for _ in range(GOLDEN_ITERS):
        for j in range(m):
            a = wk[_WK_A, j]
            b = wk[_WK_B, j]
            x1 = wk[_WK_X1, j]
            x2 = wk[_WK_X2, j]
            f1 = wk[_WK_F1, j]
            f2 = wk[_WK_F2, j]
            left = f1 < f2  # minimum in [a, x2]: drop (x2, b]
            na = a if left else x1
            nb = x2 if left else b
            xn = nb - g * (nb - na) if left else na + g * (nb - na)
            fn = line_error(xn, j, blk, nc, cdb, False)
            wk[_WK_FA, j] = wk[_WK_FA, j] if left else f1
            wk[_WK_FB, j] = f2 if left else wk[_WK_FB, j]
            wk[_WK_A, j] = na
            wk[_WK_B, j] = nb
            wk[_WK_X1, j] = xn if left else x2
            wk[_WK_X2, j] = x1 if left else xn
            wk[_WK_F1, j] = fn if left else f2
            wk[_WK_F2, j] = f1 if left else fn
    for j in range(m):
        f1 = wk[_WK_F1, j]
        f2 = wk[_WK_F2, j]
        left = f1 < f2
        xl = wk[_WK_A, j] if left else wk[_WK_X1, j]
        xm = wk[_WK_X1, j] if left else wk[_WK_X2, j]
        xr = wk[_WK_X2, j] if left else wk[_WK_B, j]
        fl = wk[_WK_FA, j] if left else f1
        fm = f1 if left else f2
        fr = f2 if left else wk[_WK_FB, j]
        d1 = xm - xl
        d2 = xm - xr
        g1 = (fm - fl) * d2
        g2 = (fm - fr) * d1
        den = g2 - g1
        u = xm - 0.5 * (d1 * g2 - d2 * g1) / den if den != 0.0 else xm
        u = u if (u > xl and u < xr) else xm  # also rejects NaN
        fu = line_error(u, j, blk, nc, cdb, False)
        best = fu < fm
        zb = u if best else xm
        eb = fu if best else fm
        scan = wk[_WK_E, j] <= eb  # the scan point itself stays a candidate
        wk[_WK_Z, j] = wk[_WK_Z, j] if scan else zb
        wk[_WK_E, j] = wk[_WK_E, j] if scan else eb
    for j in range(m):
        line_error(wk[_WK_Z, j], j, blk, nc, cdb, True)


@njit(cache=True, fastmath=False)
def _search_dz(cph, sph, gt, e0, iz, nc, amb, gd, go, blk, wk, fs, cdb, cd_best):
    """The block search for one texel (slot 0) along (cph, sph): returns (d_z, error), C_d in
    cd_best. Same code path as the block, so golden_phi starts from golden's exact result."""
    slot = np.int64(0)  # np.int64: a literal argument would compile the callees once more
    line_coeffs(cph, sph, gt, e0, iz, nc, amb, gd, go, slot, blk)
    _search_block(slot + 1, DZ_FLOOR, blk, nc, wk, fs, cdb)
    for c in range(nc):
        cd_best[c] = cdb[c, 0]
    return wk[_WK_Z, 0], wk[_WK_E, 0]


_IZ_K = shm.IZ_FROM_L10
_BC_K = 2.0 / np.sqrt(np.pi)
_GB0 = SQRT_PI / 2.0
_GB2 = np.sqrt(np.pi / 12.0)
_GB6 = -np.sqrt(5.0 * np.pi) / 8.0
_GB1 = -np.sqrt(np.pi / 3.0)
_GB2X = -np.sqrt(15.0 * np.pi) / 8.0
_GBS = 2.0 * np.pi / 3.0
_COS1 = 2.0 / 3.0
_COS2 = 0.25
_LUM_R, _LUM_G, _LUM_B = (float(v) for v in shm.LUMINANCE)
#: Texels per parallel chunk (each chunk allocates its work arrays once).
_CHUNK = 512
#: Texels per lockstep d_z search block (its work arrays stay in L1).
BLOCK = 64
#: Rows of the block coefficient array: R (3 x 5), Q (5), e0 (3), I_z (3).
_BLK_Q = 15
_BLK_E0 = 20
_BLK_IZ = 23
BLK_ROWS = 26
#: Rows of the block search work array.
_WK_Z, _WK_E, _WK_J, _WK_A, _WK_B, _WK_FA, _WK_FB, _WK_X1, _WK_X2, _WK_F1, _WK_F2 = range(11)
_WK_ROWS = 11

#: solver codes of the kernel
_FIXED, _GOLDEN, _GOLDEN_PHI, _DIRECT = 0, 1, 2, 3
_KIND = {"ahd": 0, "hhd": 1, "hlsh": 2}


@njit(cache=True, fastmath=False)
def _floor_dir(d):
    """In place: d_z >= DZ_FLOOR keeping the azimuth; returns True if d was moved."""
    if d[2] >= DZ_FLOOR:
        return False
    nxy = np.sqrt(d[0] * d[0] + d[1] * d[1])
    s = np.sqrt(1.0 - DZ_FLOOR * DZ_FLOOR)
    if nxy > 0.0:
        d[0] = d[0] / nxy * s
        d[1] = d[1] / nxy * s
    else:
        d[0] = s
        d[1] = 0.0
    d[2] = DZ_FLOOR
    return True


@njit(cache=True, fastmath=False)
def _set_unit(d, x, y, z):
    nv = np.sqrt(x * x + y * y + z * z)
    if nv > 0.0:
        d[0] = x / nv
        d[1] = y / nv
        d[2] = z / nv
    else:
        d[0] = 0.0
        d[1] = 0.0
        d[2] = 1.0


@njit(cache=True, fastmath=False)
def _prep_gt(t, iz, nc, amb, gd, go, gt, e0, r):
    """gt[c] = G (t_c - I_z,c a), e0[c] = (t_c - I_z,c a)^T G (t_c - I_z,c a)."""
    for c in range(nc):
        for k in range(9):
            r[k] = t[c, k] - iz[c] * amb[k]
        e = 0.0
        for k in range(9):
            gt[c, k] = gd[k] * r[k]
            e += gd[k] * r[k] * r[k]
        for m in range(4):
            a = GRAM_I[m]
            b = GRAM_J[m]
            gt[c, a] += go[m] * r[b]
            gt[c, b] += go[m] * r[a]
            e += 2.0 * go[m] * r[a] * r[b]
        e0[c] = e


@njit(cache=True, fastmath=False)
def _prep_shared(t, iz, amb, gd, go, gt, e0, r, gt3, e03):
    """One virtual channel whose error is the summed RGB error of the luminance-ratio model.

    With one k = (1 - w_a)/d_z for all channels, C_d,c = I_z,c k and
    sum_c E_c(k) = sum_c e0_c - 2 k sum_c I_z,c p_c + k^2 q sum_c I_z,c^2 = S (e0' - 2 k p' + k^2 q)
    with S = sum_c I_z,c^2, p' = u^T gt' , gt' = sum_c I_z,c G r_c / S, e0' = sum_c e0_c / S:
    the single-channel problem with I_z' = 1 (so C_d' = k and w_a = 1 - k d_z)."""
    _prep_gt(t, iz, np.int64(3), amb, gd, go, gt3, e03, r)  # not a literal 3: see _search_dz
    s = iz[0] * iz[0] + iz[1] * iz[1] + iz[2] * iz[2]
    for k in range(9):
        gt[0, k] = (iz[0] * gt3[0, k] + iz[1] * gt3[1, k] + iz[2] * gt3[2, k]) / s
    e0[0] = (e03[0] + e03[1] + e03[2]) / s


@njit(cache=True, fastmath=False)
def _search_phi(phi0, gt, e0, iz, nc, amb, gd, go, blk, wk, fs, cdb, cdp, cd_best):
    """d_z search at phi0, then an outer scan (PHI_SCAN) + golden search (PHI_ITERS) of phi
    around it, with the inner d_z search at every phi. returns (d_z, phi); C_d in cd_best.
    Written as one loop with one call site of the inner search (compile time)."""
    pa = phi0 - PHI_HALF_WIDTH
    pstep = 2.0 * PHI_HALF_WIDTH / (PHI_SCAN - 1)
    g = 0.6180339887498949
    e = np.inf
    bz = 1.0
    bphi = phi0
    bj = -1
    a = b = x1 = x2 = f1 = 0.0
    for it in range(1 + PHI_SCAN + 2 * PHI_ITERS):
        gi = it - 1 - PHI_SCAN  # golden step 2 * (gi // 2) + (0: x1, 1: x2)
        if it == 0:
            ph = phi0
        elif gi < 0:
            ph = pa + pstep * (it - 1)
        else:
            if gi == 0:
                if bj >= 0:
                    a = pa + pstep * max(bj - 1, 0)
                    b = pa + pstep * min(bj + 1, PHI_SCAN - 1)
                else:
                    a = phi0 - pstep
                    b = phi0 + pstep
            if gi % 2 == 0:
                x1 = b - g * (b - a)
                x2 = a + g * (b - a)
                ph = x1
            else:
                ph = x2
        z, ej = _search_dz(
            np.cos(ph), np.sin(ph), gt, e0, iz, nc, amb, gd, go, blk, wk, fs, cdb, cdp
        )
        if ej < e:
            e, bz, bphi = ej, z, ph
            for c in range(3):  # not cd_best[:] = cdp (its shape checks cost ~2 s compile)
                cd_best[c] = cdp[c]
            if it > 0 and gi < 0:
                bj = it - 1
        if gi >= 0:
            if gi % 2 == 0:
                f1 = ej
            elif f1 < ej:
                b = x2
            else:
                a = x1
    return bz, bphi


@njit(cache=True, fastmath=False, inline="always")
def _finish(i, kind, nc, siz, cdb, d, wa, clamp, out_d, out_wa):
    """w_a from C_d (if cdb is given a size), clamp to [0, 1] (ahd, hhd), d = z where no
    directional light is left; write out_d[i], out_wa[i]."""
    for c in range(cdb.shape[0]):
        # w_a = 1 - c d_z with c = C_d / I_z (bounded): never divides by d_z
        wa[c] = (siz[c] - cdb[c] * d[2]) / siz[c] if siz[c] > IZ_TINY else 1.0
    if clamp:
        for c in range(nc):
            wa[c] = min(max(wa[c], 0.0), 1.0)
    flat = True
    for c in range(nc):
        if kind == 2:
            if abs(wa[c] - 1.0) > 1.0 - WA_ONE:
                flat = False
        elif wa[c] < WA_ONE:
            flat = False
    if flat:
        for c in range(nc):
            wa[c] = 1.0
        d[0] = 0.0
        d[1] = 0.0
        d[2] = 1.0
    for c in range(3):
        out_d[i, c] = d[c]
    for c in range(nc):
        out_wa[i, c] = wa[c]


@njit(cache=True, fastmath=False)
def _flush_block(nb, kind, nc, blk, wk, fs, cdbk, bidx, bdir, bsiz, d, siz, cdb, wa, out_d, out_wa):
    """Run the lockstep d_z search of the nb deferred texels and write their d and w_a."""
    _search_block(nb, DZ_FLOOR, blk, nc, wk, fs, cdbk)
    for j in range(nb):
        bz = wk[_WK_Z, j]
        sn = np.sqrt(max(0.0, 1.0 - bz * bz))
        d[0] = sn * bdir[0, j]
        d[1] = sn * bdir[1, j]
        d[2] = bz
        _floor_dir(d)
        for c in range(nc):
            siz[c] = bsiz[c, j]
            cdb[c] = cdbk[c, j]
        _finish(bidx[j], kind, nc, siz, cdb[:nc], d, wa, True, out_d, out_wa)


@njit(cache=True, fastmath=False, nogil=True)
def _fit_chunk(ch, x, kind, rgb, solver, shared, amb, gd, go, out_iz, out_d, out_wa, out_bad):
    """Chunk ``ch`` (texels ch * _CHUNK .. ) of :func:`_fit_kernel`: a serial kernel, compiled
    once and called from the parallel loop with an int64 ``ch`` (the parfor lowering re-types its
    index as uint64: a second compile of this whole body). Callees get no literal arguments
    (np.int64(0), not 0): numba compiles a callee once more for each literal. Fit compile time
    19.1 -> 9.7 CPU s, results bit-identical (docs/time-to-quality.md, "Cold start")."""
    n = x.shape[0]
    nc = 3 if rgb else 1
    xn = np.empty((3, 9))
    t = np.empty((3, 9))
    iz = np.empty(3)
    st = np.empty((3, 9))  # signal: luminance (1 row) or rgb (3 rows) target irradiance
    siz = np.empty(3)
    gt = np.empty((3, 9))
    gt3 = np.empty((3, 9))
    e03 = np.empty(3)
    e0 = np.empty(3)
    r = np.empty(9)
    u = np.empty(9)
    cdb = np.empty(3)
    cdp = np.empty(3)
    wa = np.empty(3)
    lr = np.empty(9)
    d = np.empty(3)
    blk = np.empty((BLK_ROWS, BLOCK))
    wk = np.empty((_WK_ROWS, BLOCK))
    fs = np.empty((GOLDEN_SCAN, BLOCK))
    cdbk = np.empty((3, BLOCK))
    bidx = np.empty(BLOCK, np.int64)
    bdir = np.empty((2, BLOCK))
    bsiz = np.empty((3, BLOCK))
    nb = np.int64(0)  # not a literal 0: see _search_dz
    i1 = min(n, (ch + 1) * _CHUNK)
    for i in range(ch * _CHUNK, i1 + 1):
        # -- a full block of deferred golden searches (or the chunk's rest): search them in
        # lockstep. One call site, so the search is compiled (inlined) once.
        if nb == BLOCK or (i == i1 and nb > 0):
            _flush_block(
                nb,
                kind,
                nc,
                blk,
                wk,
                fs,
                cdbk,
                bidx,
                bdir,
                bsiz,
                d,
                siz,
                cdb,
                wa,
                out_d,
                out_wa,
            )
            nb = 0
        if i == i1:
            break
        deferred = False
        done = False
        # -- normalise, detect NaN/Inf
        m = 0.0
        finite = True
        for c in range(3):
            for k in range(9):
                v = x[i, c, k]
                if not np.isfinite(v):
                    finite = False
                elif abs(v) > m:
                    m = abs(v)
        if not finite or m == 0.0:
            for c in range(3):
                out_iz[i, c] = 0.0
                out_d[i, c] = 0.0
            for c in range(nc):
                out_wa[i, c] = 1.0
            out_d[i, 2] = 1.0
            out_bad[i] = 0.0 if finite else 1.0
            continue
        out_bad[i] = 0.0
        for c in range(3):
            for k in range(9):
                xn[c, k] = x[i, c, k] / m  # not * (1/m): 1/m overflows for subnormal m
                t[c, k] = xn[c, k] * (1.0 if k == 0 else (_COS1 if k < 4 else _COS2))
            iz[c] = max(_IZ_K * xn[c, 2], 0.0)  # I_z < 0 (ringing, leaks) -> 0
        for k in range(9):
            lr[k] = _LUM_R * xn[0, k] + _LUM_G * xn[1, k] + _LUM_B * xn[2, k]
        liz = _LUM_R * iz[0] + _LUM_G * iz[1] + _LUM_B * iz[2]
        if rgb:
            for c in range(3):
                siz[c] = iz[c]
                for k in range(9):
                    st[c, k] = t[c, k]
        else:
            siz[0] = liz
            for k in range(9):
                st[0, k] = _LUM_R * t[0, k] + _LUM_G * t[1, k] + _LUM_B * t[2, k]
        for c in range(nc):
            wa[c] = 1.0
        if liz <= IZ_TINY:
            d[0] = 0.0
            d[1] = 0.0
            d[2] = 1.0
        elif kind == 2:  # HLSH direct (Eq 22), direction from luminance, w_a per channel
            lt0 = _LUM_R * t[0, 0] + _LUM_G * t[1, 0] + _LUM_B * t[2, 0]
            lt1 = _LUM_R * t[0, 1] + _LUM_G * t[1, 1] + _LUM_B * t[2, 1]
            lt2 = _LUM_R * t[0, 2] + _LUM_G * t[1, 2] + _LUM_B * t[2, 2]
            lt3 = _LUM_R * t[0, 3] + _LUM_G * t[1, 3] + _LUM_B * t[2, 3]
            lt5 = _LUM_R * t[0, 5] + _LUM_G * t[1, 5] + _LUM_B * t[2, 5]
            lt6 = _LUM_R * t[0, 6] + _LUM_G * t[1, 6] + _LUM_B * t[2, 6]
            lt7 = _LUM_R * t[0, 7] + _LUM_G * t[1, 7] + _LUM_B * t[2, 7]
            ca = (_GB0 * lt0 + _GB2 * lt2 + _GB6 * lt6 - liz * (np.pi / 3.0)) / _GBS
            cx = (_GB1 * lt3 + _GB2X * lt7) / _GBS
            cy = (_GB1 * lt1 + _GB2X * lt5) / _GBS
            sz = liz - ca
            if sz < 0.0:  # w_a > 1: C_d < 0 and the direction flips, d_z stays >= 0
                _set_unit(d, -cx, -cy, -sz)
            else:
                _set_unit(d, cx, cy, sz)
            _floor_dir(d)
            for c in range(nc):
                b0 = (
                    _GB0 * st[c, 0] + _GB2 * st[c, 2] + _GB6 * st[c, 6] - siz[c] * (np.pi / 3.0)
                ) / _GBS
                b1 = (_GB1 * st[c, 3] + _GB2X * st[c, 7]) / _GBS
                b2 = (_GB1 * st[c, 1] + _GB2X * st[c, 5]) / _GBS
                s = d[2] * d[2] * (siz[c] - b0) + d[2] * (d[0] * b1 + d[1] * b2)
                wa[c] = (siz[c] - s) / siz[c] if siz[c] > IZ_TINY else 1.0
        else:
            need_ratio = True
            if solver == _DIRECT:  # HHD from linear SH, Eq 8, 56 (stable form), 10, 11
                bc = _BC_K * lr[0]
                bx = -_IZ_K * lr[3]
                by = -_IZ_K * lr[1]
                bz = _IZ_K * lr[2]
                disc = (bc - 2.0 * bz) ** 2 + 3.0 * (bx * bx + by * by)
                ca = ((2.0 * bc - bz) - np.sqrt(disc)) / 3.0
                ca = min(max(ca, 0.0), liz)
                _set_unit(d, bx, by, liz - ca)
                moved = _floor_dir(d)
                if not rgb and not moved and not shared:
                    wa[0] = ca / liz
                    need_ratio = False
            else:  # optimal linear direction (-l11, -l1-1, l10) of luminance
                _set_unit(d, -lr[3], -lr[1], lr[2])
                _floor_dir(d)
            if need_ratio:
                if shared:
                    _prep_shared(t, iz, amb, gd, go, gt, e0, r, gt3, e03)
                    siz[0] = 1.0
                else:
                    _prep_gt(st, siz, nc, amb, gd, go, gt, e0, r)
                if solver == _GOLDEN:  # deferred to the lockstep block search
                    nxy = np.sqrt(d[0] * d[0] + d[1] * d[1])
                    cph, sph = (d[0] / nxy, d[1] / nxy) if nxy > 0.0 else (1.0, 0.0)
                    line_coeffs(cph, sph, gt, e0, siz, nc, amb, gd, go, nb, blk)
                    bidx[nb] = i
                    bdir[0, nb] = cph
                    bdir[1, nb] = sph
                    for c in range(nc):
                        bsiz[c, nb] = siz[c]
                    nb += 1
                    deferred = True
                elif solver == _GOLDEN_PHI:
                    phi0 = np.arctan2(d[1], d[0])
                    bz, bphi = _search_phi(
                        phi0, gt, e0, siz, nc, amb, gd, go, blk, wk, fs, cdbk, cdp, cdb
                    )
                    sn = np.sqrt(max(0.0, 1.0 - bz * bz))
                    d[0] = sn * np.cos(bphi)
                    d[1] = sn * np.sin(bphi)
                    d[2] = bz
                    _floor_dir(d)
                else:
                    dir_error(d[0], d[1], d[2], gt, e0, siz, nc, amb, gd, go, True, u, cdb)
                if not deferred:
                    _finish(i, kind, nc, siz, cdb[:nc], d, wa, True, out_d, out_wa)
            else:
                _finish(i, kind, nc, siz, cdb[:0], d, wa, True, out_d, out_wa)
            done = True
        if not done:
            _finish(i, kind, nc, siz, cdb[:0], d, wa, kind != 2, out_d, out_wa)
        for c in range(3):
            out_iz[i, c] = min(iz[c] * m, IZ_MAX)


@njit(parallel=True, cache=True, fastmath=False)
def _fit_kernel(x, kind, rgb, solver, shared, amb, gd, go, out_iz, out_d, out_wa, out_bad):
    """The whole per-texel fit. x : (n, 3, 9) float64 radiance SH; outputs float32
    iz (n, 3), direction (n, 3), ambient ratio (n, 1|3), invalid (n,). ``shared``: one w_a
    (luminance ratio) minimising the summed RGB error instead of the luminance error
    (objective="rgb"). See :func:`fit`."""
    nchunk = (x.shape[0] + _CHUNK - 1) // _CHUNK
    for ch in prange(nchunk):
        _fit_chunk(
            np.int64(ch), x, kind, rgb, solver, shared, amb, gd, go, out_iz, out_d, out_wa, out_bad
        )


def fit(sh, kind: str, *, ratio: str = "luminance", solver: str = "golden", **options) -> dict:
    """Fit an IrradZ model to tangent-space radiance SH.

    sh : (..., 3, 9) float radiance SH (hemispherical: zero below the horizon).
    kind : "ahd", "hhd" or "hlsh"; ratio : "luminance" or "rgb"; solver : see SOLVERS[kind].
    objective (option, ratio="luminance" only; ahd/hhd with golden, golden_phi or direct):
    "luminance" (default) chooses d and the one w_a to minimise the error of the luminance
    signal; "rgb" to minimise the summed error of the three channels (the model in channel c
    is I_z,c times one shape). See docs/models.md for the trade-off.
    returns dict of float32 arrays: iz (..., 3), direction (..., 3),
    ambient_ratio (..., 1 or 3), invalid (..., 1) (1.0 where the input held NaN/Inf; those
    texels are output black: iz = 0, w_a = 1, d = z).
    """
    objective = options.pop("objective", None)
    if options:
        raise UsageError(f"unknown fit option(s) for {kind}: {', '.join(sorted(options))}")
    if kind not in KINDS:
        raise UsageError(f"unknown IrradZ model {kind!r}; choose one of {', '.join(KINDS)}")
    check_choice(kind, "solver", solver, SOLVERS[kind], error=UsageError)
    if ratio not in ("luminance", "rgb"):
        raise UsageError(f"ratio must be 'luminance' or 'rgb', not {ratio!r}")
    if objective not in (None, "luminance", "rgb"):
        raise UsageError(f"objective must be 'luminance' or 'rgb', not {objective!r}")
    if objective is not None and objective != ratio:
        if ratio == "rgb":
            raise UsageError("ratio='rgb' fits each channel: its objective is always 'rgb'")
        if kind == "hlsh" or solver.startswith("2018"):
            raise UsageError(
                f"objective='rgb' needs solver golden, golden_phi or direct (ahd, hhd); {kind} "
                f"{solver} fits the luminance signal as its paper defines it"
            )
    shared = ratio == "luminance" and objective == "rgb"
    sh = np.asarray(sh)
    if sh.ndim < 2 or sh.shape[-2:] != (3, 9):
        raise InputError(f"SH must have shape (..., 3, 9) (RGB x 9 coefficients), got {sh.shape}")
    if not (np.issubdtype(sh.dtype, np.floating) or np.issubdtype(sh.dtype, np.integer)):
        raise InputError(f"SH must be a real floating-point array, got dtype {sh.dtype}")
    lead = sh.shape[:-2]
    x = np.ascontiguousarray(sh.reshape(-1, 3, 9), dtype=np.float64)
    n = x.shape[0]
    nc = 3 if ratio == "rgb" else 1
    out_iz = np.empty((n, 3), np.float32)
    out_d = np.empty((n, 3), np.float32)
    out_wa = np.empty((n, nc), np.float32)
    out_bad = np.empty(n, np.float32)
    gram = np.eye(9) if solver == "2018_sphere" else gram_hemi()
    gd, go = sparse_gram(gram)
    code = {"golden": _GOLDEN, "golden_phi": _GOLDEN_PHI, "direct": _DIRECT}.get(solver, _FIXED)
    if n:
        _fit_kernel(
            x,
            _KIND[kind],
            nc == 3,
            code,
            shared,
            ambient_sh(kind),
            gd,
            go,
            out_iz,
            out_d,
            out_wa,
            out_bad,
        )
    out = {"iz": out_iz, "direction": out_d, "ambient_ratio": out_wa, "invalid": out_bad[:, None]}
    return {k: v.reshape(lead + v.shape[1:]) for k, v in out.items()}


#: Kernels read constants of these modules (frozen at compile time): recompile when they change.
numba_cache.track(globals(), reference, encoding, shm)
