"""Sparse Cholesky of the seam-stitching system (usdahd.numerics.cholesky), against numpy's
dense solver, and its fill on strip networks (what keeps seam stitching linear)."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd.numerics import cholesky


def _strip_network(cells: int, width: int = 3, seed: int = 0):
    """A grid of seam-like strips: the borders of cells x cells square charts, each border a
    strip ``width`` unknowns wide; neighbours within 1.5 apart are coupled. Returns positions
    and a random SPD matrix on that graph (CSR, both triangles)."""
    rng = np.random.default_rng(seed)
    side = 8 * cells
    xs, ys = np.meshgrid(np.arange(side + width), np.arange(side + width), indexing="ij")
    on = ((xs % 8) < width) | ((ys % 8) < width)
    pos = np.stack([xs[on], ys[on], np.zeros(on.sum())], 1).astype(float)
    n = len(pos)
    key = {tuple(p[:2].astype(int)): i for i, p in enumerate(pos)}
    rows, cols = [], []
    for i, p in enumerate(pos[:, :2].astype(int)):
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                j = key.get((p[0] + dx, p[1] + dy))
                if j is not None and j != i:
                    rows.append(i)
                    cols.append(j)
    rows, cols = np.array(rows), np.array(cols)
    w = rng.uniform(0.1, 1.0, len(rows))
    upper = rows < cols
    r, c, v = rows[upper], cols[upper], w[upper]
    # Q = sum of (e_r - e_c)(e_r - e_c)^T v (a weighted graph Laplacian) + 0.01 I: SPD
    dense = np.zeros((n, n))
    np.add.at(dense, (r, r), v)
    np.add.at(dense, (c, c), v)
    np.add.at(dense, (r, c), -v)
    np.add.at(dense, (c, r), -v)
    dense += 0.01 * np.eye(n)
    nz = np.nonzero(dense)
    order = np.lexsort((nz[1], nz[0]))
    ii, jj = nz[0][order], nz[1][order]
    indptr = np.searchsorted(ii, np.arange(n + 1))
    return pos, indptr, jj, dense[ii, jj], dense


def test_solves_like_a_dense_solver():
    pos, indptr, indices, data, dense = _strip_network(3)
    perm = cholesky.nested_dissection(pos, indptr, indices, leaf=8)
    assert np.array_equal(np.sort(perm), np.arange(len(pos)))
    b = np.random.default_rng(1).standard_normal((len(pos), 27))
    x = cholesky.factor(indptr, indices, data, perm).solve(b)
    np.testing.assert_allclose(x, np.linalg.solve(dense, b), rtol=1e-9, atol=1e-9)
    # any order gives the same solution (the order only changes the fill)
    x2 = cholesky.factor(indptr, indices, data, np.arange(len(pos))).solve(b[:, 0])
    np.testing.assert_allclose(x2, np.linalg.solve(dense, b[:, 0]), rtol=1e-9, atol=1e-9)


def test_not_positive_definite_is_refused():
    pos, indptr, indices, data, dense = _strip_network(1)
    data = np.where(indices == np.repeat(np.arange(len(pos)), np.diff(indptr)), -1.0, data)
    with pytest.raises(ValueError, match="not positive definite"):
        cholesky.factor(indptr, indices, data, np.arange(len(pos)))


def test_fill_per_unknown_stays_bounded_on_longer_seam_networks():
    """Nested dissection keeps the factor's size (and so the work) near-linear in the number
    of seam unknowns: a 4x larger chart network has at most ~1.5x the fill per unknown, where
    the natural (row-by-row) order's bandwidth grows with the network's side."""
    per = {}
    for cells in (4, 8):
        pos, indptr, indices, data, _ = _strip_network(cells)
        perm = cholesky.nested_dissection(pos, indptr, indices)
        nd = cholesky.factor(indptr, indices, data, perm)
        nat = cholesky.factor(indptr, indices, data, np.arange(len(pos)))
        per[cells] = (nd.nnz / len(pos), nat.nnz / len(pos))
    assert per[8][0] < 1.5 * per[4][0]
    assert per[8][1] > 1.7 * per[4][1]  # the natural order's fill does grow
    assert per[8][0] < per[8][1]
