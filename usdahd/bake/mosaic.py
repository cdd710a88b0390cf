"""Mosaics for the denoiser (:mod:`usdahd.bake.denoise`): the chart canvases of many records
laid out as tiles of one image per coefficient, so OIDN runs once per mosaic instead of once per
chart. ``crop`` (the part of a canvas given to OIDN), ``layout`` (shelf or skyline packing of
the tiles), ``fill_empty`` (the pixels between tiles taken from the nearest tile),
``autoexposure`` (OIDN's own HDR exposure of one tile) and ``run`` (one OIDN run over a batch).
numpy only; the OIDN device comes from the caller (``den.run``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["HDR_CROP_PAD", "OIDN_BLOCK", "PAD", "fill_empty", "plan", "run"]

#: Least dilated context (texels) on every side of a chart: a constant chart comes back
#: within 0.6 % of itself at 4, 0.12 % at 8, 0.08 % at 16 (OIDN 2.x, quality high, measured).
#: The canvas side is then rounded up to a multiple of OIDN_BLOCK, the extra going to the
#: context too (10-17 texels per side). Was 16 without rounding: OIDN then padded to
#: the next multiple of 16, 1.3-2x the pixels of a run; 8 with rounding put OIDN's raw output
#: on a noise-free gradient 0.9 % off at a chart's border (tests/bake/test_denoise.py), 10 keeps
#: the blended output's error of 16 (0.49 %) and the stages' error (docs/time-to-quality.md).
PAD = 10
#: OIDN pads every image side to a multiple of this and its run time follows the padded
#: size (measured, 2 cores: 40 / 48 px sides 4.3 / 4.6 ms, 49 / 64 px 7.5 / 6.9 ms): canvas
#: sides are rounded up to it, so the padding OIDN would add anyway is chart context.
OIDN_BLOCK = 16
#: Each chart's tile in a mosaic is its whole canvas (10-17 texels of filled context, the
#: same image OIDN gets chart by chart), so charts are >= 20 texels of their own context
#: apart and OIDN gets the same pixels as chart by chart. Tried (tests/bake/test_denoise.py, and
#: OIDN pixels of cornell_box 32^2): a crop to PAD texels of context plus MOSAIC_GAP
#: mirrored texels (MOSAIC_CROP): gap 0 / 4 put the noise-free gradient's worst texel 0.53
#: / 0.39 % off (chart by chart 0.47 %) and raised the 0.2 %-noise error of two charts
#: (0.366 % vs 0.304 %), gap 8 passed but sent OIDN 2x the pixels (64,512 vs 32,768 per
#: coefficient) and was slower than chart by chart.
MOSAIC_CROP = False
#: Extra mirrored texels around each tile (0: the canvas's own context is the gap).
MOSAIC_GAP = 0
#: Context (texels) on every side of a cropped tile (<= PAD: the canvas holds PAD), i.e. of
#: the directional coefficients' tiles (denoise.DIRECTIONAL_CROP). Their error against a
#: converged bake (benchmarks/denoise_directional.py method, 4 stages x 16-256 spp x 2 seeds,
#: docs/time-to-quality.md): 10 / 8 texels within +-1.1 / +-1.7 % of the whole canvas's, 6 up
#: to +5 % (exterior_sun_sky's l=1 at 256 spp); OIDN pixels of exterior_sun_sky's 32^2
#: directional runs 20,736 / 16,640 / 12,288 (whole canvases 24,576).
CROP_PAD = 8
#: Context (texels) on every side of c00's and c10's (I_z's) cropped tiles (denoise.HDR_CROP),
#: whose mosaic's empty pixels are filled from the tiles (:func:`fill_empty`). Measured on the
#: noise-free gradients of tests/bake/test_denoise.py (worst texel's I_z error; bound 0.5 %):
#: whole canvases 0.36 % (two charts) / 0.49 % (a tiny chart); cropped to 10 on a zero mosaic
#: 0.53 % (the earlier attempt: the zeros beyond the crop read as a dark border), filled 0.29 %
#: / 0.46 %; cropped to 8 and filled 0.69 %.
HDR_CROP_PAD = 10
#: Column width (pixels) of the skyline packing of cropped tiles (:func:`layout`): 16-pixel
#: columns lose most of what a crop saves (exterior_sun_sky 32^2: tiles of 17,850 pixels in a
#: mosaic of 21,504 on 16-pixel columns, 20,736 on 4-pixel ones; its canvases 24,576).
MOSAIC_GRID = 4


def crop(
    cv, gap: int, cropped: bool | None = None, pad: int | None = None
) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) of the part of chart canvas ``cv`` given to OIDN in a mosaic: the
    chart's bounding box and ``CROP_PAD`` texels of context on every side. The canvas's rounding
    to OIDN_BLOCK and MIN_CROP serve a run of the canvas alone (OIDN pads an image to whole
    blocks, and a tiny image has no context at its borders); in a mosaic neither applies, and
    leaving them out sends OIDN 0.4-0.6x the pixels of small charts. The noise estimate and
    the blend still use the whole canvas, so they are the same as chart by chart.
    ``cropped``: crop or not (default MOSAIC_CROP); ``pad``: the context (default CROP_PAD)."""
    y0, y1, x0, x1 = cv.box
    h, w = cv.shape
    if not (MOSAIC_CROP if cropped is None else cropped):
        return 0, h, 0, w
    pad = CROP_PAD if pad is None else pad
    return max(y0 - pad, 0), min(y1 + pad, h), max(x0 - pad, 0), min(x1 + pad, w)


