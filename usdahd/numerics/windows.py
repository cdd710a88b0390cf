"""Masked window means on chart canvases, for the denoiser's noise estimate and blend
(:mod:`usdahd.bake.variance`, :mod:`usdahd.bake.blend`, :mod:`usdahd.bake.denoise`).

:func:`box_mean`: the mean of an image over the chart texels in each (2r+1)^2 window;
:func:`box_mean_texels`: the same from and to per-texel values (no canvas for the caller);
:func:`neighbour_mean`: the mean of valid tiles over each tile's 3 x 3 neighbourhood;
and the pieces other kernels share: :func:`summed` (a summed-area table in place),
:func:`window` (a window's sum from it), :func:`count_table` (the table of a chart's mask),
:func:`finite` (``np.nan_to_num`` of one value).

Two implementations behind each function: a numba kernel (default) and a numpy reference
(``backend="numpy"``, the definition). The kernels repeat the reference's arithmetic in the
same order (a summed-area table from sequential cumulative sums; the nine shifts summed in the
same order), so they return the same numbers bit for bit (tests/numerics/test_windows.py).
Why: a chart's canvases are small (at 32^2 a few hundred texels), where the reference's ~15
numpy calls each (``np.pad`` alone ~20 us a call) are mostly per-call overhead, and at 128^2 a
chart's numpy passes ran on one core. With the blend's and the noise estimate's kernels the
denoise of a stretched_boxes bake went 93.6 -> ~72 ms at 32^2, 483 -> ~285 ms at 128^2
(issue 43, docs/time-to-quality.md).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "box_mean",
    "box_mean_texels",
    "count_table",
    "finite",
    "neighbour_mean",
    "summed",
    "window",
]

_BACKENDS = ("numba", "numpy")
#: Canvas elements (float64) of :func:`box_mean_texels`' summed-area table per channel block.
_WORK_ELEMENTS = 4_000_000


def _check_backend(backend: str) -> None:
    if backend not in _BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; use one of {_BACKENDS}")


def box_mean(img: np.ndarray, mask: np.ndarray, radius: int, backend: str = "numba") -> np.ndarray:
    """(h, w, c) float64 mean of ``img (h, w, c)`` over the ``mask (h, w) bool`` texels in
    each (2r+1)^2 window (0 where the window holds none); values outside ``mask`` (NaN
    too) are never used."""
    _check_backend(backend)
    if backend == "numpy":
        return _box_mean_numpy(img, mask, radius)
    img = np.ascontiguousarray(img, np.float64)
    mask = np.ascontiguousarray(mask, np.bool_)
    return _box_mean_numba(img, mask, int(radius))


def _box_mean_numpy(img, mask, radius):
    h, w, _ = img.shape
    r = radius
    v = np.where(mask[..., None], img, 0.0)
    s = np.pad(v, ((r + 1, r), (r + 1, r), (0, 0))).cumsum(0).cumsum(1)
    m = np.pad(mask.astype(np.float64), ((r + 1, r), (r + 1, r))).cumsum(0).cumsum(1)
    k = 2 * r + 1

    def box(a):
        return a[k:, k:] - a[:-k, k:] - a[k:, :-k] + a[:-k, :-k]

    tot, cnt = box(s)[:h, :w], box(m)[:h, :w]
    return tot / np.maximum(cnt, 1.0)[..., None]


@numba.njit(cache=True, nogil=True)
def _box_mean_numba(img, mask, r):
    h, w, c = img.shape
    k = 2 * r + 1
    ly, lx = np.nonzero(mask)
    cnt = count_table(ly, lx, h, w, r)
    # the reference's zero-padded array (r + 1 before, r after), then cumsum(0), cumsum(1)
    s = np.zeros((h + k, w + k, c))
    for i in range(len(ly)):
        for ch in range(c):
            s[ly[i] + r + 1, lx[i] + r + 1, ch] = img[ly[i], lx[i], ch]
    summed(s)
    out = np.empty((h, w, c))
    for y in range(h):
        for x in range(w):
            n = max(window(cnt, y, x, 0, k), 1.0)
            for ch in range(c):
                out[y, x, ch] = window(s, y, x, ch, k) / n
    return out


@numba.njit(cache=True, nogil=True)
def summed(a):
    """In place: ``a (hh, ww, g)`` float64 -> its summed-area table, ``a.cumsum(0).cumsum(1)``
    (the same additions in the same order)."""
    hh, ww, g = a.shape
    for y in range(1, hh):
        for x in range(ww):
            for j in range(g):
                a[y, x, j] += a[y - 1, x, j]
    for y in range(hh):
        for x in range(1, ww):
            for j in range(g):
                a[y, x, j] += a[y, x - 1, j]


@numba.njit(cache=True, nogil=True)
def window(a, y, x, j, k):
    """Channel ``j``'s sum over the k x k window of the summed-area table ``a`` whose padded
    corner is ``(y, x)``, in :func:`box_mean`'s order of operations."""
    return a[y + k, x + k, j] - a[y, x + k, j] - a[y + k, x, j] + a[y, x, j]


@numba.njit(cache=True, nogil=True)
def count_table(ly, lx, h, w, r):
    """(h + 2r + 1, w + 2r + 1, 1) summed-area table of the mask of texels ``(ly, lx)`` on an
    (h, w) canvas padded as :func:`box_mean` pads it (r + 1 before, r after)."""
    k = 2 * r + 1
    cnt = np.zeros((h + k, w + k, 1))
    for i in range(len(ly)):
        cnt[ly[i] + r + 1, lx[i] + r + 1, 0] = 1.0
    summed(cnt)
    return cnt


