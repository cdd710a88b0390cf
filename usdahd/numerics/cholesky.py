"""Sparse Cholesky factorisation of a symmetric positive definite matrix, for many right-hand
sides at once (the seam-stitching system of :func:`usdahd.bake.post.stitch`). numpy + numba.

The seam system couples only texels near a seam: its graph is a network of thin strips laid
along 3-D curves. A fill-reducing order for such a graph comes from geometry: *nested
dissection* on the unknowns' 3-D positions (split at the median of the longest axis, the
texels of one half that touch the other half form the separator, ordered last; recurse).
The factorisation is the up-looking sparse Cholesky of Davis, "Direct Methods for Sparse
Linear Systems" (SIAM 2006, ``cs_chol`` with ``cs_etree`` / ``cs_ereach``): the pattern of
each row of L is the reach of the row's entries in the elimination tree. One factorisation
serves every channel (the matrix is the same for all 27 SH coefficients), and the solve is
exact up to rounding, where conjugate gradients stopped at a residual tolerance.

Public functions
----------------
nested_dissection(position, indptr, indices, leaf=64) -> perm (n,) int64
factor(indptr, indices, data, perm) -> Factor
Factor.solve(b (n, k)) -> x (n, k)
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["factor", "nested_dissection"]

#: Leaves of the dissection at most this many unknowns are ordered as they come.
LEAF = 64


def _neighbours(indptr: np.ndarray, indices: np.ndarray, nodes: np.ndarray):
    """(owner, neighbour) pairs of every stored entry of rows ``nodes``."""
    start, stop = indptr[nodes], indptr[nodes + 1]
    deg = stop - start
    owner = np.repeat(nodes, deg)
    first = np.repeat(start - np.cumsum(deg) + deg, deg)
    return owner, indices[first + np.arange(len(owner))]


def nested_dissection(position, indptr, indices, leaf: int = LEAF) -> np.ndarray:
    """Elimination order (perm[k] = the unknown eliminated k-th) of a sparse symmetric graph
    (CSR ``indptr``, ``indices``, both triangles stored) whose unknowns sit at ``position
    (n, 3)``: recursive median bisection along the longest axis of each part's bounding box,
    the part's vertices with a neighbour across the cut (in the first half) as separator,
    eliminated after both halves. Deterministic (stable sorts only)."""
    pos = np.asarray(position, np.float64)
    n = len(pos)
    indptr = np.asarray(indptr, np.int64)
    indices = np.asarray(indices, np.int64)
    side = np.zeros(n, np.int64)  # stamp of the half a vertex was put in last
    mark = np.zeros(n, np.int64)  # stamp of the part whose separator a vertex joined
    order: list[np.ndarray] = []
    stamp = 0
    # explicit stack of (nodes, is_separator); popped LIFO, so push (sep, right, left)
    stack: list[tuple[np.ndarray, bool]] = [(np.arange(n, dtype=np.int64), False)]
    while stack:
        nodes, done = stack.pop()
        if done or len(nodes) <= leaf:
            order.append(nodes)
            continue
        p = pos[nodes]
        axis = int(np.argmax(p.max(0) - p.min(0)))
        srt = nodes[np.argsort(p[:, axis], kind="stable")]
        half = len(srt) // 2
        left, right = srt[:half], srt[half:]
        stamp += 1
        side[right] = stamp
        owner, nb = _neighbours(indptr, indices, left)
        mark[owner[side[nb] == stamp]] = stamp  # no O(n) array per part: stamps
        cut = mark[left] == stamp
        sep = left[cut]
        left = left[~cut]
        stack.append((sep, True))
        stack.append((right, False))
        stack.append((left, False))
    perm = np.concatenate(order) if order else np.zeros(0, np.int64)
    return perm.astype(np.int64)


@numba.njit(cache=True, nogil=True)
def _etree(cp, ci, n):
    """Elimination tree of the matrix whose upper triangle is the CSC (cp, ci)."""
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    for k in range(n):
        for p in range(cp[k], cp[k + 1]):
            i = ci[p]
            while i != -1 and i < k:
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    return parent


@numba.njit(cache=True, nogil=True)
def _ereach(cp, ci, k, parent, s, w, stamp):
    """Pattern of row k of L (the columns i < k with L[k, i] != 0) in s[top:], topological."""
    n = len(parent)
    top = n
    w[k] = stamp
    for p in range(cp[k], cp[k + 1]):
        i = ci[p]
        if i > k:
            continue
        length = 0
        while w[i] != stamp:
            s[length] = i
            length += 1
            w[i] = stamp
            i = parent[i]
        while length > 0:
            top -= 1
            length -= 1
            s[top] = s[length]
    return top


@numba.njit(cache=True, nogil=True)
def _chol(cp, ci, cx, n):
    """Up-looking Cholesky: L in CSC (lp, li, lx), diagonal first in each column; ok flag."""
    parent = _etree(cp, ci, n)
    s = np.empty(n, np.int64)
    w = np.zeros(n, np.int64)
    counts = np.ones(n, np.int64)  # the diagonal
    for k in range(n):
        top = _ereach(cp, ci, k, parent, s, w, k + 1)
        for q in range(top, n):
            counts[s[q]] += 1
    lp = np.zeros(n + 1, np.int64)
    for k in range(n):
        lp[k + 1] = lp[k] + counts[k]
    nnz = lp[n]
    li = np.empty(nnz, np.int64)
    lx = np.empty(nnz, np.float64)
    c = lp[:n].copy()
    x = np.zeros(n, np.float64)
    w[:] = 0
    for k in range(n):
        top = _ereach(cp, ci, k, parent, s, w, k + 1)
        x[k] = 0.0
        for p in range(cp[k], cp[k + 1]):
            if ci[p] <= k:
                x[ci[p]] += cx[p]
        d = x[k]
        x[k] = 0.0
        for q in range(top, n):
            i = s[q]
            lki = x[i] / lx[lp[i]]
            x[i] = 0.0
            for p in range(lp[i] + 1, c[i]):
                x[li[p]] -= lx[p] * lki
            d -= lki * lki
            p = c[i]
            c[i] += 1
            li[p] = k
            lx[p] = lki
        if d <= 0.0:
            return lp, li, lx, False
        p = c[k]
        c[k] += 1
        li[p] = k
        lx[p] = np.sqrt(d)
    return lp, li, lx, True


@numba.njit(cache=True, nogil=True)
def _solve(lp, li, lx, b):
    """x with L L^T x = b, b (n, k) in the factor's order (overwritten and returned)."""
    n, m = b.shape
    for j in range(n):
        d = lx[lp[j]]
        for c in range(m):
            b[j, c] /= d
        for p in range(lp[j] + 1, lp[j + 1]):
            i = li[p]
            v = lx[p]
            for c in range(m):
                b[i, c] -= v * b[j, c]
    for j in range(n - 1, -1, -1):
        for p in range(lp[j] + 1, lp[j + 1]):
            i = li[p]
            v = lx[p]
            for c in range(m):
                b[j, c] -= v * b[i, c]
        d = lx[lp[j]]
        for c in range(m):
            b[j, c] /= d
    return b