def layout(crops: list[tuple[int, int, int, int]], gap: int, grid: int = OIDN_BLOCK):
    """Packing of tiles (each crop grown by ``gap`` on every side) into one mosaic:
    ((H, W), [(y, x) of each crop's origin]). Tiles go by decreasing height, either into
    shelves (rows) of the mosaic's width or onto a skyline (each tile at the lowest place its
    width fits, on a grid of OIDN_BLOCK columns: tiles of different heights stack into the
    gaps a shelf leaves); of the widths from the widest tile to twice the square's side (at
    most ~32 of them, in OIDN_BLOCK steps) and the two packings, the one with the fewest
    mosaic pixels (OIDN's time follows them; the height is rounded to OIDN_BLOCK). ``grid``:
    the skyline's column width (cropped tiles are not whole OIDN blocks: MOSAIC_GRID)."""
    tiles = [(y1 - y0 + 2 * gap, x1 - x0 + 2 * gap) for y0, y1, x0, x1 in crops]
    order = sorted(range(len(tiles)), key=lambda i: (-tiles[i][0], -tiles[i][1]))
    area = sum(h * w for h, w in tiles)
    lo = max(w for _, w in tiles)
    hi = max(lo, 2 * int(np.sqrt(area)))
    best = None
    first = -(-lo // OIDN_BLOCK) * OIDN_BLOCK
    step = OIDN_BLOCK * max(1, (hi - first) // (32 * OIDN_BLOCK))  # <= ~32 widths tried
    for width in range(first, hi + step, step):
        for pack in (_shelves, _skyline):
            top, pos = pack(tiles, order, width, grid)
            height = -(-top // OIDN_BLOCK) * OIDN_BLOCK
            if best is None or height * width < best[0][0] * best[0][1]:
                best = ((height, width), [(y + gap, x + gap) for y, x in pos])
    return best


def _shelves(tiles, order, width, grid=None):
    """(used height, [(y, x) of each tile]): rows of tiles in ``order``, left to right."""
    pos = [None] * len(tiles)
    x = y = row = 0
    for i in order:
        h, w = tiles[i]
        if x + w > width:
            y, x, row = y + row, 0, 0
        pos[i] = (y, x)
        x, row = x + w, max(row, h)
    return y + row, pos


def _skyline(tiles, order, width, grid=OIDN_BLOCK):
    """(used height, [(y, x) of each tile]): each tile in ``order`` at the lowest (then
    leftmost) place on the skyline of the tiles before it, on ``grid``-wide columns."""
    cols = width // grid
    sky = np.zeros(cols, np.int64)
    pos = [None] * len(tiles)
    for i in order:
        h, w = tiles[i]
        c = -(-w // grid)
        tops = np.lib.stride_tricks.sliding_window_view(sky, c).max(axis=1)
        x = int(np.argmin(tops))  # the first of the lowest
        y = int(tops[x])
        sky[x : x + c] = y + h
        pos[i] = (y, x * grid)
    return int(sky.max()), pos


def autoexposure(img: np.ndarray) -> float:
    """OIDN's HDR auto exposure of ``img (h, w, 3)``: key 0.18 over the geometric mean of the
    luminance of up to 16 x 16 pixel bins (bins of luminance <= 1e-8 left out; 1 if none), as
    OIDN computes it (its ``autoexposure`` kernel), so a canvas scaled by it and run with
    ``inputScale = 1`` is what OIDN sees of the canvas alone."""
    h, w = img.shape[:2]
    nh, nw = -(-h // 16), -(-w // 16)
    lum = np.asarray(img, np.float32) @ np.array([0.212671, 0.715160, 0.072169], np.float32)
    if h % 16 == 0 and w % 16 == 0:  # whole 16 x 16 bins (every chart canvas): one reshape
        m = lum.reshape(nh, 16, nw, 16).mean(axis=(1, 3), dtype=np.float64).ravel()
        m = m[m > 1e-8]
        return 0.18 / float(np.exp2(np.mean(np.log2(m)))) if len(m) else 1.0
    ys = [(i * h) // nh for i in range(nh + 1)]
    xs = [(j * w) // nw for j in range(nw + 1)]
    logs = []
    for i in range(nh):
        for j in range(nw):
            m = float(lum[ys[i] : ys[i + 1], xs[j] : xs[j + 1]].mean())
            if m > 1e-8:
                logs.append(np.log2(m))
    return 0.18 / float(np.exp2(np.mean(logs))) if logs else 1.0


def plan(batch: list, cropped: bool | None = None, pad: int | None = None):
    """(crops, ((H, W), positions)) of the mosaic of ``batch``'s charts: the same for each
    coefficient's run, so :func:`run` takes it computed once per batch (the layout's search
    over widths and packings was 10 % of a 32^2 bake's CPU when repeated for 9 runs).
    ``cropped``: tiles cropped to the chart's box and PAD (default MOSAIC_CROP), packed on
    MOSAIC_GRID columns; ``pad``: their context (default CROP_PAD)."""
    cropped = MOSAIC_CROP if cropped is None else cropped
    crops = [crop(ch.cv, MOSAIC_GAP, cropped, pad) for ch in batch]
    grid = MOSAIC_GRID if cropped else OIDN_BLOCK
    return crops, layout(crops, MOSAIC_GAP, grid)


def fill_empty(mos: np.ndarray, used: np.ndarray) -> np.ndarray:
    """``mos (H, W, c)`` with every pixel outside ``used (H, W)`` set, in place, to the nearest
    used pixel of its row (the left one on a tie), and rows without one to the nearest row that
    has one: the tiles' edges extended instead of zeros, which OIDN's HDR network reads as a
    dark border a crop's width from the chart. One pass per axis (no ring-by-ring dilation)."""
    H, W = used.shape
    if used.all() or not used.any():
        return mos
    rows = used.any(axis=1)
    src = _nearest(used[rows])  # (rows with a used pixel, W) column of the nearest used one
    r = np.nonzero(rows)[0]
    mos[r] = mos[r[:, None], src]
    if not rows.all():
        near = _nearest(rows[None, :])[0]  # (H,) nearest row with a used pixel
        mos[~rows] = mos[near[~rows]]
    return mos


def _nearest(used: np.ndarray) -> np.ndarray:
    """(n, W) index of the nearest True of each row of ``used (n, W)`` (each row has one)."""
    n, W = used.shape
    cols = np.broadcast_to(np.arange(W), used.shape)
    left = np.maximum.accumulate(np.where(used, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(used, cols, W)[:, ::-1], axis=1)[:, ::-1]
    take_left = (left >= 0) & ((right >= W) | (cols - left <= right - cols))
    return np.where(take_left, left, right)


def run(
    den, batch: list, k: int, kind: dict, use_guides: bool, plan_=None, fill: bool = False
) -> list:
    """OIDN's output (a canvas-sized image, valid on the crop) of coefficient ``k`` of every
    chart of ``batch``, all run as tiles of one mosaic image. Each tile is the chart's
    :func:`crop` grown by ``MOSAIC_GAP`` on every side, mirrored (so around a chart's own
    context there is more of it, not a neighbour: charts are at least 2 PAD texels apart,
    all of it their own filled context); in HDR mode each tile is scaled by its own
    :func:`autoexposure` and the mosaic run with ``inputScale`` 1 (OIDN's exposure of the
    whole mosaic would else follow its brightest charts), and the output divided back.
    ``plan_``: the batch's :func:`plan` (computed here when not given); ``fill``: the mosaic's
    pixels outside every tile set from the nearest tile (:func:`fill_empty`), else 0."""
    gap = MOSAIC_GAP
    crops, ((H, W), pos) = plan(batch) if plan_ is None else plan_
    hdr = kind.get("hdr", False)

    def part(img, c):
        y0, y1, x0, x1 = c
        return img[y0:y1, x0:x1]

    images = [part(ch.images[k], c) for ch, c in zip(batch, crops, strict=True)]
    scales = [autoexposure(im) if hdr else 1.0 for im in images]

    def build(imgs, scale):
        mos = np.zeros((H, W, imgs[0].shape[-1]), np.float32)
        used = np.zeros((H, W), bool)
        for im, (y, x), s in zip(imgs, pos, scale, strict=True):
            h, w = im.shape[:2]
            tile = np.pad(im, ((gap, gap), (gap, gap), (0, 0)), mode="symmetric") if gap else im
            mos[y - gap : y + h + gap, x - gap : x + w + gap] = tile * np.float32(s)
            used[y - gap : y + h + gap, x - gap : x + w + gap] = True
        return fill_empty(mos, used) if fill else mos

    guides = {}
    if use_guides:
        for name in ("albedo", "normal"):
            if name in batch[0].guides:
                parts = [part(ch.guides[name], c) for ch, c in zip(batch, crops, strict=True)]
                guides[name] = build(parts, [1.0] * len(batch))
    out = den.run(build(images, scales), **kind, **guides, input_scale=1.0 if hdr else None)
    res = []
    for ch, c, (y, x), s in zip(batch, crops, pos, scales, strict=True):
        y0, y1, x0, x1 = c
        full = np.zeros(ch.images[k].shape, np.float32)
        full[y0:y1, x0:x1] = out[y : y + y1 - y0, x : x + x1 - x0] / np.float32(s)
        res.append(full)
    return res