def box_mean_texels(
    values: np.ndarray,
    ly: np.ndarray,
    lx: np.ndarray,
    shape: tuple[int, int],
    radius: int,
    backend: str = "numba",
) -> np.ndarray:
    """(m, c) float64 :func:`box_mean` of per-texel ``values (m, c)`` placed at ``(ly, lx)
    (m,)`` of a canvas of ``shape`` (its mask: those texels), read back at the same texels:
    each texel's mean over the texels within ``radius`` (Chebyshev). Values are rounded to
    float32 first and read as ``np.nan_to_num`` (what a :class:`usdahd.bake.canvas.Canvas`
    image holds), so the result equals ``box_mean(canvas.image(values, fill=False), mask,
    radius)[ly, lx]`` bit for bit. The kernel builds the canvas's summed-area tables for a
    block of channels at a time (bounded memory for a large chart)."""
    _check_backend(backend)
    ly = np.asarray(ly, np.int64)
    lx = np.asarray(lx, np.int64)
    values = np.asarray(values)
    if backend == "numpy":
        mask = np.zeros(shape, bool)
        mask[ly, lx] = True
        img = np.full((*shape, values.shape[1]), np.nan, np.float32)
        img[ly, lx] = values
        return _box_mean_numpy(np.nan_to_num(img.astype(np.float64)), mask, radius)[ly, lx]
    side = 2 * int(radius) + 1
    block = int(np.clip(_WORK_ELEMENTS // ((shape[0] + side) * (shape[1] + side)), 1, 64))
    return _box_mean_texels_numba(
        np.ascontiguousarray(values, np.float32),
        np.ascontiguousarray(ly),
        np.ascontiguousarray(lx),
        int(shape[0]),
        int(shape[1]),
        int(radius),
        block,
    )


@numba.njit(cache=True, nogil=True)
def finite(v):
    """``np.nan_to_num`` of one float64 (for kernels: usdahd.numerics.noise, usdahd.bake.blend)."""
    if v != v:
        return 0.0
    if v == np.inf:
        return np.finfo(np.float64).max
    if v == -np.inf:
        return -np.finfo(np.float64).max
    return v


@numba.njit(cache=True, nogil=True)
def _box_mean_texels_numba(values, ly, lx, h, w, r, block):
    m, nc = values.shape
    k = 2 * r + 1
    cnt = count_table(ly, lx, h, w, r)
    out = np.empty((m, nc))
    for c0 in range(0, nc, block):
        g = min(nc, c0 + block) - c0
        s = np.zeros((h + k, w + k, g))
        for i in range(m):
            for j in range(g):
                s[ly[i] + r + 1, lx[i] + r + 1, j] = finite(np.float64(values[i, c0 + j]))
        summed(s)
        for i in range(m):
            n = max(window(cnt, ly[i], lx[i], 0, k), 1.0)
            for j in range(g):
                out[i, c0 + j] = window(s, ly[i], lx[i], j, k) / n
    return out


def neighbour_mean(
    tiles: np.ndarray, valid: np.ndarray, fallback: np.ndarray, backend: str = "numba"
) -> np.ndarray:
    """(th, tw, c) float64 mean of the ``valid (th, tw, c) bool`` entries of ``tiles (th, tw,
    c)`` over each tile's 3 x 3 neighbourhood; ``fallback (c,)`` where none is valid."""
    _check_backend(backend)
    if backend == "numpy":
        return _neighbour_mean_numpy(tiles, valid, fallback)
    tiles = np.ascontiguousarray(tiles, np.float64)
    valid = np.ascontiguousarray(valid, np.bool_)
    # a new writable array (a read-only view would be another numba signature)
    fallback = np.array(np.broadcast_to(fallback, tiles.shape[-1:]), np.float64)
    return _neighbour_mean_numba(tiles, valid, fallback)


def _neighbour_mean_numpy(tiles, valid, fallback):
    th, tw = tiles.shape[:2]
    pv = np.pad(np.where(valid, tiles, 0.0), ((1, 1), (1, 1), (0, 0)))
    pc = np.pad(valid.astype(np.float64), ((1, 1), (1, 1), (0, 0)))
    shifts = [(dy, dx) for dy in range(3) for dx in range(3)]
    tot = sum(pv[dy : dy + th, dx : dx + tw] for dy, dx in shifts)
    cnt = sum(pc[dy : dy + th, dx : dx + tw] for dy, dx in shifts)
    return np.where(cnt > 0, tot / np.maximum(cnt, 1.0), fallback)


@numba.njit(cache=True, nogil=True)
def _neighbour_mean_numba(tiles, valid, fallback):
    th, tw, c = tiles.shape
    out = np.empty((th, tw, c))
    for ty in range(th):
        for tx in range(tw):
            for ch in range(c):
                tot = 0.0
                cnt = 0.0
                # the reference's order of shifts; an invalid or outside tile adds 0 (exact)
                for dy in range(3):
                    y = ty + dy - 1
                    if y < 0 or y >= th:
                        continue
                    for dx in range(3):
                        x = tx + dx - 1
                        if x >= 0 and x < tw and valid[y, x, ch]:
                            tot += tiles[y, x, ch]
                            cnt += 1.0
                out[ty, tx, ch] = tot / cnt if cnt > 0 else fallback[ch]
    return out
