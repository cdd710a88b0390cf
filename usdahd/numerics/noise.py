"""Tile statistics of squared second differences: the core of the denoiser's noise estimate.

For spatially independent noise of variance s^2, a second difference ``x[p-d] - 2 x[p] +
x[p+d]`` along a row, column or diagonal has mean square ``6 s^2`` and vanishes on a linear
signal (``usdahd.bake.denoise.noise_variance`` explains how the statistics become a variance).
:func:`tile_stats` gathers, for every ``tile x tile`` block of a canvas and channel, the mean,
median and count of the squared second differences of the 4 directions centred in the block
whose three texels are all in ``support``; and the same over the whole canvas.

Two implementations behind each function: a numba kernel (default) and a numpy reference
(``backend="numpy"``, the definition; tests/bake/test_denoise.py checks their parity). The numpy
tile statistics materialize a (h, w, 4, c) array and sort every block: on a 46 x 46 canvas of
27 channels 7 ms, the kernel ~1 ms (usdahd/bake/denoise.py's noise estimate ran twice per chart
and was a third of the denoise time). :func:`second_differences`' and :func:`bends`' kernels return
their references' numbers bit for bit (the same arithmetic without the padded copies and the
(h, w, 4, c) array; :func:`bends` is the denoiser's curvature test, a chart at a time).
"""

from __future__ import annotations

import numba
import numpy as np

from usdahd.numerics import numba_cache, windows
from usdahd.numerics.windows import finite as _finite

__all__ = ["bends", "second_differences", "tile_stats"]

#: The 4 directions (dx, dy) of the second differences: row, column, both diagonals.
DIRECTIONS = ((1, 0), (0, 1), (1, 1), (1, -1))
_DIR = np.array(DIRECTIONS, dtype=np.int64)


