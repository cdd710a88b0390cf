"""One chart alone in an image of its own (:class:`Canvas`), for the denoiser
(:mod:`usdahd.bake.denoise`): OIDN's input with the chart's own filled context around it, and
the chart's bounding box alone (:meth:`Canvas.work`) for the noise estimate and the blend.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.mosaic import OIDN_BLOCK, PAD
from usdahd.bake.post import dilate
from usdahd.bake.variance import NOISE_TILE

__all__ = ["MIN_CROP", "Canvas"]

#: Smallest canvas side given to OIDN: below ~16 its output on constant images is off by
#: 5-30 % even away from borders; tiny charts are centred in a canvas this big.
MIN_CROP = 32


class Canvas:
    """A chart alone in its own image: (ly, lx) of its texels, mask, and the canvas shape."""

    def __init__(
        self, xy, pad: int = PAD, min_crop: int = MIN_CROP, mode: str = "symmetric",
        block: int = OIDN_BLOCK,
    ):  # fmt: skip
        xy = np.asarray(xy, dtype=np.int64)
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        size = hi - lo + 1
        full = np.maximum(-(-(size + 2 * pad) // block) * block, min_crop)
        origin = lo - (full - size) // 2
        self.lx, self.ly = xy[:, 0] - origin[0], xy[:, 1] - origin[1]
        self.shape = (int(full[1]), int(full[0]))
        self.mask = np.zeros(self.shape, dtype=bool)
        self.mask[self.ly, self.lx] = True
        y0, x0 = int(self.ly.min()), int(self.lx.min())
        self.box = (y0, int(self.ly.max()) + 1, x0, int(self.lx.max()) + 1)
        self.mode = mode

    def image(self, values: np.ndarray, fill: bool = True) -> np.ndarray:
        """(h, w, c) float32 canvas of per-texel ``values (m, c)``. Outside the chart: with
        ``fill``, holes in the chart's bounding box grown from the chart (dilation) and the
        box mirrored outward (symmetric padding, repeated as needed), so the context has the
        chart's own signal and noise statistics; else NaN."""
        values = np.asarray(values, dtype=np.float32)
        img = np.full((*self.shape, values.shape[-1]), np.nan, np.float32)
        img[self.ly, self.lx] = values
        if not fill:
            return img
        y0, y1, x0, x1 = self.box
        box = dilate(np.nan_to_num(img[y0:y1, x0:x1]), self.mask[y0:y1, x0:x1], None)
        h, w = self.shape
        pads = ((y0, h - y1), (x0, w - x1), (0, 0))
        return np.pad(box, pads, mode=self.mode)

    def gather(self, img: np.ndarray) -> np.ndarray:
        return img[self.ly, self.lx]

    def work(self, align: int = NOISE_TILE) -> Canvas:
        """The chart's bounding box as a canvas of its own, its origin on this canvas's
        ``align`` grid, for everything but OIDN's input (``image(fill=False)``, ``gather``,
        ``mask``): the noise estimate, the pooling and the blend need no context, and a small
        chart's box is a fraction of its OIDN canvas (at 32² a 2 x 27 chart: 54 of 1,536
        pixels). Results on it equal the canvas's bit for bit: the noise estimate's tiles stay
        on the same grid, masked sums only add zeros outside the chart, and beyond its edges
        there is no chart texel either."""
        y0, y1, x0, x1 = self.box
        oy, ox = y0 - y0 % align, x0 - x0 % align
        wv = object.__new__(Canvas)
        wv.lx, wv.ly = self.lx - ox, self.ly - oy
        wv.shape = (y1 - oy, x1 - ox)
        wv.mask = self.mask[oy:y1, ox:x1]
        wv.box = (y0 - oy, y1 - oy, x0 - ox, x1 - ox)
        wv.mode = self.mode
        return wv