@dataclass
class Factor:
    """L L^T = P A P^T; ``solve`` takes and returns vectors in A's own order."""

    perm: np.ndarray
    lp: np.ndarray
    li: np.ndarray
    lx: np.ndarray

    @property
    def nnz(self) -> int:
        return int(self.lp[-1])

    def solve(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, np.float64)
        vec = b.ndim == 1
        bb = np.ascontiguousarray((b[:, None] if vec else b)[self.perm])
        y = _solve(self.lp, self.li, self.lx, bb)
        x = np.empty_like(y)
        x[self.perm] = y
        return x[:, 0] if vec else x


def factor(indptr, indices, data, perm) -> Factor:
    """Cholesky factor of the symmetric positive definite CSR matrix (``indptr``, ``indices``,
    ``data``; both triangles stored, duplicates summed) in the elimination order ``perm``.
    ValueError if it is not positive definite."""
    indptr = np.asarray(indptr, np.int64)
    indices = np.asarray(indices, np.int64)
    data = np.asarray(data, np.float64)
    perm = np.asarray(perm, np.int64)
    n = len(indptr) - 1
    pinv = np.empty(n, np.int64)
    pinv[perm] = np.arange(n)
    row = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    i, j = pinv[row], pinv[indices]
    keep = i <= j  # upper triangle of P A P^T, stored by columns j
    i, j, v = i[keep], j[keep], data[keep]
    o = np.lexsort((i, j))
    i, j, v = i[o], j[o], v[o]
    cp = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(j, minlength=n), out=cp[1:])
    lp, li, lx, ok = _chol(cp, i, v, n)
    if not ok:
        raise ValueError("matrix is not positive definite")
    return Factor(perm=perm, lp=lp, li=li, lx=lx)