def second_differences(
    img: np.ndarray,
    support: np.ndarray,
    directions: int = len(DIRECTIONS),
    fill=np.nan,
    backend: str = "numba",
) -> np.ndarray:
    """(h, w, k, c) float64 squared second differences of ``img (h, w, c)`` in the first
    ``directions`` (k) of :data:`DIRECTIONS` (all 4 by default; 2: the row and the column)
    centred at each texel; ``fill`` (NaN by default; 0 for callers that sum or take maxima)
    where p - d, p or p + d is outside ``support (h, w) bool``. Values are read as by
    ``np.nan_to_num`` (NaN outside the support is fine: never read). ``backend``: the numba
    kernel or the numpy reference (the same numbers bit for bit)."""
    if backend == "numba":
        return _second_differences_numba(
            np.ascontiguousarray(img, np.float64),
            np.ascontiguousarray(support, np.bool_),
            int(directions),
            float(fill),
            _DIR,
        )
    if backend != "numpy":
        raise ValueError(f"unknown backend {backend!r}")
    h, w, c = img.shape
    pad_v = np.pad(np.nan_to_num(img.astype(np.float64)), ((1, 1), (1, 1), (0, 0)))
    pad_m = np.pad(support, 1)
    out = np.empty((h, w, directions, c))
    for k, (dx, dy) in enumerate(DIRECTIONS[:directions]):
        a = pad_v[1 - dy : 1 - dy + h, 1 - dx : 1 - dx + w]
        b = pad_v[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
        ok = support & pad_m[1 - dy : 1 - dy + h, 1 - dx : 1 - dx + w]
        ok &= pad_m[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
        d = a - 2.0 * pad_v[1 : 1 + h, 1 : 1 + w] + b
        out[:, :, k] = np.where(ok[..., None], d * d, fill)
    return out


@numba.njit(cache=True, nogil=True)
def _second_differences_numba(img, support, nd, fill, dirs):
    h, w, c = img.shape
    out = np.empty((h, w, nd, c))
    for y in range(h):
        for x in range(w):
            for k in range(nd):
                dx, dy = dirs[k, 0], dirs[k, 1]
                ya, xa, yb, xb = y - dy, x - dx, y + dy, x + dx
                ok = support[y, x] and 0 <= ya < h and 0 <= yb < h and 0 <= xa < w
                ok = ok and 0 <= xb < w and support[ya, xa] and support[yb, xb]
                for ch in range(c):
                    if ok:
                        d = _finite(img[ya, xa, ch]) - 2.0 * _finite(img[y, x, ch])
                        d = d + _finite(img[yb, xb, ch])
                        out[y, x, k, ch] = d * d
                    else:
                        out[y, x, k, ch] = fill
    return out


def bends(
    values: np.ndarray,
    variance: np.ndarray,
    ly: np.ndarray,
    lx: np.ndarray,
    shape: tuple[int, int],
    factor: float,
    backend: str = "numba",
) -> np.ndarray:
    """(h, w) bool: the texels ``(ly, lx) (m,)`` of a canvas of ``shape`` where, for some
    channel of ``values (m, c)``, a squared second difference (any of the 4 directions,
    :func:`second_differences` on the canvas of those texels) exceeds ``factor x variance
    (m, c)``. Both are placed on the canvas as float32 (a :class:`usdahd.bake.canvas.Canvas`
    image) and read as ``np.nan_to_num``; the kernel (default) equals the numpy reference
    (the canvas route) bit for bit, without its (h, w, 4, c) array."""
    ly = np.asarray(ly, np.int64)
    lx = np.asarray(lx, np.int64)
    if backend == "numpy":
        mask = np.zeros(shape, bool)
        mask[ly, lx] = True

        def image(v):
            img = np.full((*shape, v.shape[1]), np.nan, np.float32)
            img[ly, lx] = v
            return img

        sd = second_differences(image(values), mask, fill=0.0, backend="numpy")
        v = np.nan_to_num(image(variance))
        return (sd.max(axis=2) > factor * v).any(axis=2) & mask
    if backend != "numba":
        raise ValueError(f"unknown backend {backend!r}")
    return _bends_numba(
        np.ascontiguousarray(values, np.float32),
        np.ascontiguousarray(variance, np.float32),
        np.ascontiguousarray(ly),
        np.ascontiguousarray(lx),
        int(shape[0]),
        int(shape[1]),
        float(factor),
        _DIR,
    )


@numba.njit(cache=True, nogil=True)
def _bends_numba(values, variance, ly, lx, h, w, factor, dirs):
    m, c = values.shape
    nd = dirs.shape[0]
    mask = np.zeros((h, w), np.bool_)
    img = np.zeros((h, w, c))
    for i in range(m):
        mask[ly[i], lx[i]] = True
        for ch in range(c):
            img[ly[i], lx[i], ch] = _finite(np.float64(values[i, ch]))
    out = np.zeros((h, w), np.bool_)
    for i in range(m):
        y, x = ly[i], lx[i]
        for ch in range(c):
            thr = factor * _finite(np.float64(variance[i, ch]))
            # the reference's maximum over the 4 directions, 0 for a missing one
            top = 0.0
            for k in range(nd):
                dx, dy = dirs[k, 0], dirs[k, 1]
                ya, xa, yb, xb = y - dy, x - dx, y + dy, x + dx
                if 0 <= ya < h and 0 <= yb < h and 0 <= xa < w and 0 <= xb < w:
                    if mask[ya, xa] and mask[yb, xb]:
                        q = img[ya, xa, ch] - 2.0 * img[y, x, ch]
                        q = q + img[yb, xb, ch]
                        top = max(top, q * q)
            if top > thr:
                out[y, x] = True
                break
    return out


def nan_median(values: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """NaN-ignoring median along ``axis`` (NaN where all are NaN) and the count of non-NaN
    values, without warnings."""
    v = np.sort(values, axis=axis)  # NaNs sort last
    cnt = np.sum(~np.isnan(values), axis=axis)
    lo = np.expand_dims(np.maximum(cnt - 1, 0) // 2, axis)
    hi = np.expand_dims(cnt // 2, axis)
    med = 0.5 * (np.take_along_axis(v, lo, axis) + np.take_along_axis(v, hi, axis))
    return np.where(cnt > 0, np.squeeze(med, axis), np.nan), cnt


def tile_stats(
    img: np.ndarray,
    support: np.ndarray,
    tile: int,
    backend: str = "numba",
    need: np.ndarray | None = None,
    min_count: int = 0,
):
    """Statistics of the squared second differences of ``img (h, w, c)`` (NaN outside the
    chart is fine: only ``support`` texels are read) per ``tile x tile`` block.

    support : (h, w) bool, the texels a difference may use (all three must be in it).
    returns ``(mean, median, count, chart_mean, chart_median, chart_count)``: per block
    ``(th, tw, c)`` float64 mean (0 where count is 0), float64 median (NaN where 0) and int64
    count, with ``th = ceil(h / tile)``, ``tw = ceil(w / tile)``; and the same over the whole
    canvas per channel, ``(c,)``. A difference belongs to the block of its centre texel.
    need : (th, tw) bool, optional: the blocks whose estimate the caller uses. Then the
    chart-wide median (a selection over every difference: on a 128 x 128 chart 40 % of the
    kernel's time) is computed only when one of them has no block with at least
    ``min_count`` differences in its 3 x 3 neighbourhood, the one case where the caller
    falls back to the chart's statistics (:func:`usdahd.bake.variance.canvas_noise`); else
    it is NaN.
    """
    img = np.ascontiguousarray(np.nan_to_num(np.asarray(img, np.float64)))
    support = np.ascontiguousarray(np.asarray(support, bool))
    th, tw = -(-img.shape[0] // tile), -(-img.shape[1] // tile)
    force = need is None
    need = np.zeros((th, tw), bool) if force else np.ascontiguousarray(need, np.bool_)
    if need.shape != (th, tw):
        raise ValueError(f"need of shape {need.shape} does not fit {th} x {tw} tiles")
    if backend == "numpy":
        out = _tile_stats_numpy(img, support, tile)
        count = out[2][:, :, 0] if img.shape[2] else np.zeros((th, tw), np.int64)
        if not force and not _falls_back(count, need, min_count):
            out = (*out[:4], np.full_like(out[4], np.nan), out[5])
        return out
    if backend != "numba":
        raise ValueError(f"unknown backend {backend!r}")
    return _tile_stats_numba(img, support, int(tile), _DIR, need, int(min_count), force)


def _falls_back(count: np.ndarray, need: np.ndarray, min_count: int) -> bool:
    """Whether a ``need`` tile has no tile with ``count (th, tw) >= min_count`` within its
    3 x 3 neighbourhood."""
    ok = np.pad(count >= min_count, 1)
    th, tw = count.shape
    near = np.zeros((th, tw), bool)
    for dy in range(3):
        for dx in range(3):
            near |= ok[dy : dy + th, dx : dx + tw]
    return bool((need & ~near).any())


def _tile_stats_numpy(img, support, tile):
    h, w, c = img.shape
    nd = len(DIRECTIONS)
    d2 = second_differences(img, support, backend="numpy")
    th, tw = -(-h // tile), -(-w // tile)
    padded = np.full((th * tile, tw * tile, nd, c), np.nan)
    padded[:h, :w] = d2
    blocks = padded.reshape(th, tile, tw, tile, nd, c).transpose(0, 2, 1, 3, 4, 5)
    blocks = blocks.reshape(th, tw, tile * tile * nd, c)
    have = ~np.isnan(blocks)
    cnt = have.sum(axis=2)
    mean = np.where(have, blocks, 0.0).sum(axis=2) / np.maximum(cnt, 1)
    med, _ = nan_median(blocks, axis=2)
    flat = d2.reshape(-1, c)
    fmed, fcnt = nan_median(flat, axis=0)
    fmean = np.nansum(flat, axis=0) / np.maximum(fcnt, 1)
    return mean, med, cnt.astype(np.int64), fmean, fmed, fcnt.astype(np.int64)


@numba.njit(cache=True, nogil=True)
def _tile_stats_numba(img, support, tile, dirs, need, min_count, force):
    h, w, c = img.shape
    nd = dirs.shape[0]
    th = (h + tile - 1) // tile
    tw = (w + tile - 1) // tile
    # which (texel, direction) differences exist: all three texels in the support
    ok = np.zeros((h, w, nd), np.bool_)
    per_tile = np.zeros((th, tw), np.int64)
    n_all = 0
    for y in range(h):
        for x in range(w):
            if not support[y, x]:
                continue
            for k in range(nd):
                dx, dy = dirs[k, 0], dirs[k, 1]
                ya, xa, yb, xb = y - dy, x - dx, y + dy, x + dx
                if ya < 0 or yb < 0 or ya >= h or yb >= h:
                    continue
                if xa < 0 or xb < 0 or xa >= w or xb >= w:
                    continue
                if support[ya, xa] and support[yb, xb]:
                    ok[y, x, k] = True
                    n_all += 1
                    per_tile[y // tile, x // tile] += 1
    # the chart-wide median only where a needed tile falls back to it (tile_stats' need)
    want = force
    for ty in range(th):
        for tx in range(tw):
            if want or not need[ty, tx]:
                continue
            near = False
            for yy in range(max(ty - 1, 0), min(ty + 2, th)):
                for xx in range(max(tx - 1, 0), min(tx + 2, tw)):
                    near = near or per_tile[yy, xx] >= min_count
            want = not near
    mean = np.zeros((th, tw, c))
    med = np.full((th, tw, c), np.nan)
    cnt = np.zeros((th, tw, c), np.int64)
    fmean = np.zeros(c)
    fmed = np.full(c, np.nan)
    fcnt = np.zeros(c, np.int64)
    buf = np.empty(tile * tile * nd)
    allv = np.empty(max(n_all, 1))
    for ch in range(c):
        m = 0
        total = 0.0
        for ty in range(th):
            for tx in range(tw):
                k_in = 0
                s = 0.0
                for y in range(ty * tile, min(h, (ty + 1) * tile)):
                    for x in range(tx * tile, min(w, (tx + 1) * tile)):
                        for k in range(nd):
                            if ok[y, x, k]:
                                dx, dy = dirs[k, 0], dirs[k, 1]
                                d = img[y - dy, x - dx, ch] - 2.0 * img[y, x, ch]
                                d += img[y + dy, x + dx, ch]
                                d *= d
                                buf[k_in] = d
                                allv[m] = d
                                k_in += 1
                                m += 1
                                s += d
                cnt[ty, tx, ch] = k_in
                total += s
                if k_in > 0:
                    mean[ty, tx, ch] = s / k_in
                    med[ty, tx, ch] = np.median(buf[:k_in])
        fcnt[ch] = m
        if m > 0:
            fmean[ch] = total / m
        if m > 0 and want:
            # a selection, not a sort: the chart-wide median was most of this kernel's time
            # on big canvases (144 x 144 x 27: 9 of 12 ms per channel)
            fmed[ch] = np.median(allv[:m])
    return mean, med, cnt, fmean, fmed, fcnt


# _second_differences_numba links windows.finite: an edit there recompiles it
numba_cache.track(globals(), windows)
